"""pkf against ACTS (the `pyacts` wheel) on the same telescope and the same measurements (issue 18).

The geometry is pkf's built-in `telescope` (10 pixel planes at z = 100, 200, …, 1000 mm,
σ = 0.01 mm in x and y, x/X0 = 0.01 per plane, homogeneous 1 T field along y) and ACTS's
`TelescopeDetector` with the same planes (silicon, X0 = 93.7 mm, so 0.937 mm thick for
x/X0 = 0.01; 1000 × 1000 mm half sizes; `ConstantBField` (0, 1 T, 0)). pkf simulates a gun
(`--events` × 10 particles, p = 1–50 GeV, 2 < η < 4: every track crosses the 10 planes) and
BOTH fitters fit the SAME hits: pkf from its `TrackBatch`, ACTS from a `MeasurementContainer`
and `ProtoTrackContainer` filled by a Python algorithm with the same (x, y, σ) per hit.

Rows (µs per track, CPU time (`time.process_time`) of the fit alone, one thread, after a
warm-up, the best call (below); all in one process run):

- Kalman: ACTS KF (`makeKalmanFitterFunction`, multiple scattering and energy loss on)
  vs pkf's reference Kalman fitter with 1 and 2 passes, and pkf's parametrized fitter;
- GX2F: ACTS (`makeGlobalChiSquareFitterFunction`) vs pkf's `gx2f`;
- GSF, 12 components, on an ELECTRON gun with the same seed, momenta and directions:
  ACTS (`makeGsfFitterFunction`, KL-distance reduction, mean merge) vs pkf's `gsf`.
  The wheel ships no Bethe–Heitler file, so ACTS's GSF gets pkf's own mixture
  (`pkf.params.bethe_heitler`, the shipped one) converted to ACTS's polynomial format
  (`acts_bethe_heitler_json`, written next to the JSON output / in a temporary directory).

ACTS starts each track from `TrackParamsEstimationAlgorithm` on the first three hits (its
own helix estimate, as in its truth-estimated seeding); pkf from its own hit-based seed
(`seed_batch`). Neither seed is timed. Quality at the first plane (ACTS: the fitted track
parameters on its reference surface, the first plane; tracks whose vertex lies beyond the
first plane, σ_z = 45 mm, are left out of the pulls): Gaussian cores (`pkf.params.gauss`)
of the q/p and x pulls and of δ(q/p)/(q/p). "ok": a fitted state for the track (ACTS
tracks are identified by their outermost measurement; the JSON also counts ACTS fits that
used fewer measurements than the track has). ACTS's GSF reports the covariance of its
whole mixture (the merge method only picks the mean), so its q/p pull core is well below
1 where the core resolution is as good as pkf's; pkf's "core" output reports the core's.

    python benchmarks/vs_acts.py [--events 200] [--repeat 7] [--min-seconds 2] [--json out.json]

Each fitter is timed at least --repeat times and until its timed calls add up to
--min-seconds of CPU (ACTS: a second Sequencer run with enough events if the first fell
short), the same budget on both sides. The parametrized fit of the 2,000 tracks takes
~5 ms, and its first calls after the warm-up run slow: best of 7 was 2.75–2.83 µs per track
where best of 25 was 2.52–2.63 (3 fresh processes each). ACTS's KF events (~55 ms) vary by
a few per cent.

Between runs the ratios move more than within one: pkf's telescope fit depends on where
its arrays land in memory (the same code, interleaved in one process, ran 12–15 % apart
depending on which side allocated first; `pkf.fit.kalman_lanes`), and ACTS's KF took
30.5–36.1 µs per track in four runs of one day on one machine (parametrized / ACTS KF
0.081–0.095). Compare rows over several runs.

Needs the optional `bench` extra (`pip install -e .[bench]`, i.e. pyacts==48.1.0).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "fit"))
from fit_helpers import TruthSample  # noqa: E402

from pkf.fit.gsf import fit_batch_gsf, gsf_extrapolator  # noqa: E402
from pkf.fit.gx2f import fit_batch_gx2f  # noqa: E402
from pkf.fit.tracks import FitOptions, fit_batch  # noqa: E402
from pkf.geometry import load_geometry  # noqa: E402
from pkf.params.bethe_heitler import Z_GRID, load_bethe_heitler_mixture  # noqa: E402
from pkf.params.gauss import gaussian_core  # noqa: E402
from pkf.params.parameter_set import shipped_parameters  # noqa: E402

GUN = dict(particles=10, p_min=1000.0, p_max=50000.0, eta_min=2.0, eta_max=4.0)
SILICON_X0_MM = 93.70  # ACTS's TelescopeDetector material (Acts::Material silicon, X0 = 9.370 cm)
GSF_COMPONENTS = 12


# ------------------------------------------------------------------------------------------
# timing helpers
# ------------------------------------------------------------------------------------------


#: Each fitter's timed calls add up to at least this much CPU [s] (--min-seconds).
MIN_SECONDS = 2.0


def calls_for_budget(repeat: int, seconds_per_call: float, min_seconds: float) -> int:
    """Timed calls: at least `repeat`, and enough to fill `min_seconds` of CPU."""
    return max(repeat, math.ceil(min_seconds / max(seconds_per_call, 1e-9)))


def best_cpu(repeat: int, fn, min_seconds: float = MIN_SECONDS):
    """Best CPU time [s] of at least `repeat` calls of fn that add up to `min_seconds`
    (after one warm-up call), the median, and fn's last result."""
    result = fn()
    times = []
    while len(times) < repeat or sum(times) < min_seconds:
        t0 = time.process_time()
        result = fn()
        times.append(time.process_time() - t0)
    return min(times), float(np.median(times)), result


