"""`pkf demo`: the whole chain on the built-in default, in one go (docs/cli.md).

Simulates B_s⁰ → φφ events (on minimum bias) in the lhcb-like detector, reconstructs
them with the parametrized and the reference Kalman fitter, and prints the headline
numbers: pull widths and momentum resolution of each fitter, their ratio, the fit
speed-up — each computed from the written run tables — and, from the report, the B_s
mass resolution of each fitter and their ratio on the same candidates (decays with four
long kaons that both fitters fitted, `pkf.report.metrics`).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from pkf.io.reader import read_table
from pkf.io.schemas import PULLS
from pkf.pipeline.reconstruct import ReconstructionConfig, run_reconstruction
from pkf.pipeline.report import run_report
from pkf.pipeline.simulate import SimulationConfig, run_simulation
from pkf.params.gauss import gaussian_core
from pkf.report.runs import verify_run_files

DEMO_FITTERS = ("parametrized", "reference")


def headline_numbers(run_dir: Path) -> dict:
    """Pull widths and δp/p core per fitter at the first hit, and the fit speed-up.

    Raises:
        InputError: a partition file of the run does not match run.json.
    """
    run = json.loads((run_dir / "run.json").read_text())
    verify_run_files(run_dir, run)
    pulls = read_table(run_dir, PULLS, name="pulls").to_pydict()
    fitter = np.array(pulls["fitter"])
    first = np.array(pulls["location"]) == "first_hit"
    out = {}
    for name in sorted(set(fitter)):
        sel = first & (fitter == name)
        # δ(q/p)/|q/p| = ∓δp/p: the same width as δp/p (the sign is the charge's)
        dp = np.array(pulls["res_qop"])[sel] * np.array(pulls["p_true"])[sel]
        out[name] = {
            "tracks": int(sel.sum()),
            "pull_width": {c: gaussian_core(np.array(pulls[f"pull_{c}"])[sel]).sigma for c in ("x", "y", "tx", "ty", "qop")},
            "dp_over_p_core": gaussian_core(dp).sigma,
            "tracks_per_s": run["timing"]["fit"][name]["tracks_per_s"],
        }
    passes = run["config"].get("fit_iterations") or {}
    for name in out:
        out[name]["passes"] = passes.get(name)
    if "parametrized" in out and "reference" in out:
        out["speed_up"] = out["parametrized"]["tracks_per_s"] / out["reference"]["tracks_per_s"]
        out["resolution_ratio"] = out["parametrized"]["dp_over_p_core"] / out["reference"]["dp_over_p_core"]
    return out


def run_demo(out: Path, events: int, seed: int, overwrite: bool, echo=print) -> dict:
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    dataset, run_dir = out / "dataset", out / "run"
    meta = run_simulation(SimulationConfig(generator="bs2phiphi", events=events, seed=seed), dataset,
                          overwrite=overwrite)
    echo(f"simulated {meta['counts']['events']} B_s -> phi phi events ({meta['counts']['hits']} hits) into {dataset}")
    run_reconstruction(dataset, run_dir, ReconstructionConfig(fitters=DEMO_FITTERS, pattern="truth"),
                       overwrite=overwrite)
    echo(f"reconstructed with {', '.join(DEMO_FITTERS)} (ideal pattern recognition) into {run_dir}")
    numbers = headline_numbers(run_dir)
    for name in DEMO_FITTERS:
        n = numbers[name]
        widths = ", ".join(f"{c} {w:.2f}" for c, w in n["pull_width"].items())
        echo(f"{name:>12}: {n['tracks']} matched tracks; pull widths {widths}; "
             f"dp/p core {100 * n['dp_over_p_core']:.2f}%; {n['tracks_per_s']:.0f} tracks/s")
    echo(f"momentum resolution parametrized/reference: {numbers['resolution_ratio']:.3f}; "
         f"fit speed-up: {numbers['speed_up']:.1f}x (fit passes: parametrized "
         f"{numbers['parametrized']['passes']}, reference {numbers['reference']['passes']})")
    summary = run_report([(run_dir, "demo")], out / "report", overwrite=overwrite)
    for name in DEMO_FITTERS:
        mass = summary["entries"][f"demo/{name}"].get("mass") or {}
        fit = mass.get("fit") or {}
        if fit.get("sigma") is not None:
            echo(f"{name:>12}: B_s mass resolution {fit['sigma']:.1f} ± {fit.get('sigma_error') or 0:.1f} MeV "
                 f"from {mass.get('n_candidates')} candidates")
        else:
            echo(f"{name:>12}: no B_s mass fit ({mass.get('note', 'too few candidates')})")
    common = (summary["entries"]["demo/parametrized"].get("mass") or {}).get("ratio_to_reference")
    if common and common.get("sigma_ratio") is not None:
        error = common.get("sigma_ratio_error")
        numbers["mass_resolution_ratio"] = common["sigma_ratio"]
        numbers["mass_resolution_ratio_error"] = error
        echo(f"B_s mass resolution parametrized/reference on the same {common['n_candidates']} candidates: "
             f"{common['sigma_ratio']:.3f}" + (f" ± {error:.3f}" if error is not None else "") +
             f" ({common['fit']['sigma']:.1f} vs {common['reference_fit']['sigma']:.1f} MeV)")
    echo(f"report: {out / 'report' / 'index.html'}")
    echo("pattern recognition was the ideal (MC) grouping, to compare the fitters on the same "
         "tracks; `pkf reconstruct` uses the triplet pattern recognition by default")
    return numbers
