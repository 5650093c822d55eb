"""Whole pattern recognition vs pile-up (DESIGN §12, issue 5): ms/event at ν = 1, 2, 4, 7.6.

Simulates lhcb-like minimum-bias events at each pile-up and runs exactly the pattern step
of `pkf reconstruct --pattern triplet` (`pkf.pipeline.triplet_pattern.triplet_candidates`:
VELO triplet search, merging and arbitration, then the forward extension through UT and
SciFi) on one core after JIT warm-up, timing the VELO search and the forward extension
separately (best of --repeat; pile-up values interleaved, so that a change of the
machine's load affects them alike). With --split-forward the forward extension is also
timed without its second pass (``no_ut_fallback=False``: the UT starts only), so that
the second pass's full-range scans are the difference (that run's tracks are not used). The quality on the same events uses the matching of
`pkf reconstruct` (DESIGN §10): long-track efficiency for p > 5 GeV and 2–5 GeV, long
ghost and clone rates, VELO-track efficiency, ghost and clone rate (VELO tracks matched on
their VELO hits). And what the forward extension did with the VELO tracks: per event, the
CPU µs per VELO track and the shares extended into the SciFi (of them found only by the
second pass's full-range scan), upstream and not extended (ν = 7.6, 40 events: 318 VELO
tracks per event, 79 % of them extended, 18.5 % only by the scan: the extension works
mostly on tracks it extends). Prints tables, the time(7.6)/time(1) ratio against the hit ratio, and
writes JSON with --json.

    python benchmarks/pattern_recognition.py [--events 200] [--repeat 3] [--split-forward] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import time
from pathlib import Path

import numpy as np

from pkf.geometry import load_geometry
from pkf.geometry.detector import SUBDETECTORS
from pkf.params.parameter_set import shipped_parameters
from pkf.pipeline.batch import metrics_from_counts, pattern_counts
from pkf.pipeline.matching import match_tracks, reconstructible_particles, velo_reconstructible_particles
from pkf.pipeline.simulate import SimulationConfig, simulate_batch
from pkf.pipeline.triplet_pattern import triplet_candidates
from pkf.seeding.forward import extend_velo_tracks
from pkf.seeding.velo_search import find_velo_tracks

PILEUPS = (1.0, 2.0, 4.0, 7.6)
KEY_SCALE = 1 << 32


def _columns(table) -> dict:
    return {c: table.column(c).to_numpy(zero_copy_only=False) for c in table.column_names}


def _sample(geometry, events: int, pileup: float, seed: int) -> dict:
    config = SimulationConfig(generator="minbias", events=events, pileup=pileup, seed=seed)
    hits, particles, mc_hits = (_columns(t) for t in simulate_batch(geometry, config, 0, events))
    return {"h": hits, "p": particles, "m": mc_hits}


def _timed_pattern(geometry, ext, h, split_forward=False) -> tuple[float, float, float, dict]:
    """The pattern step of `triplet_candidates`, split into its two stages, and with
    split_forward the forward extension's first pass alone (else NaN): CPU seconds, and
    what the forward extension did with the VELO tracks (`_extension_counts`)."""
    c0 = time.process_time()
    velo = find_velo_tracks(h["event_id"], h["layer"], h["u"], h["v"], h["z"],
                            np.column_stack([h["sigma_u"], h["sigma_v"]]), geometry)
    c1 = time.process_time()
    forward_args = (velo.event_id, np.column_stack([velo.x, velo.y, velo.tx, velo.ty]), velo.z,
                    h["event_id"], h["layer"], h["u"], h["sigma_u"], geometry, ext)
    forward = extend_velo_tracks(*forward_args)
    c2 = time.process_time()
    counts = _extension_counts(forward)
    if not split_forward:
        return c1 - c0, c2 - c1, math.nan, counts
    extend_velo_tracks(*forward_args, no_ut_fallback=False)
    return c1 - c0, c2 - c1, time.process_time() - c2, counts


def _extension_counts(forward) -> dict:
    """VELO tracks given to the forward extension and what became of them: extended into the
    SciFi (``found``), of those found only by the second pass's full-range scan
    (``from_scan``), upstream tracks, and the rest (``not_extended``, VELO-only candidates).
    Where the forward time goes per VELO track: on tracks it extends, or on hopeless ones."""
    n = int(forward.status.size)
    found = int(forward.found.sum())
    upstream = int(forward.upstream.sum())
    return {"velo_tracks": n, "found": found, "from_scan": int((forward.from_scan & forward.found).sum()),
            "upstream": upstream, "not_extended": n - found - upstream}


def _quality(geometry, ext, sample) -> dict:
    h, p, m = sample["h"], sample["p"], sample["m"]
    candidates = triplet_candidates(geometry, ext, h["event_id"], h["layer"], h["u"], h["v"], h["z"],
                                    h["sigma_u"], h["sigma_v"])
    cand_event, cand_track, rows = candidates.hit_event, candidates.hit_track, candidates.hit_row
    hit_key = np.where(m["particle_id"] > 0, h["event_id"] * KEY_SCALE + m["particle_id"], 0)
    track_key = cand_event * KEY_SCALE + cand_track
    tracks, track_of_hit = np.unique(track_key, return_inverse=True)
    n = tracks.size
    sub = geometry.layer_subdetector[h["layer"][rows]]
    matched, _, _ = match_tracks(track_of_hit, hit_key[rows], n)
    is_long = np.bincount(track_of_hit, weights=sub == SUBDETECTORS.index("scifi"), minlength=n) > 0
    velo_hit = sub == SUBDETECTORS.index("velo")
    velo_matched, _, _ = match_tracks(track_of_hit[velo_hit], hit_key[rows][velo_hit], n)
    p_key = p["event_id"] * KEY_SCALE + p["particle_id"]
    order = np.argsort(p_key)
    p_key, mom = p_key[order], np.sqrt(p["px"] ** 2 + p["py"] ** 2 + p["pz"] ** 2)[order]

    def momentum(keys):
        return mom[np.minimum(np.searchsorted(p_key, keys), p_key.size - 1)]

    long_rec = reconstructible_particles(geometry, hit_key, h["layer"])
    velo_rec = velo_reconstructible_particles(geometry, hit_key, h["layer"])
    return {"long": metrics_from_counts(pattern_counts(matched[is_long], long_rec, momentum(long_rec))),
            "velo": metrics_from_counts(pattern_counts(velo_matched, velo_rec, momentum(velo_rec)))}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=200, help="events per pile-up value")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs (best is kept)")
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--split-forward", action="store_true",
                        help="also time the forward extension without its second pass (full-range scans)")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    args = parser.parse_args()

    geometry = load_geometry("lhcb-like")
    ext = shipped_parameters(geometry).extrapolator(geometry)
    samples = {nu: _sample(geometry, args.events, nu, args.seed) for nu in PILEUPS}
    _timed_pattern(geometry, ext, samples[PILEUPS[0]]["h"], args.split_forward)  # JIT warm-up
    velo_s = {nu: [] for nu in PILEUPS}
    fwd_s = {nu: [] for nu in PILEUPS}
    first_s = {nu: [] for nu in PILEUPS}
    counts = {}
    for _ in range(args.repeat):
        for nu in PILEUPS:
            tv, tf, t1, counts[nu] = _timed_pattern(geometry, ext, samples[nu]["h"], args.split_forward)
            velo_s[nu].append(tv)
            fwd_s[nu].append(tf)
            first_s[nu].append(t1)

    rows = []
    for nu in PILEUPS:
        h = samples[nu]["h"]
        total = [a + b for a, b in zip(velo_s[nu], fwd_s[nu])]
        q = _quality(geometry, ext, samples[nu])
        rows.append({
            "pileup": nu, "events": args.events, "hits_per_event": h["event_id"].size / args.events,
            "cpu_ms_per_event": 1e3 * min(total) / args.events,
            "velo_cpu_ms_per_event": 1e3 * min(velo_s[nu]) / args.events,
            "forward_cpu_ms_per_event": 1e3 * min(fwd_s[nu]) / args.events,
            "forward_first_pass_cpu_ms_per_event": (1e3 * min(first_s[nu]) / args.events
                                                    if args.split_forward else None),
            "forward_cpu_us_per_velo_track": 1e6 * min(fwd_s[nu]) / max(counts[nu]["velo_tracks"], 1),
            "extension": counts[nu],
            "long": q["long"], "velo": q["velo"],
        })

    head = (f"{'nu':>4} {'hits/ev':>8} {'ms/ev':>7} {'VELO':>6} {'fwd':>6} {'eff>5':>7} {'eff2-5':>7} "
            f"{'ghost':>6} {'clone':>6} {'VELOeff':>8} {'VELOgh':>7}")
    print(head)
    print("-" * len(head))
    for r in rows:
        lp = r["long"]["efficiency_by_p"]
        print(f"{r['pileup']:4.1f} {r['hits_per_event']:8.0f} {r['cpu_ms_per_event']:7.2f} "
              f"{r['velo_cpu_ms_per_event']:6.2f} {r['forward_cpu_ms_per_event']:6.2f} "
              f"{100 * lp['p_gt_5GeV']['efficiency']:6.2f}% {100 * lp['p_2_5GeV']['efficiency']:6.2f}% "
              f"{100 * r['long']['ghost_rate']:5.2f}% {100 * r['long']['clone_rate']:5.2f}% "
              f"{100 * r['velo']['efficiency']:7.2f}% {100 * r['velo']['ghost_rate']:6.2f}%")
    print("forward extension per VELO track: tracks/event, µs each (CPU), extended into the SciFi "
          "(of them found only by the full-range scan), upstream, not extended")
    for r in rows:
        c = r["extension"]
        n = max(c["velo_tracks"], 1)
        print(f"{r['pileup']:4.1f} {c['velo_tracks'] / r['events']:7.1f} {r['forward_cpu_us_per_velo_track']:7.1f} µs "
              f"{100 * c['found'] / n:6.1f}% ({100 * c['from_scan'] / n:4.1f}%) {100 * c['upstream'] / n:5.1f}% "
              f"{100 * c['not_extended'] / n:5.1f}%")
    if args.split_forward:
        print("forward extension, ms/event: first pass (UT starts) + second pass (full-range scans)")
        for r in rows:
            first = r["forward_first_pass_cpu_ms_per_event"]
            print(f"{r['pileup']:4.1f} {first:7.2f} + {r['forward_cpu_ms_per_event'] - first:6.2f}")
    lo, hi = rows[0], rows[-1]
    t_ratio = hi["cpu_ms_per_event"] / lo["cpu_ms_per_event"]
    h_ratio = hi["hits_per_event"] / lo["hits_per_event"]
    print(f"time(7.6)/time(1) = {t_ratio:.2f}   hits(7.6)/hits(1) = {h_ratio:.2f}   "
          f"time ~ hits^{math.log(t_ratio) / math.log(h_ratio):.2f}   (CPU time, one core)")
    for stage in ("velo", "forward"):
        ratio = hi[f"{stage}_cpu_ms_per_event"] / lo[f"{stage}_cpu_ms_per_event"]
        print(f"  {stage}: time(7.6)/time(1) = {ratio:.2f}   time ~ hits^{math.log(ratio) / math.log(h_ratio):.2f}")
    if args.json:
        out = {"benchmark": "pattern_recognition",
               "description": "triplet_candidates (VELO search + forward extension) on lhcb-like minbias, "
                              "one core, CPU time after JIT warm-up, best of repeat",
               "machine": {"python": platform.python_version(), "processor": platform.processor(),
                           "cpus": os.cpu_count()},
               "seed": args.seed, "repeat": args.repeat, "rows": rows,
               "time_ratio_7.6_over_1": t_ratio, "hits_ratio_7.6_over_1": h_ratio}
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(out, indent=2) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
