"""B_s⁰ → φφ mass resolution of the parametrized vs the reference fitter on the same candidates (issue 6).

Simulates `bs2phiphi` events on the lhcb-like default (or takes an existing run), fits
the truth-grouped tracks with both fitters (`--pattern truth`: the same hits for both),
and prints, from the kaons' beamline states (DESIGN §10, paper Fig. 4):

- σ(m) of each fitter on its own candidates (the report's per-fitter `mass.fit`);
- σ(m) of both on the *common* candidates (decays whose four kaons both fitters fitted)
  and their ratio with a jackknife error (the report's `mass.ratio_to_reference`);
  candidates are decays whose four kaons are long reconstructible particles (as the
  report; paper §5: tracks with measurements in every subdetector);
- which component makes a difference: σ(m) with |p| from one fitter and the direction
  from the other, or with the true |p| or the true direction;
- per kaon of the common candidates, in bins of the true momentum: the Gaussian core
  (and mean) of δp/p against the production momentum, and of δtx, δty [µrad] against the
  production direction, with the qop pull width.

    python benchmarks/bs_mass_compare.py [--events 2000] [--seed 7] [--out DIR] [--params FILE]
    python benchmarks/bs_mass_compare.py --run RUN          # an existing run with both fitters
    [--json out.json]
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

from pkf.io.schemas import particle_key
from pkf.params.gauss import gaussian_core
from pkf.pipeline.inputs import column
from pkf.pipeline.reconstruct import ReconstructionConfig, run_reconstruction
from pkf.pipeline.report import load_truth
from pkf.pipeline.simulate import SimulationConfig, run_simulation
from pkf.report.massfit import KAON_MASS, fit_mass_peak, four_momenta, invariant_mass
from pkf.report.metrics import MASS_WINDOW_MEV, bs_kaon_state_rows, mass_ratio_on_common_candidates
from pkf.report.runs import load_runs, rows_of

FITTERS = ("parametrized", "reference")
P_EDGES = (2000.0, 3000.0, 5000.0, 10000.0, 20000.0, 1e6)


def _masses(qop, tx, ty) -> np.ndarray:
    return invariant_mass(four_momenta(qop.reshape(-1), tx.reshape(-1), ty.reshape(-1), KAON_MASS).reshape(-1, 4, 4))


def _sigma(masses) -> dict:
    fit = fit_mass_peak(masses, MASS_WINDOW_MEV)
    return {"sigma": fit.sigma, "sigma_error": fit.sigma_error, "n": int(np.size(masses)), "status": fit.status}


def analyse(run_dir: Path) -> dict:
    (run,) = load_runs([run_dir])
    missing = [f for f in FITTERS if f not in run.fitters]
    if missing:
        raise SystemExit(f"{run_dir}: run has no fitter {', '.join(missing)}")
    truth = load_truth(run)
    if truth.status != "ok":
        raise SystemExit(f"{run_dir}: {truth.status}")
    # production truth of every particle, looked up by key
    from pkf.pipeline.inputs import load_dataset

    _, dataset = load_dataset(run.dataset_path)
    parts = dataset.particles
    key = particle_key(column(parts, "event_id", np.int64), column(parts, "particle_id", np.int64))
    order = np.argsort(key)
    px, py, pz, charge = (column(parts, c)[order] for c in ("px", "py", "pz", "charge"))
    key = key[order]

    per_fitter = {}
    for name in FITTERS:
        chi2 = rows_of(run.table("chi2"), name)
        chi2_ok = chi2.filter(np.array(chi2.column("status").to_pylist()) == "ok")
        states = rows_of(run.table("states"), name, "beamline")
        decays, rows = bs_kaon_state_rows(truth, chi2_ok, states)
        per_fitter[name] = {c: column(states, c)[rows] for c in ("qop", "tx", "ty", "c44")}
        per_fitter[name]["decays"] = decays
    out = {"run": str(run_dir), "n_signal_decays": int(truth.n_bs), "fitters": {}}
    for name in FITTERS:
        s = per_fitter[name]
        out["fitters"][name] = {"own_candidates": _sigma(_masses(s["qop"], s["tx"], s["ty"]))}

    # the common candidates, kaons in the same order
    common, ia, ib = np.intersect1d(per_fitter["parametrized"]["decays"], per_fitter["reference"]["decays"],
                                    return_indices=True)
    par = {c: v[ia] for c, v in per_fitter["parametrized"].items() if c != "decays"}
    ref = {c: v[ib] for c, v in per_fitter["reference"].items() if c != "decays"}
    m_par, m_ref = _masses(par["qop"], par["tx"], par["ty"]), _masses(ref["qop"], ref["tx"], ref["ty"])
    out["common"] = mass_ratio_on_common_candidates(m_par, m_ref)
    kaon_keys = truth.kaon_keys[common]
    pos = np.searchsorted(key, kaon_keys)
    p_true = np.sqrt(px[pos] ** 2 + py[pos] ** 2 + pz[pos] ** 2)
    qop_true, tx_true, ty_true = charge[pos] / p_true, px[pos] / pz[pos], py[pos] / pz[pos]
    out["components"] = {
        "p_parametrized_direction_reference": _sigma(_masses(par["qop"], ref["tx"], ref["ty"])),
        "p_reference_direction_parametrized": _sigma(_masses(ref["qop"], par["tx"], par["ty"])),
        "p_parametrized_direction_true": _sigma(_masses(par["qop"], tx_true, ty_true)),
        "p_reference_direction_true": _sigma(_masses(ref["qop"], tx_true, ty_true)),
        "p_true_direction_parametrized": _sigma(_masses(qop_true, par["tx"], par["ty"])),
        "p_true_direction_reference": _sigma(_masses(qop_true, ref["tx"], ref["ty"])),
    }
    kaons = {}
    for name, s in (("parametrized", par), ("reference", ref)):
        dp = (1.0 / np.abs(s["qop"]) - p_true) / p_true
        dtx, dty = s["tx"] - tx_true, s["ty"] - ty_true
        pull = (s["qop"] - qop_true) / np.sqrt(s["c44"])
        bins = []
        for lo, hi in zip(P_EDGES[:-1], P_EDGES[1:]):
            m = (p_true >= lo) & (p_true < hi)
            g, gx, gy, gp = (gaussian_core(v[m]) for v in (dp, dtx, dty, pull))
            bins.append({"p_min": lo, "p_max": hi, "kaons": int(m.sum()),
                         "dp_over_p_core": g.sigma, "dp_over_p_core_error": g.sigma_error, "dp_over_p_mean": g.mean,
                         "tx_core_urad": 1e6 * gx.sigma, "ty_core_urad": 1e6 * gy.sigma, "qop_pull_width": gp.sigma})
        kaons[name] = bins
    out["kaons_at_beamline"] = kaons
    return out


def _print(result: dict) -> None:
    print(f"run {result['run']}: {result['n_signal_decays']} B_s decays")
    for name, r in result["fitters"].items():
        o = r["own_candidates"]
        print(f"{name:>13}: own candidates {o['n']:5d}  σ(m) = {o['sigma']:.2f} ± {o['sigma_error']:.2f} MeV ({o['status']})")
    c = result["common"]
    print(f"common candidates {c['n_candidates']}: σ(m) parametrized {c['fit']['sigma']:.2f} ± "
          f"{c['fit']['sigma_error']:.2f}, reference {c['reference_fit']['sigma']:.2f} ± "
          f"{c['reference_fit']['sigma_error']:.2f} MeV; ratio {c['sigma_ratio']:.3f} ± {c['sigma_ratio_error']:.3f} "
          f"(jackknife, {c['jackknife_groups']} groups)")
    print("σ(m) by component (common candidates):")
    for k, v in result["components"].items():
        print(f"  {k:<36} {v['sigma']:6.2f} ± {v['sigma_error']:.2f} MeV")
    print(f"{'p [GeV]':>10}{'kaons':>7} | {'δp/p core ×1e3 (mean)':>24} par / ref | {'ratio':>6} | tx core µrad par/ref |"
          f" qop pull width par/ref")
    for bp, br in zip(result["kaons_at_beamline"]["parametrized"], result["kaons_at_beamline"]["reference"]):
        rng = f"{bp['p_min'] / 1e3:.0f}–{bp['p_max'] / 1e3:.0f}" if bp["p_max"] < 1e6 else f"≥{bp['p_min'] / 1e3:.0f}"
        print(f"{rng:>10}{bp['kaons']:>7} | {1e3 * bp['dp_over_p_core']:6.3f} ({1e3 * bp['dp_over_p_mean']:+.3f}) / "
              f"{1e3 * br['dp_over_p_core']:6.3f} ({1e3 * br['dp_over_p_mean']:+.3f}) | "
              f"{bp['dp_over_p_core'] / br['dp_over_p_core']:6.3f} | {bp['tx_core_urad']:7.1f} / {br['tx_core_urad']:7.1f} | "
              f"{bp['qop_pull_width']:.2f} / {br['qop_pull_width']:.2f}")


def _jsonable(value):
    if isinstance(value, dict):
        return {k: _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, (float, np.floating)):
        return float(value) if math.isfinite(value) else None
    if isinstance(value, np.integer):
        return int(value)
    return value


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--run", type=Path, default=None, help="existing run directory with both fitters")
    parser.add_argument("--events", type=int, default=2000)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--out", type=Path, default=None, help="work directory (default: a temporary one)")
    parser.add_argument("--params", default=None, help="parameter file of the parametrized fitter")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    if args.run is None:
        work = args.out or Path(tempfile.mkdtemp(prefix="bs_mass_compare_"))
        work.mkdir(parents=True, exist_ok=True)
        dataset, run = work / "dataset", work / "run"
        t0 = time.perf_counter()
        run_simulation(SimulationConfig(generator="bs2phiphi", events=args.events, seed=args.seed), dataset,
                       overwrite=True)
        run_reconstruction(dataset, run, ReconstructionConfig(fitters=FITTERS, pattern="truth", params=args.params),
                           overwrite=True)
        print(f"simulated and reconstructed {args.events} events (seed {args.seed}) in "
              f"{time.perf_counter() - t0:.0f} s: {run}", file=sys.stderr)
        args.run = run
    result = analyse(args.run)
    _print(result)
    if args.json:
        args.json.write_text(json.dumps(_jsonable(result), indent=2) + "\n")


if __name__ == "__main__":
    main()
