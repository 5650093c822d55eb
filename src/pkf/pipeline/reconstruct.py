"""The `pkf reconstruct` stage: pattern recognition, fits, MC matching, run tables (docs/formats.md).

The dataset is validated in bounded memory and cut into partitions of at most
``events_per_batch`` events of one input file (:mod:`pkf.pipeline.plan`); each
partition is reconstructed on its own (:mod:`pkf.pipeline.batch`) by an executor —
this process, local worker processes, or a Dask scheduler (:mod:`pkf.pipeline.executor`)
— and written as one Parquet file per run table: ``RUN/chi2/part-FFFF-BBBBB.parquet``
and so on for ``candidates``, ``states`` and ``pulls`` (when MC is present).
``run.json`` lists the partitions with the SHA-256 of every file. The run is built in
``.RUN.partial/`` and renamed into place at the end; a rerun resumes it
(:mod:`pkf.pipeline.resume`).
"""

from __future__ import annotations

import time
from dataclasses import replace
from pathlib import Path

import numpy as np

import pkf
from pkf.errors import InputError
from pkf.geometry.detector import BUILTIN_GEOMETRIES
from pkf.io.atomic import atomic_write_json, check_output_apart, check_output_dir
from pkf.io.stream import close_readers, file_sha256
from pkf.pipeline import triplet_pattern
from pkf.pipeline.allocator import keep_freed_memory
from pkf.pipeline.batch import StageClock, metrics_from_counts
from pkf.pipeline.config import ReconstructionConfig
from pkf.pipeline.executor import PartitionTask, default_workers, execute, kernels_ready, reconstruct_task
from pkf.pipeline.plan import DatasetPlan, plan_dataset, with_keys
from pkf.pipeline.progress import PartitionProgress, progress_bar
from pkf.pipeline.resume import RunStaging, complete_run

#: Default events per partition: bounds each worker's memory (~8000 hits per event at ν = 7.6,
#: about 0.6 GiB per worker at 50 events).
EVENTS_PER_BATCH = 50
def geometry_file(option: str | None) -> str | None:
    """``--geometry`` when it names a file (an input of the run), else None."""
    return None if option is None or option in BUILTIN_GEOMETRIES else option


def _check_config_against(plan: DatasetPlan, config: ReconstructionConfig) -> None:
    """Problems of the configuration for this dataset, before any work (docs/cli.md#exit-codes-and-messages)."""
    if config.pattern == "truth" and not plan.has_mc:
        raise InputError(f"{plan.path}: --pattern truth needs mc_hits, and the dataset has none")
    from pkf.params.parameter_set import load_parameters

    if config.params is not None or config.pattern == "triplet" or "parametrized" in config.fitters:
        load_parameters(plan.geometry, config.params)  # InputError for a file of another geometry
    if config.pattern == "triplet":
        from pkf.seeding.forward.prepare import layout

        try:  # a detector the triplet pattern cannot search (the telescope): say so before any work
            layout(plan.geometry)
        except InputError as error:
            raise InputError(f"{error}; the triplet pattern (the default) cannot search it: "
                             "reconstruct it with --pattern truth") from None


def _tasks(plan: DatasetPlan, config, staging: Path) -> list[PartitionTask]:
    import numba

    light = {name: replace(scan, events=np.zeros(0, np.int64), starts=np.zeros(0, np.int64))
             for name, scan in plan.tables.items()}
    tasks = []
    for p in plan.partitions:
        tables = {"hits": (light["hits"], *p.hits_rows)}
        for name in ("particles", "mc_hits"):
            if name in plan.tables:
                tables[name] = (light[name], *plan.tables[name].rows_of_events(p.first_event, p.last_event + 1))
        tasks.append(PartitionTask(p.name, p.key, str(plan.path.resolve()), config.to_dict(), tables, str(staging),
                                   str(numba.config.CACHE_DIR)))
    return tasks


