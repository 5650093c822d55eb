"""Fit quality on real events, per fitter × track type × momentum bin (issue 15, deliverable 5).

Simulates lhcb-like minimum bias (default ν = 7.6; ``--generator pythia``: Pythia 8 pp events) and reconstructs it with the triplet pattern
and the requested fitters through the CLI, exactly as a user runs it (or reads an existing run
with --run), then tabulates for the *real* (non-ghost, MC-matched) candidates of each fitter and
track type (``long``, ``upstream`` = VELO+UT, ``velo``; the chi2 table's ``track_type`` column,
else the hit counts, `pkf.report.metrics.track_types`), overall and in bins of the true momentum:

- share fitted: candidates with status ``ok`` / real candidates (and the failures by status);
- χ²/ndf mean of the fitted ones;
- pulls at the first hit (x, y, tx, ty, q/p): Gaussian-core mean and width
  (`pkf.report.metrics.pull_summary`, i.e. `pkf.params.gauss.gaussian_core`) and RMS;
- δp/p at the first hit: Gaussian-core width [%] (`pkf.report.metrics.delta_p_over_p`).

Prints one table per fitter and writes everything as JSON with --json::

    python benchmarks/fit_quality.py [--events 60] [--seed 31] [--pileup 7.6] [--generator minbias|pythia] [--work DIR]
        [--fitter parametrized --fitter reference ...] [--run RUN_DIR] [--species electron] [--json out.json]

``--species electron`` keeps the real tracks matched to electrons only: the GSF assumes an
electron and is judged on electrons (on pions its Bethe–Heitler tail widens the q/p error).
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
from pathlib import Path

from dataclasses import dataclass

import numpy as np
import pyarrow as pa
import pyarrow.dataset as ds

from pkf.report.metrics import TRACK_TYPES, delta_p_over_p, lookup_sorted, pull_summary, track_types
from pkf.report.runs import column, rows_of
from pkf.params.gauss import gaussian_core
from pkf.simulation.species import SPECIES

FITTERS = ("parametrized", "reference", "gx2f", "gsf")
#: True-momentum bins [GeV] (the issue's acceptance bins, plus everything below 1.5 GeV).
P_EDGES_GEV = (0.0, 1.5, 3.0, 5.0, 10.0, 100.0, np.inf)
PULL_PARAMETERS = ("x", "y", "tx", "ty", "qop")
LOCATION = "first_hit"
KEY = 1 << 32


def _cli(*args: str) -> None:
    subprocess.run([sys.executable, "-m", "pkf.cli", *args], check=True, env=os.environ.copy())


def make_run(work: Path, events: int, seed: int, pileup: float, fitters, workers: int,
             generator: str = "minbias") -> Path:
    """Simulate (once) and reconstruct the sample under `work`; returns the run directory."""
    dataset = work / f"{generator}_nu{pileup}_ev{events}_s{seed}"
    if not (dataset / "meta.json").exists():
        _cli("simulate", "--generator", generator, "--pileup", str(pileup), "--events", str(events),
             "--seed", str(seed), "--out", str(dataset), "--overwrite")
    run = work / f"run_{generator}"
    fitter_args = [a for f in fitters for a in ("--fitter", f)]
    _cli("reconstruct", str(dataset), "--out", str(run), "--overwrite", "--workers", str(workers), *fitter_args)
    return run


def _true_particles(dataset: Path, event: np.ndarray, particle: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """|p| [MeV] and |PDG code| of each (event, particle) from the dataset's particles table
    (NaN and 0 if absent)."""
    t = ds.dataset(dataset / "particles.parquet" if (dataset / "particles.parquet").exists()
                   else dataset / "particles").to_table(columns=["event_id", "particle_id", "pdg", "px", "py", "pz"])
    key = column(t, "event_id", np.int64) * KEY + column(t, "particle_id", np.int64)
    p = np.sqrt(column(t, "px") ** 2 + column(t, "py") ** 2 + column(t, "pz") ** 2)
    pdg = np.abs(column(t, "pdg", np.int64))
    order = np.argsort(key)
    pos, found = lookup_sorted(key[order], event * KEY + particle)
    return np.where(found, p[order][pos], np.nan), np.where(found, pdg[order][pos], 0)


@dataclass
class _Run:
    fitters: list
    chi2: pa.Table
    states: pa.Table
    pulls: pa.Table | None
    dataset_path: Path


def _read_run(run_dir: Path) -> _Run:
    """The tables of a run as stored (plain pyarrow: also runs of older pkf versions, whose
    chi2 table has no track_type column and which `pkf.report.runs.load_run` refuses)."""
    info = json.loads((run_dir / "run.json").read_text())
    tables = {name: ds.dataset(run_dir / name).to_table() if (run_dir / name).exists() else None
              for name in ("chi2", "states", "pulls")}
    fitters = info["config"]["fitters"]
    return _Run(fitters, tables["chi2"], tables["states"], tables["pulls"], Path(info["input"]["path"]))


def _track_key(table) -> np.ndarray:
    return column(table, "event_id", np.int64) * KEY + column(table, "track_id", np.int64)


def _cell(real_status, real_chi2_ndf, pulls, dpp) -> dict:
    """The statistics of one (fitter, type, p bin) cell."""
    n = int(real_status.size)
    ok = real_status == "ok"
    failures = {}
    for s in np.unique(real_status[~ok]):
        failures[str(s)] = int(np.sum(real_status == s))
    chi = real_chi2_ndf[ok]
    chi = chi[np.isfinite(chi)]
    out = {"n_real": n, "n_ok": int(ok.sum()), "share_ok": float(ok.mean()) if n else None,
           "failures": failures, "chi2_ndf_mean": float(chi.mean()) if chi.size else None,
           "pulls": {}, "dp_over_p": None}
    for name in PULL_PARAMETERS:
        v = pulls[name]
        out["pulls"][name] = pull_summary(v) if np.isfinite(v).sum() >= 10 else {"n": int(np.isfinite(v).sum())}
    finite = dpp[np.isfinite(dpp)]
    if finite.size >= 10:
        core = gaussian_core(finite)
        out["dp_over_p"] = {"n": int(finite.size), "core_sigma_percent": 100.0 * core.sigma,
                            "rms_percent": 100.0 * float(np.sqrt(np.mean(finite ** 2)))}
    return out


def analyse(run_dir: Path, dataset: Path | None = None, species: str = "all") -> dict:
    """Per fitter × track type × p bin statistics of a run (see the module docstring), of the
    real tracks matched to particles of `species` (a name of `SPECIES`, or "all")."""
    run = _read_run(run_dir)
    dataset = dataset or run.dataset_path
    if run.pulls is None:
        raise SystemExit(f"{run_dir}: no pulls table (the dataset has no MC truth)")
    result = {"run": str(run_dir), "dataset": str(dataset), "location": LOCATION,
              "species": species, "p_edges_gev": [float(e) for e in P_EDGES_GEV], "fitters": {}}
    for fitter in run.fitters:
        chi2 = rows_of(run.chi2, fitter)
        real = ~column(chi2, "is_ghost", bool) & (column(chi2, "mc_particle_id", np.int64) > 0)
        chi2 = chi2.filter(real)
        p_true, pdg = _true_particles(dataset, column(chi2, "event_id", np.int64),
                                      column(chi2, "mc_particle_id", np.int64))
        if species != "all":
            chi2 = chi2.filter(pdg == SPECIES[species][0])
            p_true = p_true[pdg == SPECIES[species][0]]
        types = track_types(chi2)
        status = np.asarray(chi2.column("status").to_pylist(), dtype=object)
        chi2_ndf = column(chi2, "chi2_ndf")
        # pulls (first hit) of the same tracks, aligned to the chi2 rows
        pulls_table = rows_of(run.pulls, fitter, LOCATION)
        pkey = _track_key(pulls_table)
        order = np.argsort(pkey)
        pos, found = lookup_sorted(pkey[order], _track_key(chi2))
        pulls = {}
        for name in PULL_PARAMETERS:
            v = column(pulls_table, f"pull_{name}")[order][pos]
            pulls[name] = np.where(found, v, np.nan)
        dpp_all = delta_p_over_p(pulls_table, rows_of(run.states, fitter, LOCATION))[order][pos]
        dpp = np.where(found, dpp_all, np.nan)
        per_type = {}
        for track_type in TRACK_TYPES + ("all",):
            in_type = np.ones(types.size, bool) if track_type == "all" else types == track_type
            bins = []
            for lo, hi in zip(P_EDGES_GEV[:-1], P_EDGES_GEV[1:]):
                sel = in_type & (p_true >= lo * 1e3) & (p_true < hi * 1e3)
                bins.append(_cell(status[sel], chi2_ndf[sel], {k: v[sel] for k, v in pulls.items()}, dpp[sel]))
            per_type[track_type] = {"all": _cell(status[in_type], chi2_ndf[in_type],
                                                 {k: v[in_type] for k, v in pulls.items()}, dpp[in_type]),
                                    "bins": bins}
        result["fitters"][fitter] = per_type
    return result


def _fmt(v, spec=".2f") -> str:
    return "-" if v is None else format(v, spec)


def _width(cell, name) -> str:
    p = cell["pulls"].get(name, {})
    if "width" not in p:
        return "   -/-   "
    return f"{_fmt(p['width'])}/{_fmt(p['rms'])}"


def print_tables(result: dict) -> None:
    """One table per fitter: rows type × p bin; pull columns 'core width/RMS'."""
    edges = result["p_edges_gev"]
    labels = [f"{lo:g}-{hi:g}" for lo, hi in zip(edges[:-1], edges[1:])]
    head = (f"{'type':9s}{'p [GeV]':>10s}{'real':>7s}{'ok %':>8s}{'χ²/ndf':>8s}"
            + "".join(f"{'pull ' + n:>12s}" for n in PULL_PARAMETERS) + f"{'δp/p %':>8s}  failures")
    for fitter, per_type in result["fitters"].items():
        of = "" if result["species"] == "all" else f" matched to {result['species']}s"
        print(f"\n== {fitter} (first hit; pulls: core width/RMS; real = non-ghost matched candidates{of})")
        print(head)
        for track_type, data in per_type.items():
            rows = [("all", data["all"])] + list(zip(labels, data["bins"]))
            for label, cell in rows:
                if cell["n_real"] == 0:
                    continue
                share = None if cell["share_ok"] is None else 100.0 * cell["share_ok"]
                dpp = cell["dp_over_p"]["core_sigma_percent"] if cell["dp_over_p"] else None
                fails = ", ".join(f"{k}: {v}" for k, v in cell["failures"].items())
                print(f"{track_type:9s}{label:>10s}{cell['n_real']:7d}{_fmt(share, '.2f'):>8s}"
                      f"{_fmt(cell['chi2_ndf_mean']):>8s}"
                      + "".join(f"{_width(cell, n):>12s}" for n in PULL_PARAMETERS)
                      + f"{_fmt(dpp, '.3f'):>8s}  {fails}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--events", type=int, default=60)
    parser.add_argument("--seed", type=int, default=31)
    parser.add_argument("--pileup", type=float, default=7.6)
    parser.add_argument("--generator", choices=("minbias", "pythia"), default="minbias",
                        help="pkf's minimum bias or Pythia 8 pp events (needs the pythia extra)")
    parser.add_argument("--fitter", action="append", choices=FITTERS)
    parser.add_argument("--workers", type=int, default=1)
    parser.add_argument("--work", type=Path, default=Path("/tmp/pkf-fit-quality"))
    parser.add_argument("--run", type=Path, help="analyse this existing run instead of making one")
    parser.add_argument("--dataset", type=Path, help="its dataset (default: the one run.json names)")
    parser.add_argument("--species", choices=("all", *SPECIES), default="all",
                        help="only the real tracks of this species (e.g. electron for the GSF)")
    parser.add_argument("--json", type=Path)
    args = parser.parse_args(argv)
    run = args.run
    if run is None:
        args.work.mkdir(parents=True, exist_ok=True)
        run = make_run(args.work, args.events, args.seed, args.pileup, args.fitter or FITTERS, args.workers,
                       args.generator)
    result = analyse(run, args.dataset, args.species)
    print_tables(result)
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
