"""Electron fits on lhcb-like (issue 15): do the written q/p covariances cover the errors?

An electron gun (2–50 GeV, 2 < η < 5) in the lhcb-like detector, truth tracks, fitted by
the reference and parametrized Kalman fitters under the pion and the electron hypothesis
(`--hypothesis`, two passes, as `pkf reconstruct`) and by the GSF (default options). Per
fitter and location (first hit, beamline, last VELO hit, last UT hit, last hit): the
number of tracks, the q/p pull RMS, the share of pulls within ±1.2, the pulls' Gaussian
core and mean, and the δp/p Gaussian core and central-68 % half-width. Truth: the
mc_hit q/p at a hit (the production q/p for the parametrized fitter under the pion
hypothesis, whose states then carry it), the production q/p at the beamline. The events are the same as

    pkf simulate --generator gun --species electron --events N --particles P --p-min 2000 --p-max 50000 --seed S

    python benchmarks/electron_fits.py [--events 300] [--particles 5] [--seed 7] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "fit"))
from fit_helpers import TruthSample  # noqa: E402

from pkf.fit.gsf import fit_batch_gsf, gsf_extrapolator  # noqa: E402
from pkf.fit.hypothesis import with_hypothesis  # noqa: E402
from pkf.fit.tracks import FitOptions, fit_batch  # noqa: E402
from pkf.geometry import load_geometry  # noqa: E402
from pkf.params.gauss import gaussian_core  # noqa: E402
from pkf.params.parameter_set import shipped_parameters  # noqa: E402

LOCATIONS = ("first_hit", "beamline", "last_velo_hit", "last_ut_hit", "last_hit")


def location_nodes(sample, location: str) -> np.ndarray:
    """Node index per track at `location` (−1 where the track has none; beamline: the first hit)."""
    b = sample.batch
    if location in ("first_hit", "beamline"):
        return b.offsets[:-1].copy()
    if location == "last_hit":
        return b.offsets[1:] - 1
    track = np.repeat(np.arange(b.n_tracks), b.n_nodes)
    last = np.full(b.n_tracks, -1)
    idx = np.flatnonzero(sample.geometry.layer_subdetector[b.layer] == {"last_velo_hit": 0, "last_ut_hit": 1}[location])
    np.maximum.at(last, track[idx], idx)
    return last


def summary(qop, var, truth) -> dict:
    pull = (qop - truth) / np.sqrt(var)
    dpp = np.abs(truth) / np.abs(qop) - 1.0
    lo, hi = np.percentile(dpp, [16, 84])
    return {"tracks": int(pull.size), "pull_rms": float(np.sqrt(np.mean(pull**2))),
            "within_1.2": float(np.mean(np.abs(pull) < 1.2)), "pull_core": gaussian_core(pull).sigma,
            "pull_mean": float(np.mean(pull)), "dp_over_p_core": gaussian_core(dpp).sigma,
            "dp_over_p_sigma68": float(0.5 * (hi - lo))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=300)
    parser.add_argument("--particles", type=int, default=5)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    geometry = load_geometry("lhcb-like")
    sample = TruthSample(geometry, events=args.events, seed=args.seed, species="electron", particles=args.particles,
                         p_min=2000.0, p_max=50000.0, eta_min=2.0, eta_max=5.0)
    parametrized = shipped_parameters(geometry).extrapolator(geometry)
    fits, production = {}, {}
    for hypothesis in ("pion", "electron"):
        options = FitOptions.from_flat(iterations=2, hypothesis=hypothesis)
        for name, ext in (("reference", sample.extrapolator), ("parametrized", parametrized)):
            fits[f"{name}/{hypothesis}"] = fit_batch(with_hypothesis(ext, geometry, hypothesis), sample.batch, options,
                                                     sample.seeds, sample.seed_covs, sample.beamline)
            production[f"{name}/{hypothesis}"] = name == "parametrized" and hypothesis == "pion"
    fits["gsf"] = fit_batch_gsf(gsf_extrapolator(geometry), sample.batch, FitOptions(), sample.seeds,
                                sample.seed_covs, sample.beamline)
    production["gsf"] = False
    ok = np.all([r.status == 0 for r in fits.values()], axis=0)
    rows = sample.batch.hit_row
    results = {"tracks": int(sample.batch.n_tracks), "fitted_by_all": int(ok.sum()), "fits": {}}
    for name, result in fits.items():
        results["fits"][name] = {}
        for location in LOCATIONS:
            nodes = location_nodes(sample, location)
            sel = ok & (nodes >= 0)
            nodes = nodes[sel]
            if location == "beamline":
                _, state, cov = result.locations["beamline"]
                qop, var = state[sel, 4], cov[sel, 4, 4]
            else:
                qop, var = result.node_state[nodes, 4], result.node_cov[nodes, 4, 4]
            at_production = location == "beamline" or production[name]
            truth = sample.production_qop[rows[nodes]] if at_production else sample.truth[rows[nodes], 4]
            results["fits"][name][location] = summary(qop, var, truth)
    print(f"Electron gun 2–50 GeV, lhcb-like, {results['fitted_by_all']} of {results['tracks']} truth tracks "
          "fitted by all: q/p pulls and δp/p")
    print(f"{'fit':<24}{'location':<15}{'tracks':>7}{'pull RMS':>10}{'|pull|<1.2':>11}{'pull core':>10}"
          f"{'pull mean':>10}{'δp/p core':>11}{'δp/p σ68':>10}")
    for name, locations in results["fits"].items():
        for location, r in locations.items():
            print(f"{name:<24}{location:<15}{r['tracks']:>7}{r['pull_rms']:>10.3f}{r['within_1.2']:>11.3f}"
                  f"{r['pull_core']:>10.3f}{r['pull_mean']:>10.3f}{100 * r['dp_over_p_core']:>10.3f}%"
                  f"{100 * r['dp_over_p_sigma68']:>9.2f}%")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2) + "\n")


if __name__ == "__main__":
    main()