def run_reconstruction(dataset_path: str | Path, out: str | Path, config: ReconstructionConfig,
                       overwrite: bool = False, progress: bool | None = None, workers: int | None = 1,
                       scheduler: str | None = None, events_per_batch: int = EVENTS_PER_BATCH,
                       echo=None) -> dict:
    """Reconstruct the dataset at `dataset_path` into the run directory `out`; returns run.json.

    workers: local worker processes (None: all cores; 1: this process).
    scheduler: address of a Dask distributed scheduler (then ``workers`` is ignored).
    events_per_batch: events per partition (memory per worker grows with it).
    echo: called with a line of news (e.g. resumed partitions), if given.
    """
    wall0 = time.perf_counter()
    keep_freed_memory()  # batches reuse freed arrays instead of faulting in new pages (pkf.pipeline.allocator)
    config.validate()
    dataset_path = Path(dataset_path)
    workers = default_workers() if workers is None else workers
    if workers < 1:
        raise InputError(f"--workers: must be >= 1, not {workers}")
    inputs = (dataset_path, config.params, geometry_file(config.geometry))
    check_output_apart(out, inputs)  # before anything: --overwrite would delete an input inside --out
    final = Path(out)
    maybe_complete = not overwrite and final.is_dir() and (final / "run.json").is_file()
    if not maybe_complete:
        check_output_dir(out, overwrite)
    validation: dict = {}
    with StageClock(validation, "validate"):  # the whole dataset, before any work (docs/cli.md)
        plan = plan_dataset(dataset_path, events_per_batch, config.geometry)
        _check_config_against(plan, config)
    if echo:
        for line in plan.warnings():
            echo(f"pkf: warning: {line}")
    run_config = config.to_dict() | {"events_per_batch": events_per_batch,
                                     "fit_iterations": {f.name: config.fit_options(f).kalman.iterations
                                                        for f in config.validate()}}
    if config.params is not None and Path(config.params).is_file():
        run_config["params_sha256"] = file_sha256(config.params)
    if geometry_file(config.geometry) is not None:
        run_config["geometry_sha256"] = file_sha256(config.geometry)
    plan = with_keys(plan, run_config)
    keys = {p.name: p.key for p in plan.partitions}
    if maybe_complete:
        info = complete_run(final, keys)
        if info is None:
            raise InputError(f"{out}: output directory exists and is not empty (use --overwrite to replace it)")
        if echo:
            echo(f"{out} is complete: all {len(keys)} partitions are done and intact")
        return info

    with RunStaging(out, overwrite, inputs) as staging:
        done = staging.finished(keys)
        if done and echo:
            echo(f"resuming: {len(done)} of {len(keys)} partitions already done")
        todo = [t for t in _tasks(plan, config, staging.path) if t.name not in done]
        events_of = {p.name: p.n_events for p in plan.partitions}
        use_workers = 1 if scheduler is None and (workers <= 1 or len(todo) <= 1) else workers
        if todo and (use_workers > 1 or scheduler is not None) and not kernels_ready(todo[0]):
            reconstruct_task(todo[0], max_events=1)  # compile or load kernels here: workers load the cache
        with progress_bar(plan.n_events, "reconstruct", progress=progress,
                          initial=sum(events_of[n] for n in done)) as bar:
            events_done = PartitionProgress(bar, events_of)

            def on_done(entry):
                done[entry["name"]] = entry
                events_done.finish(entry["name"])

            t0 = time.perf_counter()
            try:
                execute(todo, use_workers, scheduler, on_done, events_done.advance)
            finally:
                close_readers()  # the input files this process read partitions of
            work_wall = time.perf_counter() - t0
        run = _run_json(plan, run_config, done, dataset_path)
        run["timing"] = validation | run["timing"]
        run["execution"] = {"workers": None if scheduler else use_workers, "scheduler": scheduler,
                            "partitions": len(keys), "resumed_partitions": len(keys) - len(todo),
                            "events_processed": sum(events_of[t.name] for t in todo),
                            "wall_s": work_wall, "total_wall_s": time.perf_counter() - wall0}
        w = run["execution"]
        w["events_per_s"] = w["events_processed"] / work_wall if work_wall > 0 and todo else None
        atomic_write_json(run, staging.path / "run.json")
        staging.finish()
    crowded = run["counts"]["events_over_hit_limit"]
    if crowded and echo:
        echo(f"pkf: warning: {crowded} event(s) with more than {triplet_pattern.MAX_EVENT_HITS} hits not "
             f"searched by the triplet pattern (its cost per hit grows with the occupancy): event ids "
             f"{run['counts']['events_over_hit_limit_ids']}, counted in run.json counts.events_over_hit_limit")
    return run