def starts_on_first_plane(sample: TruthSample) -> np.ndarray:
    """Tracks whose first hit is on the first plane (ACTS's reference surface): the pulls use these."""
    first_layer = sample.batch.layer[sample.batch.offsets[:-1]]
    return first_layer == sample.batch.layer.min()


def pull_cores(state, cov, truth, ok):
    """Gaussian-core widths of the q/p and x pulls and of δ(q/p)/(q/p) at the first plane
    (state, truth in pkf's (x, y, tx, ty, q/p)), over the tracks `ok`."""
    out = {}
    for name, i in (("qop", 4), ("x", 0)):
        pull = (state[ok, i] - truth[ok, i]) / np.sqrt(cov[ok, i, i])
        out[name] = gaussian_core(pull).sigma
    out["dqop_over_qop"] = gaussian_core(state[ok, 4] / truth[ok, 4] - 1.0).sigma
    out["median_qop_sigma_over_qop"] = float(np.median(np.sqrt(cov[ok, 4, 4]) / np.abs(state[ok, 4])))
    out["tracks"] = int(ok.sum())
    return out


# ------------------------------------------------------------------------------------------
# pkf side
# ------------------------------------------------------------------------------------------


def pkf_rows(sample: TruthSample, electrons: TruthSample, repeat: int, min_seconds: float = MIN_SECONDS) -> dict:
    """µs per track and pull cores of pkf's fitters on the pion sample (GSF: electrons)."""
    geometry = sample.geometry
    rows = {}
    first = sample.batch.offsets[:-1]
    truth = sample.truth[sample.batch.hit_row[first]]
    runs = {
        "pkf reference, 1 pass": (sample.extrapolator, fit_batch, FitOptions(max_outliers=0)),
        "pkf reference, 2 passes": (sample.extrapolator, fit_batch, FitOptions.from_flat(max_outliers=0, iterations=2)),
        "pkf parametrized": (shipped_parameters(geometry).extrapolator(geometry), fit_batch,
                             FitOptions(max_outliers=0)),
        "pkf gx2f": (sample.extrapolator, fit_batch_gx2f, FitOptions(max_outliers=0)),
    }
    for name, (ext, fit, opts) in runs.items():
        wall, median, r = best_cpu(repeat, lambda ext=ext, fit=fit, opts=opts: fit(ext, sample.batch, opts,
                                                                                     sample.seeds, sample.seed_covs),
                                   min_seconds)
        _, state, cov = r.locations["first_hit"]
        ok = r.status == 0
        t = truth.copy()
        if "parametrized" in name:  # the parametrized states carry the production q/p
            t[:, 4] = sample.production_qop[sample.batch.hit_row[first]]
        rows[name] = {"tracks": int(sample.batch.n_tracks), "us_per_track": 1e6 * wall / sample.batch.n_tracks,
                      "median_us_per_track": 1e6 * median / sample.batch.n_tracks,
                      "ok_fraction": float(ok.mean()), "pull_core": pull_cores(state, cov, t, ok & starts_on_first_plane(sample))}
    ctx = gsf_extrapolator(geometry)
    opts = FitOptions.from_flat(max_outliers=0, max_components=GSF_COMPONENTS)
    wall, median, r = best_cpu(repeat, lambda: fit_batch_gsf(ctx, electrons.batch, opts, electrons.seeds,
                                                             electrons.seed_covs), min_seconds)
    _, state, cov = r.locations["first_hit"]
    ok = r.status == 0
    e_truth = electrons.truth[electrons.batch.hit_row[electrons.batch.offsets[:-1]]]
    rows["pkf gsf"] = {"tracks": int(electrons.batch.n_tracks), "us_per_track": 1e6 * wall / electrons.batch.n_tracks,
                       "median_us_per_track": 1e6 * median / electrons.batch.n_tracks,
                       "ok_fraction": float(ok.mean()), "pull_core": pull_cores(state, cov, e_truth, ok & starts_on_first_plane(electrons))}
    return rows


