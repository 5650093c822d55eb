"""The `pkf tune` stage: fit the parametrized extrapolations on a simulated dataset (docs/parameters.md#how-the-coefficients-are-tuned).

Before any work (the UT→SciFi tabulation alone takes ~2–4 min) the output file is
checked (:func:`check_output_file`) and every step of the geometry must have the state
pairs its fits need (:func:`pkf.params.tuning.required_pairs`); too little data is
refused with one line that names the steps and the events it would take, rather than a
parameter file with zeros in the steps that could not be fitted.
"""

from __future__ import annotations

import datetime
import math
import os
import time
from pathlib import Path

import numpy as np

import pkf
from pkf.errors import InputError
from pkf.geometry.detector import BUILTIN_GEOMETRIES, Geometry
from pkf.io.reader import extra_columns_warning
from pkf.io.atomic import check_output_apart
from pkf.io.schemas import particle_key
from pkf.params.parameter_set import ParameterSet, slot_structure
from pkf.physics.constants import PDG_PION
from pkf.params.transport import STEP_UT_TO_SCIFI
from pkf.params.tuning import build_pairs, short_steps, step_groups, tune_slots
from pkf.params.ut_to_scifi import META_SIZE, UTSciFiTable, tabulate_ut_to_scifi
from pkf.pipeline.inputs import align_mc, column, load_dataset, production_truth
from pkf.pipeline.progress import progress_bar

UT_TO_SCIFI_P_MIN = 3000.0  # MeV (paper §4): the eq. 21 polynomials cover |q/p| ≤ 1/p_min
#: MeV: the soft range p_low ≤ p < p_min continues them (LHCb's implementation covers 1.5 GeV);
#: below it the parametrized fit's UT→SciFi step is RK4 through the field map (flagged)
UT_TO_SCIFI_P_LOW = 1500.0
#: (x/z, y/z) grid points of the UT→SciFi table. The paper uses 50×50; 50×100 halves the
#: spacing in y/z, across which the field (and its 100 mm map) varies fastest: the table's
#: error at 3–5 GeV drops from 86 to 53 µm RMS (measured at the first SciFi layer).
UT_TO_SCIFI_GRID = (50, 100)


def ut_to_scifi_table(geometry: Geometry, field_map, progress: bool | None = False) -> UTSciFiTable | None:
    """The RK4 tabulation of the geometry's UT→SciFi step, if it has one.

    progress: a bar over the grid's rows (None: only when stderr is a terminal).
    """
    slots = slot_structure(geometry)
    for s, kind in enumerate(slots.between_type):
        if kind == STEP_UT_TO_SCIFI:
            last = slots.sub_last[s]
            with progress_bar(UT_TO_SCIFI_GRID[0], "tune: UT→SciFi table", unit="row", progress=progress) as bar:
                return tabulate_ut_to_scifi(field_map, z_from=float(geometry.layer_z[last]),
                                            z_to=float(geometry.layer_z[last + 1]), p_min=UT_TO_SCIFI_P_MIN,
                                            p_low=UT_TO_SCIFI_P_LOW, nx=UT_TO_SCIFI_GRID[0],
                                            ny=UT_TO_SCIFI_GRID[1], progress=bar.update)
    return None


def check_output_file(path: str | os.PathLike, overwrite: bool, inputs=()) -> Path:
    """Check that the output file ``path`` can be written (atomically: a temporary file in
    its folder, then a rename); return it as an absolute path.

    Raises:
        InputError: ``path`` is a directory or another non-file, exists and ``overwrite``
            is False, its folder does not exist or is not writable, or it equals or sits
            inside one of ``inputs`` (files or directories).
    """
    check_output_apart(path, inputs)
    shown = os.fspath(path)
    final = Path(os.path.abspath(path))
    if final.is_dir():
        raise InputError(f"--out {shown}: is a directory (give the parameter file to write, e.g. {shown}/params.json)")
    if final.exists() or final.is_symlink():
        if not final.is_file():
            raise InputError(f"--out {shown}: exists and is not a regular file")
        if not overwrite:
            raise InputError(f"--out {shown}: exists (use --overwrite to replace it)")
    folder = final.parent
    if not folder.is_dir():
        raise InputError(f"--out {shown}: directory {folder} does not exist")
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputError(f"--out {shown}: directory {folder} is not writable")
    return final


def check_enough_pairs(dataset_path, geometry: Geometry, pairs, n_events: int) -> None:
    """Refuse a dataset with fewer state pairs in a step than its fits need (one line:
    the steps, their pairs and need, and the events it would take)."""
    groups = step_groups(slot_structure(geometry), pairs, geometry.layer_z.size)
    short = short_steps(groups)
    if not short:
        return
    shown = ", ".join(f"{g.name} {g.pairs.size}/{need}" for g, need in short[:4])
    more = f" and {len(short) - 4} more" if len(short) > 4 else ""
    worst = max(need / max(g.pairs.size, 1) for g, need in short)
    raise InputError(
        f"{dataset_path}: too little data to tune {len(short)} of {len(groups)} steps (pairs/needed: {shown}{more}); "
        f"at the same rate of pion pairs per event that takes at least {math.ceil(worst * n_events)} events "
        f"(this dataset has {n_events}); no parameter file written")


def failed_fits(reports: dict) -> list[str]:
    """The fits Minuit did not mark valid, as "STEP FIT" (e.g. "slot 52 noise")."""
    failed = []
    for name, info in reports.items():
        failed += [f"{name} {fit}" for fit, r in info["extrapolation"].items() if isinstance(r, dict)
                   and not r.get("valid", True)]
        if not info["noise"]["valid"]:
            failed.append(f"{name} noise")
    return failed