def _run_json(plan: DatasetPlan, run_config: dict, done: dict, dataset_path: Path) -> dict:
    """run.json from the partitions' journal entries, summed in partition order."""
    entries = [done[p.name] for p in plan.partitions]
    fitters = list(run_config["fitters"])
    counts = {"events": 0, "hits": 0, "candidates": 0, "tracks": {f: 0 for f in fitters},
              "below_p_min": {f: 0 for f in fitters}, "events_over_hit_limit": 0}
    crowded_ids: list = []
    timing: dict = {}
    fit = {f: {"wall_s": 0.0, "tracks": 0, "nodes": 0} for f in fitters}
    pattern = {"pattern": None, "velo": None}
    for e in entries:
        s = e["summary"]
        for k in ("events", "hits", "candidates"):
            counts[k] += s[k]
        if "events_over_hit_limit" in s:
            counts["events_over_hit_limit"] += s["events_over_hit_limit"]["events"]
            crowded_ids += s["events_over_hit_limit"]["event_ids"]
        for f in fitters:
            counts["tracks"][f] += s["tracks"][f]
            counts["below_p_min"][f] += s.get("below_p_min", {}).get(f, 0)
            for k in fit[f]:
                fit[f][k] += s["fit"][f][k]
        for stage, t in s["timing"].items():
            entry = timing.setdefault(stage, {"wall_s": 0.0, "cpu_s": 0.0})
            entry["wall_s"] += t["wall_s"]
            entry["cpu_s"] += t["cpu_s"]
        for k in pattern:
            if k in s:
                pattern[k] = {c: (pattern[k] or {}).get(c, 0) + v for c, v in s[k].items()}
    run = {
        "pkf_version": pkf.__version__,
        "kind": "run",
        "config": run_config | {"dataset": str(dataset_path)},
        "input": {"path": str(dataset_path.resolve()), "content_hash": plan.content_hash,
                  "geometry": plan.geometry.name, "geometry_hash": plan.geometry.content_hash,
                  "geometry_from": ("--geometry " + run_config["geometry"] if run_config.get("geometry")
                                    else "meta.json"),
                  "ignored_columns": {name: list(scan.ignored_columns) for name, scan in plan.tables.items()
                                      if scan.ignored_columns},
                  "files": {name: [{"path": str(f), "sha256": h} for f, h in zip(scan.files, scan.sha256)]
                            for name, scan in plan.tables.items()}},
        "counts": counts,
        "timing": _timing_json(timing, fit),
        "partitions": [{"name": p.name, "key": p.key, "first_event": p.first_event, "last_event": p.last_event,
                        "events": p.n_events, "input_file": str(plan.tables["hits"].files[p.file_index]),
                        "hits_rows": list(p.hits_rows), "files": done[p.name]["files"]}
                       for p in plan.partitions],
    }
    if crowded_ids:
        run["counts"]["events_over_hit_limit_ids"] = crowded_ids[:10]
    if plan.has_mc and pattern["pattern"] is not None:
        run["pattern"] = metrics_from_counts(pattern["pattern"])
        run["pattern"]["definition"] = ("long tracks (with SciFi hits) against long-reconstructible "
                                        "particles (docs/physics.md#matching-and-metrics)")
        run["pattern"]["velo"] = metrics_from_counts(pattern["velo"])
    return run


def _timing_json(timing: dict, fit_stats: dict) -> dict:
    """Per stage wall_s/cpu_s summed over partitions; per fitter speeds (after JIT warm-up).

    ``tracks_per_s`` and ``ns_per_node`` divide by the CPU time of the fitter's kernels summed
    over workers, not by wall time: with several workers sharing the cores, wall time counts the
    waits for a core and the speed would depend on ``--workers`` (docs/formats.md). ``wall_s`` stays
    recorded beside it.
    """
    out = {stage: dict(t) for stage, t in timing.items() if not stage.startswith("fit.")}
    out["fit"] = {}
    for name, stats in fit_stats.items():
        cpu = timing.get(f"fit.{name}", {}).get("cpu_s", 0.0)
        out["fit"][name] = {
            "wall_s": stats["wall_s"], "cpu_s": cpu, "tracks": stats["tracks"], "nodes": stats["nodes"],
            "tracks_per_s": stats["tracks"] / cpu if cpu > 0 else None,
            "ns_per_node": 1e9 * cpu / stats["nodes"] if stats["nodes"] and cpu > 0 else None,
        }
    return out
