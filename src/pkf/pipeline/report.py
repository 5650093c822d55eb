"""The `pkf report` stage: run directories → REPORT/ with summary.json, index.html and PNG plots (docs/formats.md#summaryjson).

Inputs are validated and every number is computed before anything is written;
the report directory is then built in a hidden staging directory and renamed into
place (:func:`pkf.io.atomic.staged_output_dir`), so bad input or a crash leaves no
partial report. The summary.json keys are documented in :mod:`pkf.report.metrics`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from pkf.io.atomic import atomic_write_json, check_output_apart, check_output_dir, staged_output_dir
from pkf.io.schemas import particle_key
from pkf.io.reader import Dataset
from pkf.io.stream import read_rows
from pkf.physics.constants import PDG_BS, PDG_KAON, PDG_PHI
from pkf.pipeline.inputs import STATE_NAMES, align_mc
from pkf.pipeline.plan import plan_dataset
from pkf.pipeline.progress import progress_bar
from pkf.pipeline.matching import reconstructible_sets
from pkf.report.html import render_html
from pkf.report.metrics import ETA_EDGES, P_EDGES_MEV, DatasetTruth, bin_index, compute_report, lookup_sorted
from pkf.report.runs import RunInput, column, load_runs, parse_run_spec

__all__ = ["run_report", "load_truth", "load_truths", "REPORT_FILES"]

#: Files every report holds (plus the PNG plots that have data).
REPORT_FILES = ("index.html", "summary.json")


def run_report(run_specs: list, out: Path, overwrite: bool = False, reference: str | None = None,
               echo=None, progress: bool | None = None) -> dict:
    """Write the report of the runs ``run_specs`` into the directory ``out``; return the summary.

    Args:
        run_specs: run directories of `pkf reconstruct`, each a path, ``"RUN:LABEL"`` or a
            (path, label) pair (:func:`pkf.report.runs.parse_run_spec`); the same fitter may
            appear in several runs, whose labels must differ.
        out: report directory to create (``index.html``, ``summary.json``, PNG plots).
        overwrite: replace an existing non-empty ``out``.
        reference: ``LABEL/FITTER`` or ``LABEL`` of the entry that ratios compare with
            (default: the first ``reference`` fitter, else the first entry).
        echo: called with each warning line (e.g. runs from different datasets), if given.
        progress: bars over the events of the datasets and of the runs read (None: only when
            stderr is a terminal). Both are read one partition at a time, in bounded memory.

    Returns:
        the summary (the contents of summary.json, before NaN → null).

    Raises:
        InputError: bad or incomplete run directory, two runs with one label, an unknown
            reference, a malformed dataset, or an ``out`` that cannot be written (one
            line; nothing is written).
    """
    run_dirs = [parse_run_spec(spec)[0] for spec in run_specs]
    check_output_dir(out, overwrite, inputs=run_dirs)
    runs = load_runs(run_specs)
    inputs = [*run_dirs, *(run.dataset_path for run in runs)]
    check_output_apart(out, inputs)
    with progress_bar(None, "report: datasets", progress=progress) as bar:
        truths = load_truths(runs, bar.update)
    events = sum(int((run.info.get("counts") or {}).get("events") or 0) for run in runs)
    with progress_bar(events or None, "report: runs", progress=progress) as bar:
        data = compute_report(runs, truths, reference, bar.update)
    for line in data.summary["warnings"]:
        if echo:
            echo(line)

    from pkf.report.plots import make_plots  # matplotlib is imported only when a report is made

    with staged_output_dir(out, overwrite, inputs) as staging:
        plots = make_plots(data, staging)
        (staging / "index.html").write_text(render_html(data.summary, plots), encoding="utf-8")
        atomic_write_json(data.summary, staging / "summary.json")
    return data.summary


#: Events of the dataset read at a time for the report's MC truth (~40 MB at ν = 7.6).
TRUTH_EVENTS_PER_PART = 50
#: The columns of the dataset that the report's MC truth uses.
_TRUTH_COLUMNS = {"hits": ("event_id", "hit_id", "layer"),
                  "mc_hits": ("event_id", "hit_id", "particle_id", *STATE_NAMES),
                  "particles": ("event_id", "particle_id", "pdg", "px", "py", "pz", "parent_id", "from_signal")}


def load_truth(run: RunInput, progress=None) -> DatasetTruth:
    """Read the run's dataset (particles, mc_hits, hits, geometry) for efficiency and the B_s mass.

    The dataset is validated and read :data:`TRUTH_EVENTS_PER_PART` events at a time
    (:func:`pkf.pipeline.plan.plan_dataset`); only the truth the report needs is kept (a few
    numbers per reconstructible particle and per kaon). ``progress``, if given, is called with
    the number of events of each part.

    A missing dataset, one without MC truth or one that changed since the run gives a
    status saying so (the sections are then marked unavailable); a present but
    malformed dataset raises InputError.
    """
    path = run.dataset_path
    if path is None:
        return DatasetTruth("run.json names no dataset (input.path)")
    if not path.is_dir():
        return DatasetTruth(f"dataset {path} not found (moved or deleted since the run)")
    geometry_option = (run.info.get("config") or {}).get("geometry")  # the run's --geometry, if given
    if geometry_option is None and not (path / "meta.json").is_file():
        return DatasetTruth(f"{path} is not a dataset (no meta.json)")
    plan = plan_dataset(path, TRUTH_EVENTS_PER_PART, geometry_option)
    if not plan.has_mc or "particles" not in plan.tables:
        return DatasetTruth(f"dataset {path} has no MC truth (particles, mc_hits)")
    recorded = (run.info.get("input") or {}).get("content_hash")
    if recorded and recorded != plan.content_hash:
        return DatasetTruth(f"dataset {path} changed since the run (content hash differs from run.json)")

    parts = []
    bounds = [None] + [p.first_event for p in plan.partitions[1:]] + [None]  # tile every event id
    for k, partition in enumerate(plan.partitions):
        tables = {}
        for name, scan in plan.tables.items():
            lo, hi = partition.hits_rows if name == "hits" else scan.rows_of_events(bounds[k], bounds[k + 1])
            tables[name] = read_rows(scan, lo, hi, _TRUTH_COLUMNS[name])
        parts.append(_truth_of_part(plan.geometry, Dataset(path, {}, tables["hits"], tables["particles"],
                                                            tables["mc_hits"])))
        if progress is not None:
            progress(partition.n_events)
    reco = np.concatenate([part["reco"] for part in parts])
    order = np.argsort(reco, kind="stable")
    quads = np.concatenate([part["quads"] for part in parts])
    quads = quads[np.argsort(quads[:, 0], kind="stable")]  # as one dict over all kaons in key order
    by_type = {}
    for kind in ("upstream", "velo"):  # long: reco_key, reco_p_bin, reco_eta_bin
        keys = np.concatenate([part[kind][0] for part in parts])
        k_order = np.argsort(keys, kind="stable")
        by_type[kind] = tuple(np.concatenate([part[kind][i] for part in parts])[k_order] for i in range(3))
    return DatasetTruth("ok", plan.n_events, reco[order], np.concatenate([part["p"] for part in parts])[order],
                        np.concatenate([part["eta"] for part in parts])[order], quads,
                        sum(part["n_bs"] for part in parts), np.sort(np.concatenate([part["kaons"] for part in parts])),
                        by_type)


def _truth_of_part(geometry, dataset: Dataset) -> dict:
    """What :func:`load_truth` keeps of some whole events: the reconstructible particles' keys
    (sorted) and the bins of their true p and η (:func:`~pkf.report.metrics.bin_index` in
    P_EDGES_MEV and ETA_EDGES; long, and (keys, p bin, η bin) of the upstream and VELO
    reconstructible ones); the kaon keys of each B_s decay (rows of four, sorted); the number of B_s; the keys
    of every kaon."""
    hits = dataset.hits
    event_id = column(hits, "event_id", np.int64)
    particle, _ = align_mc(dataset, event_id)
    key = particle_key(event_id, particle)
    layer = column(hits, "layer", np.int64)
    reconstructible = reconstructible_sets(geometry, key, layer)  # sorted keys
    reco = reconstructible["long"]
    reco_of = {"upstream": reconstructible["upstream"], "velo": reconstructible["velo"]}

    parts = dataset.particles
    p_event = column(parts, "event_id", np.int64)
    p_id = column(parts, "particle_id", np.int64)
    p_key = particle_key(p_event, p_id)
    order = np.argsort(p_key)
    p_key_sorted = p_key[order]
    px, py, pz = (column(parts, c)[order] for c in ("px", "py", "pz"))
    pos, _ = lookup_sorted(p_key_sorted, reco)
    pt = np.hypot(px, py)
    p = np.sqrt(pt**2 + pz**2)
    with np.errstate(divide="ignore", invalid="ignore"):
        eta = -np.log(np.tan(0.5 * np.arctan2(pt, pz)))
    p_bin, eta_bin = bin_index(p, P_EDGES_MEV), bin_index(eta, ETA_EDGES)
    by_type = {}
    for kind, keys in reco_of.items():
        kpos, _ = lookup_sorted(p_key_sorted, keys)
        by_type[kind] = (keys, p_bin[kpos], eta_bin[kpos])

    # B_s → φφ, φ → K⁺K⁻: group signal kaons by their grand-parent
    pdg = column(parts, "pdg", np.int64)[order]
    parent = column(parts, "parent_id", np.int64)[order]
    signal = column(parts, "from_signal", bool)[order]
    ev_sorted = p_event[order]
    parent_key = particle_key(ev_sorted, parent)
    ppos, pfound = lookup_sorted(p_key_sorted, parent_key)
    parent_pdg = np.where(pfound, pdg[ppos], 0)
    grand_key = np.where(pfound, particle_key(ev_sorted, parent[ppos]), 0)
    gpos, gfound = lookup_sorted(p_key_sorted, grand_key)
    grand_pdg = np.where(pfound & gfound, pdg[gpos], 0)
    is_kaon = signal & (np.abs(pdg) == PDG_KAON) & (parent_pdg == PDG_PHI) & (np.abs(grand_pdg) == PDG_BS)
    bs = signal & (np.abs(pdg) == PDG_BS)
    kaons_of = {}
    for k_key, g_key in zip(p_key_sorted[is_kaon], grand_key[is_kaon]):
        kaons_of.setdefault(int(g_key), []).append(int(k_key))
    quads = [sorted(v) for v in kaons_of.values() if len(v) == 4]
    return {"reco": reco, "p": p_bin[pos], "eta": eta_bin[pos], "quads": np.array(quads, dtype=np.int64).reshape(-1, 4),
            "n_bs": int(bs.sum()), "kaons": p_key_sorted[np.abs(pdg) == PDG_KAON], **by_type}


def load_truths(runs: list[RunInput], progress=None) -> list[DatasetTruth | None]:
    """`load_truth` of each run with MC truth (None for the others), each dataset read once
    (``progress``: see :func:`load_truth`)."""
    by_path: dict[Path, DatasetTruth] = {}
    truths = []
    for run in runs:
        if not run.has_mc:
            truths.append(None)
        elif run.dataset_path is None:
            truths.append(load_truth(run))
        else:
            key = run.dataset_path.resolve()
            if key not in by_path:
                by_path[key] = load_truth(run, progress)
            truths.append(by_path[key])
    return truths