def pion_pairs(dataset_path, geometry_option: str | None = None, echo=None):
    """(geometry, dataset, field map, the state pairs of the dataset's pions, number of
    events): the data set D of the tuning (docs/parameters.md#how-the-coefficients-are-tuned). ``geometry_option``: ``--geometry``
    NAME|FILE.toml, if given; ``echo`` is given the warning lines (ignored extra columns).

    Raises:
        InputError: the dataset has no MC truth, mc_hits of unknown particles, or no pions.
    """
    geometry, dataset = load_dataset(dataset_path, geometry_option)
    if echo:
        for name, extra in dataset.ignored_columns.items():
            echo(f"pkf: warning: {extra_columns_warning(dataset.sources[name], name, extra)}")
    if dataset.mc_hits is None or dataset.particles is None:
        raise InputError(f"{dataset_path}: tuning needs mc_hits and particles (a simulated dataset)")
    field_map = geometry.reconstruction_field()
    event = column(dataset.hits, "event_id", np.int64)
    particle, truth = align_mc(dataset, event)
    layer = column(dataset.hits, "layer", np.int64)
    production = production_truth(dataset)
    keys = particle_key(event, particle)
    signal = np.flatnonzero(particle > 0)
    pos = np.minimum(np.searchsorted(production["key"], keys[signal]), production["key"].size - 1)
    if not np.all(production["key"][pos] == keys[signal]):
        raise InputError(f"{dataset_path}: mc_hits refer to particles missing from the particles table")
    # The fit assumes the pion hypothesis (as the reference fitter's material effects do):
    # tune on pions, so that slow kaons and protons (1/β) and radiating electrons do not
    # inflate the noise of every track.
    pions = np.abs(production["pdg"][pos]) == PDG_PION
    signal, pos = signal[pions], pos[pions]
    if signal.size == 0:
        raise InputError(f"{dataset_path}: no pion hits to tune on")
    pairs = build_pairs(event[signal], particle[signal], layer[signal], truth[signal], production["qop"][pos],
                        geometry.layer_z, field_map)
    return geometry, dataset, field_map, pairs, int(np.unique(event).size)


def run_tuning(dataset_path: str | Path, out: str | Path, overwrite: bool = False, echo=print,
               geometry: str | None = None, progress: bool | None = None) -> ParameterSet:
    """Tune every step of the dataset's geometry and write the parameter file `out`.

    geometry: ``--geometry`` NAME|FILE.toml, if given (else the one the dataset's meta.json records).
    progress: bars over the UT→SciFi table's rows and over the steps (None: only when stderr
    is a terminal); ``echo``'s lines are written above them.

    Raises:
        InputError: a bad ``out`` (:func:`check_output_file`), a dataset that is not a
            simulation with pions, too few state pairs in a step
            (:func:`check_enough_pairs`), or a fit that Minuit does not mark valid;
            nothing is written.
    """
    geometry_file = None if geometry is None or geometry in BUILTIN_GEOMETRIES else geometry
    out = check_output_file(out, overwrite, inputs=(dataset_path, geometry_file))
    started = time.perf_counter()
    geometry, dataset, field_map, pairs, n_events = pion_pairs(dataset_path, geometry, echo)
    check_enough_pairs(dataset_path, geometry, pairs, n_events)
    echo(f"tune: {pairs.x1.shape[0]} state pairs of pions from {n_events} events")
    table = ut_to_scifi_table(geometry, field_map, progress)
    if table is not None:
        echo(f"tune: UT→SciFi table tabulated with RK4 ({time.perf_counter() - started:.0f} s so far)")
    uts_arrays = table.as_arrays() if table is not None else (np.zeros(META_SIZE), np.zeros((1, 1, 4, 1)))
    slots = slot_structure(geometry)
    steps = sum(g.pairs.size > 0 for g in step_groups(slots, pairs, geometry.layer_z.size))

    with progress_bar(steps, "tune: steps", unit="step", progress=progress) as bar:
        def report(name, info):
            noise = info["noise"]
            fits = info["extrapolation"]
            ok = all(v.get("valid", True) for v in fits.values() if isinstance(v, dict)) and noise["valid"]
            with bar.external_write_mode():
                echo(f"tune: {name:<9} {info['pairs']:>7} pairs  fits {'ok' if ok else 'NOT VALID'}")
            bar.update(1)

        result = tune_slots(slots, pairs, geometry.layer_z, uts_arrays, progress=report)
    failed = failed_fits(result.reports)
    if failed:
        raise InputError(f"{dataset_path}: {len(failed)} fits did not converge ({', '.join(failed[:5])}"
                         f"{' …' if len(failed) > 5 else ''}): too little or unusual data for these steps; "
                         "tune on more events; no parameter file written")
    params = ParameterSet(
        geometry_name=geometry.name, geometry_hash=geometry.content_hash,
        extrapolation=result.extrapolation, noise=result.noise, ut_to_scifi=table,
        metadata={
            "pkf_version": pkf.__version__,
            "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
            "field_map_hash": field_map.content_hash(),
            "sample": {"dataset": str(Path(dataset_path).resolve()), "events": n_events,
                       "pairs": int(pairs.x1.shape[0]), "meta": dataset.meta.get("config", {})},
            "fits": result.reports,
            "tuning_seconds": round(time.perf_counter() - started, 1),
        },
    )
    params.save(out)
    return params