# ------------------------------------------------------------------------------------------
# ACTS side
# ------------------------------------------------------------------------------------------


def acts_bethe_heitler_json(path: Path, t_low: float = 0.002, t_high: float = 0.05, degree: int = 5) -> dict:
    """Write pkf's shipped Bethe–Heitler mixture in ACTS's JSON format
    (`loadBetheHeitlerApproxFromJson`: one range [t_low, t_high] of x/X0, "transform" on);
    returns the largest CDF difference between the converted and pkf's mixture at the
    path lengths of this benchmark (t = 0.010–0.0104 X0 per plane).

    ACTS evaluates per component, at x = t [X0], weight = logistic(P_w(x)), mean =
    logistic(P_m(x)), variance = exp(P_v(x)) (then normalises the weights); coefficients
    highest order first (Horner). pkf's components are continuous in t, so each
    transformed parameter is fitted by least squares on a log grid of t."""
    mixture = load_bethe_heitler_mixture()
    t = np.geomspace(t_low, t_high, 400)
    w, mu, var = (np.array(a) for a in zip(*(mixture.components(ti) for ti in t)))
    logit = lambda p: np.log(p) - np.log1p(-p)  # noqa: E731
    eps = 1e-12
    coeffs = [{"weight_coeffs": np.polyfit(t, logit(np.clip(w[:, k], eps, 1 - eps)), degree).tolist(),
               "mean_coeffs": np.polyfit(t, logit(np.clip(mu[:, k], eps, 1 - eps)), degree).tolist(),
               "var_coeffs": np.polyfit(t, np.log(np.maximum(var[:, k], 1e-300)), degree).tolist()}
              for k in range(mixture.n_components)]
    path.write_text(json.dumps({"ranges": [{"low_x0": t_low, "high_x0": t_high, "transform": True,
                                            "components": coeffs}]}))
    worst = 0.0
    from scipy.special import expit, ndtr

    for ti in np.linspace(0.010, 0.0104, 5):
        cw = np.array([expit(np.polyval(c["weight_coeffs"], ti)) for c in coeffs])
        cm = np.array([expit(np.polyval(c["mean_coeffs"], ti)) for c in coeffs])
        cs = np.sqrt([np.exp(np.polyval(c["var_coeffs"], ti)) for c in coeffs])
        cdf = (cw / cw.sum() * ndtr((Z_GRID[:, None] - cm) / cs)).sum(-1)
        worst = max(worst, float(np.abs(cdf - mixture.cdf(Z_GRID, ti)).max()))
    return {"file": str(path), "t_range": [t_low, t_high], "degree": degree, "max_cdf_difference": worst}


