"""The `pkf tune` stage: fit the parametrized extrapolations on a simulated dataset (DESIGN §9.3)."""

from __future__ import annotations

import datetime
import time
from pathlib import Path

import numpy as np

import pkf
from pkf.errors import InputError
from pkf.geometry.detector import Geometry
from pkf.io.atomic import check_output_apart
from pkf.io.schemas import particle_key
from pkf.params.parameter_set import ParameterSet, slot_structure
from pkf.params.transport import STEP_UT_TO_SCIFI
from pkf.params.tuning import build_pairs, tune_slots
from pkf.params.ut_to_scifi import META_SIZE, UTSciFiTable, tabulate_ut_to_scifi
from pkf.pipeline.inputs import align_mc, column, load_dataset, production_truth

UT_TO_SCIFI_P_MIN = 3000.0  # MeV (paper §4)
#: (x/z, y/z) grid points of the UT→SciFi table. The paper uses 50×50; 50×100 halves the
#: spacing in y/z, across which the field (and its 100 mm map) varies fastest: the table's
#: error at 3–5 GeV drops from 86 to 53 µm RMS (measured at the first SciFi layer).
UT_TO_SCIFI_GRID = (50, 100)
PDG_PION = 211


def ut_to_scifi_table(geometry: Geometry, field_map) -> UTSciFiTable | None:
    """The RK4 tabulation of the geometry's UT→SciFi step, if it has one."""
    slots = slot_structure(geometry)
    for s, kind in enumerate(slots.between_type):
        if kind == STEP_UT_TO_SCIFI:
            last = slots.sub_last[s]
            return tabulate_ut_to_scifi(field_map, z_from=float(geometry.layer_z[last]),
                                        z_to=float(geometry.layer_z[last + 1]), p_min=UT_TO_SCIFI_P_MIN,
                                        nx=UT_TO_SCIFI_GRID[0], ny=UT_TO_SCIFI_GRID[1])
    return None


def run_tuning(dataset_path: str | Path, out: str | Path, overwrite: bool = False, echo=print) -> ParameterSet:
    """Tune every step of the dataset's geometry and write the parameter file `out`."""
    out = Path(out)
    check_output_apart(out, [dataset_path])
    if out.exists() and not overwrite:
        raise InputError(f"--out {out}: exists (use --overwrite to replace it)")
    if not out.parent.is_dir():
        raise InputError(f"--out {out}: directory {out.parent} does not exist")
    started = time.perf_counter()
    geometry, dataset = load_dataset(dataset_path)
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
    echo(f"tune: {pairs.x1.shape[0]} state pairs of pions from {np.unique(event).size} events")
    table = ut_to_scifi_table(geometry, field_map)
    if table is not None:
        echo(f"tune: UT→SciFi table tabulated with RK4 ({time.perf_counter() - started:.0f} s so far)")
    uts_arrays = table.as_arrays() if table is not None else (np.zeros(META_SIZE), np.zeros((4, 1, 1, 1)))

    def report(name, info):
        noise = info["noise"]
        fits = info["extrapolation"]
        ok = all(v.get("valid", True) for v in fits.values() if isinstance(v, dict)) and noise["valid"]
        echo(f"tune: {name:<9} {info['pairs']:>7} pairs  fits {'ok' if ok else 'NOT VALID'}")

    result = tune_slots(slot_structure(geometry), pairs, geometry.layer_z, uts_arrays, progress=report)
    params = ParameterSet(
        geometry_name=geometry.name, geometry_hash=geometry.content_hash,
        extrapolation=result.extrapolation, noise=result.noise, ut_to_scifi=table,
        metadata={
            "pkf_version": pkf.__version__,
            "date": datetime.datetime.now(datetime.timezone.utc).isoformat(timespec="seconds"),
            "field_map_hash": field_map.content_hash(),
            "sample": {"dataset": str(Path(dataset_path).resolve()), "events": int(np.unique(event).size),
                       "pairs": int(pairs.x1.shape[0]), "meta": dataset.meta.get("config", {})},
            "fits": result.reports,
            "tuning_seconds": round(time.perf_counter() - started, 1),
        },
    )
    params.save(out)
    return params
