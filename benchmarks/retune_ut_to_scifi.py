"""Regenerate the UT→SciFi part of a parameter file: the table and the slot that uses it.

The table depends on the field map only (`pkf.pipeline.tune.ut_to_scifi_table`, the same
call as `pkf tune`); the UT→SciFi slot's parameters — ΔE (the energy lost upstream of the
magnet, at which the table is evaluated), the noise p̃0–p̃3 and the straggling p̃5 — are
fitted *through* the table (`pkf.params.tuning.tune_slots`, the same fits as `pkf tune`),
so they are refitted with it, on the pion pairs (last UT layer → first SciFi layer) of a
simulated dataset. Every other slot is kept as it is. This is how the shipped lhcb-like set
got its 1.5 GeV table (issue 15), on the sample of its metadata::

    pkf simulate --generator bs2phiphi --events 4000 --seed 2024 --out /tmp/bs_4000
    python benchmarks/retune_ut_to_scifi.py /tmp/bs_4000 [--params IN.json] --out OUT.json

--params: the file to start from (default: the shipped set of the dataset's geometry).
"""

from __future__ import annotations

import argparse
import datetime
import time
from pathlib import Path

import numpy as np

import pkf
import pkf.pipeline.tune as tune
from pkf.params.parameter_set import ParameterSet, shipped_parameters, slot_structure
from pkf.params.transport import STEP_UT_TO_SCIFI
from pkf.params.tuning import tune_slots
from pkf.params.ut_to_scifi import META_P_MIN, covered_p_min


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--params", type=Path, help="parameter file to start from (default: the shipped set)")
    parser.add_argument("--out", type=Path, required=True)
    args = parser.parse_args()
    started = time.perf_counter()

    geometry = tune.load_dataset(args.dataset)[0]
    slots = slot_structure(geometry)
    uts = [s for s, kind in enumerate(slots.between_type) if kind == STEP_UT_TO_SCIFI]
    if not uts:
        raise SystemExit(f"geometry {geometry.name!r} has no UT→SciFi step")
    last = int(slots.sub_last[uts[0]])
    keep = (last, last + 1)

    # the pairs of the one step: only the hits of its two layers (a pair of the step is two
    # hits of one particle on exactly these layers, `pkf.params.tuning.pair_slot`)
    real_build_pairs = tune.build_pairs

    def step_pairs(event, particle, layer, *rest):
        sel = np.isin(layer, keep)
        return real_build_pairs(event[sel], particle[sel], layer[sel], *(a[sel] for a in rest[:2]), *rest[2:])

    tune.build_pairs = step_pairs
    geometry, dataset, field_map, pairs, n_events = tune.pion_pairs(args.dataset)
    tune.build_pairs = real_build_pairs
    print(f"{pairs.x1.shape[0]} pion pairs on layers {keep} from {n_events} events")

    table = tune.ut_to_scifi_table(geometry, field_map)
    meta = table.as_arrays()[0]
    print(f"table: p_min {meta[META_P_MIN]:.0f} MeV, covers p >= {covered_p_min(meta):.0f} MeV, "
          f"{table.nx}x{table.ny}, {table.tabulation['seconds']:.0f} s")
    result = tune_slots(slots, pairs, geometry.layer_z, table.as_arrays())
    name = f"slot {last}"
    report = result.reports[name]
    print(f"{name}: ΔE {result.extrapolation[last, 0]:.3f} MeV, noise {np.round(result.noise[last], 5).tolist()}, "
          f"valid {report['noise']['valid']}")

    base = ParameterSet.load(args.params) if args.params else shipped_parameters(geometry)
    base.check_geometry(geometry, str(args.params or "shipped"))
    extrapolation, noise = base.extrapolation.copy(), base.noise.copy()
    old = (extrapolation[last, 0], noise[last].copy())
    extrapolation[last] = result.extrapolation[last]
    noise[last] = result.noise[last]
    metadata = dict(base.metadata)
    metadata["fits"] = dict(metadata.get("fits", {}), **{name: report})
    metadata["ut_to_scifi_retuned"] = {
        "date": datetime.datetime.now(datetime.UTC).isoformat(timespec="seconds"),
        "pkf_version": pkf.__version__,
        "how": "benchmarks/retune_ut_to_scifi.py: table retabulated (pkf.pipeline.tune.ut_to_scifi_table), "
               f"{name} refitted through it (pkf.params.tuning.tune_slots); the other slots unchanged",
        "dataset": str(args.dataset.resolve()), "events": n_events, "pairs": int(report["pairs"]),
        "meta": dataset.meta.get("config", {}),
        "previous": {"delta_e_mev": float(old[0]), "noise": [float(v) for v in old[1]]},
        "seconds": round(time.perf_counter() - started, 1),
    }
    out = ParameterSet(geometry_name=base.geometry_name, geometry_hash=base.geometry_hash,
                       extrapolation=extrapolation, noise=noise, ut_to_scifi=table, metadata=metadata)
    out.save(args.out)
    print(f"wrote {args.out}: ΔE {old[0]:.3f} -> {extrapolation[last, 0]:.3f} MeV, "
          f"straggling {old[1][5]:.3f} -> {noise[last, 5]:.3f} MeV")


if __name__ == "__main__":
    main()