class ActsTelescope:
    """ACTS's TelescopeDetector with pkf's telescope planes and field."""

    def __init__(self, geometry):
        import acts
        import acts.examples as ae

        self.acts, self.ae = acts, ae
        z = np.asarray(geometry.layer_z, dtype=float)
        x_over_x0 = np.unique(geometry.layer_x_over_x0)
        (layers,) = geometry.config["layers"]  # one layer block of identical planes
        field = geometry.field.params
        if x_over_x0.size != 1 or geometry.field.description[0] != "uniform":
            raise ValueError("ActsTelescope: needs identical planes in a uniform field")
        cfg = ae.TelescopeDetector.Config()
        cfg.positions = z.tolist()
        cfg.stereos = [0.0] * z.size
        cfg.offsets = [0.0, 0.0]
        cfg.bounds = [float(layers["half_x"]), float(layers["half_y"])]
        cfg.thickness = float(x_over_x0[0]) * SILICON_X0_MM
        cfg.surfaceType = 0
        cfg.rotDirection = 2  # planes normal to z, as in pkf
        self.detector = ae.TelescopeDetector(cfg)
        self.tracking_geometry = self.detector.trackingGeometry()
        surfaces = []
        self.tracking_geometry.visitSurfaces(lambda s: surfaces.append(s))
        gctx = self.detector.nominalGeometryContext()
        surfaces.sort(key=lambda s: s.center(gctx)[2])
        self.surfaces = surfaces
        tesla = acts.UnitConstants.T
        self.field = acts.ConstantBField(acts.Vector3(*(float(b) * tesla for b in field)))


def make_fitter(tel: ActsTelescope, kind: str, bethe_heitler_file: Path | None):
    acts, ae = tel.acts, tel.ae
    level = acts.logging.WARNING
    if kind == "kf":
        return ae.makeKalmanFitterFunction(tel.tracking_geometry, tel.field, multipleScattering=True,
                                           energyLoss=True, reverseFilteringMomThreshold=0.0,
                                           reverseFilteringCovarianceScaling=1.0,
                                           freeToBoundCorrection=ae.FreeToBoundCorrection(False), chi2Cut=float("inf"),
                                           useJosephFormulation=False, level=level)
    if kind == "gx2f":
        return ae.makeGlobalChiSquareFitterFunction(tel.tracking_geometry, tel.field, multipleScattering=True,
                                                    energyLoss=True,
                                                    freeToBoundCorrection=ae.FreeToBoundCorrection(False),
                                                    nUpdateMax=17, relChi2changeCutOff=1e-7, level=level)
    if kind == "gsf":
        bha = ae.loadBetheHeitlerApproxFromJson(str(bethe_heitler_file), clamp_to_range=True,
                                                no_change_limit=1e-4, single_gaussian_limit=0.002)
        return ae.makeGsfFitterFunction(tel.tracking_geometry, tel.field, betheHeitlerApprox=bha,
                                        maxComponents=GSF_COMPONENTS, weightCutoff=1e-4,
                                        componentMergeMethod=ae.ComponentMergeMethod.mean,
                                        mixtureReductionAlgorithm=ae.MixtureReductionAlgorithm.KLDistance,
                                        reverseFilteringCovarianceScaling=1.0, level=level)
    raise ValueError(kind)


def acts_fit(tel: ActsTelescope, sample: TruthSample, kind: str, repeat: int, bethe_heitler_file: Path | None,
             mass_hypothesis: str) -> dict:
    """Fit the sample's tracks with an ACTS fitter in a Sequencer (one thread), `repeat` + 1
    events of the same tracks; CPU time of the fitting algorithm per event, best after the
    first; the fitted parameters at the first plane of the last event."""
    acts, ae = tel.acts, tel.ae
    batch = sample.batch
    n_tracks = int(batch.n_tracks)
    layer = batch.layer
    hx, hy = sample.hits["u"][batch.hit_row], sample.hits["v"][batch.hit_row]
    su, sv = sample.hits["sigma_u"][batch.hit_row], sample.hits["sigma_v"][batch.hit_row]
    plane_of_layer = {int(lay): i for i, lay in enumerate(np.unique(layer))}
    geo_ids = [s.geometryId for s in tel.surfaces]
    node_geo = [geo_ids[plane_of_layer[int(lay)]] for lay in layer]
    offsets = batch.offsets
    clock: dict = {"start": [], "stop": []}
    fitted: dict = {}

    class Feed(ae.IAlgorithm):
        """Writes the same hits as pkf's TrackBatch: one 2-D measurement per node, one proto track per track."""

        def __init__(self):
            super().__init__(name="PkfFeed", level=acts.logging.WARNING)
            self.out_meas = ae.WriteDataHandle(self, ae.MeasurementContainer, "OutputMeasurements")
            self.out_meas.initialize("measurements")
            self.out_proto = ae.WriteDataHandle(self, ae.ProtoTrackContainer, "OutputProtoTracks")
            self.out_proto.initialize("prototracks")
            self.out_subset = ae.WriteDataHandle(self, ae.MeasurementSubset, "OutputMeasurementSubset")
            self.out_subset.initialize("measurement_subset")
            self.alive = None

        @staticmethod
        def measurements():
            container = ae.MeasurementContainer()
            container.reserve(len(node_geo))
            for k in range(len(node_geo)):
                container.emplaceMeasurement(node_geo[k], [0, 1], [float(hx[k]), float(hy[k])],
                                             [float(su[k]) ** 2, float(sv[k]) ** 2])
            return container

        def execute(self, ctx):
            protos = ae.ProtoTrackContainer()
            for t in range(n_tracks):
                protos.append(ae.ProtoTrack(list(range(int(offsets[t]), int(offsets[t + 1])))))
            # the space-point maker reads a subset, a view of a container: writing a container
            # to the whiteboard moves it, so the subset gets its own copy, kept alive here
            self.alive = self.measurements()
            self.out_subset(ctx, ae.MeasurementSubset(self.alive, list(range(len(node_geo)))))
            self.out_meas(ctx, self.measurements())
            self.out_proto(ctx, protos)
            return ae.ProcessCode.SUCCESS

    class Stopwatch(ae.IAlgorithm):
        def __init__(self, key):
            super().__init__(name=f"Stopwatch{key}", level=acts.logging.WARNING)
            self.key = key

        def execute(self, ctx):
            clock[self.key].append(time.process_time())
            return ae.ProcessCode.SUCCESS

    class Collect(ae.IAlgorithm):
        """Reads the fitted parameters at the reference surface (the first plane)."""

        def __init__(self):
            super().__init__(name="Collect", level=acts.logging.WARNING)
            self.tracks = ae.ReadDataHandle(self, ae.ConstTrackContainer, "InputTracks")
            self.tracks.initialize("fitted_tracks")

        def execute(self, ctx):
            fitted["tracks"] = self.tracks(ctx.eventStore)
            fitted["rows"] = _track_parameters(fitted["tracks"])
            return ae.ProcessCode.SUCCESS

    seq = ae.Sequencer(events=repeat + 1, numThreads=1, logLevel=acts.logging.WARNING,
                       outputDir=tempfile.mkdtemp(prefix="vs_acts_"))
    seq.addAlgorithm(Feed())
    seq.addAlgorithm(ae.SpacePointMaker(level=acts.logging.WARNING, inputMeasurements="measurement_subset",
                                        outputSpacePoints="spacepoints", trackingGeometry=tel.tracking_geometry,
                                        geometrySelection=[acts.GeometryIdentifier(volume=1)]))
    seq.addAlgorithm(ae.ProtoTracksToSeeds(level=acts.logging.WARNING, inputProtoTracks="prototracks",
                                           inputSpacePoints="spacepoints", outputSeeds="seeds",
                                           outputProtoTracks="seeded_prototracks"))
    hypothesis = getattr(acts.ParticleHypothesis, mass_hypothesis)
    seq.addAlgorithm(ae.TrackParamsEstimationAlgorithm(
        level=acts.logging.WARNING, inputSeeds="seeds", inputProtoTracks="seeded_prototracks",
        outputTrackParameters="initial_parameters", outputSeeds="estimated_seeds",
        outputProtoTracks="estimated_prototracks", trackingGeometry=tel.tracking_geometry,
        magneticField=tel.field, particleHypothesis=hypothesis,
        spacePointSelection=ae.SeedSpacePointSelection.FirstThree))
    seq.addAlgorithm(Stopwatch("start"))
    seq.addAlgorithm(ae.TrackFittingAlgorithm(
        level=acts.logging.WARNING, inputMeasurements="measurements", inputProtoTracks="estimated_prototracks",
        inputInitialTrackParameters="initial_parameters", outputTracks="fitted_tracks", pickTrack=-1,
        fit=make_fitter(tel, kind, bethe_heitler_file), calibrator=ae.makePassThroughCalibrator(),
        referenceSurface=tel.surfaces[0]))
    seq.addAlgorithm(Stopwatch("stop"))
    seq.addAlgorithm(Collect())
    seq.run()
    times = np.array(clock["stop"]) - np.array(clock["start"])
    params, covs, n_meas, last = fitted["rows"]
    return {"cpu_s": float(times[1:].min()), "median_cpu_s": float(np.median(times[1:])), "event_cpu_s": times.tolist(),
            "parameters": params, "covariances": covs,
            "n_measurements": n_meas, "outermost_xy": last}


def _track_parameters(tracks) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Per fitted track: bound parameters (n, 6) and covariances (n, 6, 6) at the reference
    surface, the number of measurements used, and the (x, y) of its outermost measurement
    (to identify the track: a failed fit leaves no track, so indices may shift)."""
    params = np.array(tracks.parameters, dtype=float).reshape(-1, 6)
    covs = np.array(tracks.covariance, dtype=float).reshape(-1, 6, 6)
    n_meas = np.array(tracks.nMeasurements, dtype=np.int64)
    last = np.array([list(tracks.getTrack(i).outermostTrackState.effectiveCalibrated)[:2]
                     for i in range(len(tracks))], dtype=float).reshape(-1, 2)
    return params, covs, n_meas, last


def acts_state_to_pkf(params, cov):
    """ACTS bound (loc0, loc1, φ, θ, q/p [e/GeV], t) on a z plane → pkf (x, y, tx, ty, q/p [1/MeV])
    and the propagated covariance (first-order Jacobian)."""
    x, y, phi, theta, qop_gev = params[:5]
    dx, dy, dz = math.sin(theta) * math.cos(phi), math.sin(theta) * math.sin(phi), math.cos(theta)
    state = np.array([x, y, dx / dz, dy / dz, qop_gev / 1000.0])
    jac = np.zeros((5, 6))
    jac[0, 0] = jac[1, 1] = 1.0
    # tx = tan θ cos φ, ty = tan θ sin φ
    sec2 = 1.0 / dz**2
    jac[2, 2], jac[2, 3] = -math.tan(theta) * math.sin(phi), sec2 * math.cos(phi)
    jac[3, 2], jac[3, 3] = math.tan(theta) * math.cos(phi), sec2 * math.sin(phi)
    jac[4, 4] = 1.0 / 1000.0
    return state, jac @ cov @ jac.T


def acts_rows(sample: TruthSample, electrons: TruthSample, repeat: int, bethe_heitler_file: Path,
              min_seconds: float = MIN_SECONDS) -> dict:
    tel = ActsTelescope(sample.geometry)
    rows = {}
    for name, kind, smp, hyp in (("ACTS KF", "kf", sample, "pion"), ("ACTS GX2F", "gx2f", sample, "pion"),
                                 ("ACTS GSF", "gsf", electrons, "electron")):
        res = acts_fit(tel, smp, kind, repeat, bethe_heitler_file, hyp)
        calls = calls_for_budget(repeat, res["cpu_s"], min_seconds)
        if calls > repeat:  # the same CPU budget as pkf's rows: a second run with more events
            more = acts_fit(tel, smp, kind, calls, bethe_heitler_file, hyp)
            timed = res["event_cpu_s"][1:] + more["event_cpu_s"][1:]
            more["event_cpu_s"] = res["event_cpu_s"] + more["event_cpu_s"]
            more["cpu_s"], more["median_cpu_s"] = float(min(timed)), float(np.median(timed))
            res = more
        n = int(smp.batch.n_tracks)
        first = smp.batch.offsets[:-1]
        truth = smp.truth[smp.batch.hit_row[first]]
        state = np.full((n, 5), np.nan)
        cov = np.full((n, 5, 5), np.nan)
        # a failed ACTS fit leaves no track: identify each fitted track by its outermost
        # measurement (the same numbers as the track's last hit)
        last = smp.batch.offsets[1:] - 1
        last_xy = np.column_stack([smp.hits["u"][smp.batch.hit_row[last]], smp.hits["v"][smp.batch.hit_row[last]]])
        order = np.lexsort(last_xy.T[::-1])
        pos = np.searchsorted(last_xy[order, 0], res["outermost_xy"][:, 0])
        track = order[np.minimum(pos, n - 1)]
        same = np.all(last_xy[track] == res["outermost_xy"], axis=1)
        all_hits = same & (res["n_measurements"] == smp.batch.n_nodes[track])
        for j in np.flatnonzero(same):
            state[track[j]], cov[track[j]] = acts_state_to_pkf(res["parameters"][j], res["covariances"][j])
        fewer = int((~all_hits[same]).sum())
        ok = np.all(np.isfinite(state), axis=1)
        rows[name] = {"tracks": n, "us_per_track": 1e6 * res["cpu_s"] / n, "ok_fraction": float(ok.mean()),
                      "median_us_per_track": 1e6 * res["median_cpu_s"] / n,
                      "fitted_with_fewer_measurements_than_hits": fewer,
                      "event_cpu_s": res["event_cpu_s"], "pull_core": pull_cores(state, cov, truth, ok & starts_on_first_plane(smp))}
    return rows


# ------------------------------------------------------------------------------------------


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=200, help="gun events of 10 particles each")
    parser.add_argument("--repeat", type=int, default=7, help="timed repetitions per fitter at least, best kept (after a warm-up)")
    parser.add_argument("--min-seconds", type=float, default=MIN_SECONDS,
                        help="timed CPU per fitter at least [s]: more repetitions where calls are short")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    try:
        import acts  # noqa: F401
        import acts.examples  # noqa: F401
    except ImportError:
        sys.exit("vs_acts.py needs the `bench` extra: pip install -e '.[bench]' (pyacts==48.1.0)")

    geometry = load_geometry("telescope")
    pions = TruthSample(geometry, events=args.events, seed=18, **GUN)
    electrons = TruthSample(geometry, events=args.events, seed=18, species="electron", **GUN)
    bh_dir = args.json.parent if args.json else Path(tempfile.mkdtemp(prefix="vs_acts_"))
    bh = acts_bethe_heitler_json(bh_dir / "pkf_bethe_heitler_acts_format.json")
    bh_file = Path(bh["file"])

    results = {"rows": {}}
    results["rows"].update(pkf_rows(pions, electrons, args.repeat, args.min_seconds))
    results["rows"].update(acts_rows(pions, electrons, args.repeat, bh_file, args.min_seconds))
    r = results["rows"]
    ratio = lambda a, b: r[a]["us_per_track"] / r[b]["us_per_track"]  # noqa: E731
    results["ratios_pkf_over_acts"] = {
        "reference 1 pass / ACTS KF": ratio("pkf reference, 1 pass", "ACTS KF"),
        "reference 2 passes / ACTS KF": ratio("pkf reference, 2 passes", "ACTS KF"),
        "parametrized / ACTS KF": ratio("pkf parametrized", "ACTS KF"),
        "gx2f / ACTS GX2F": ratio("pkf gx2f", "ACTS GX2F"),
        "gsf / ACTS GSF": ratio("pkf gsf", "ACTS GSF"),
    }
    results["setup"] = {"events": args.events, "repeat": args.repeat, "min_seconds": args.min_seconds, "gun": GUN, "seed": 18,
                        "tracks_pions": int(pions.batch.n_tracks), "tracks_electrons": int(electrons.batch.n_tracks),
                        "acts_version": ".".join(map(str, acts.__version__)),
                        "acts_bethe_heitler": {"source": "pkf's shipped mixture, converted (acts_bethe_heitler_json)", **bh},
                        "timing": "time.process_time of the fit alone, one thread, after a warm-up: best of at least "
                                  "repeat calls that add up to min_seconds (median: median_us_per_track)"}
    print(f"{len(pions.batch.offsets) - 1} pion tracks (GSF: {electrons.batch.n_tracks} electron tracks), "
          f"telescope, one thread, CPU µs per track (best of ≥ {args.repeat} calls, ≥ {args.min_seconds:g} s each fitter)")
    print(f"{'fitter':<26}{'µs/track':>10}{'ok':>8}{'q/p pull':>10}{'x pull':>9}{'δ(q/p)/(q/p)':>14}")
    for name, row in r.items():
        print(f"{name:<26}{row['us_per_track']:>10.1f}{100 * row['ok_fraction']:>7.1f}%"
              f"{row['pull_core']['qop']:>10.3f}{row['pull_core']['x']:>9.3f}"
              f"{100 * row['pull_core']['dqop_over_qop']:>13.3f}%")
    for name, value in results["ratios_pkf_over_acts"].items():
        print(f"{name:<32}{value:>7.3f}")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
