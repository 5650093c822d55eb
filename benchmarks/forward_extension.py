"""Forward extension speed and quality vs pile-up (DESIGN §12): ms/event at ν = 1, 2, 4, 7.6.

Simulates lhcb-like minimum-bias events at each pile-up, builds the VELO tracks from MC
truth (each particle's own VELO hits, straight-line state at its last hit; ``--velo
search`` uses `find_velo_tracks` instead), and runs `extend_velo_tracks` (UT search, q/p
scan of the SciFi, combinatorial Kalman filter, UT confirmation, DESIGN §7.4) on one
core after JIT warm-up (best of --repeat; pile-up values interleaved so that a change of
the machine's load affects them alike). Prints a table and writes JSON (--json): wall
and CPU ms/event and µs per VELO track, VELO tracks and UT+SciFi hits per event, and the
quality on the same events: efficiency of long-reconstructible particles (≥ 70 % of the
added hits correct) for p > 5 GeV, 2–5 GeV and without UT hits, ghost rate, q/p core
resolution. The last line gives time(7.6)/time(1) against hits(7.6)/hits(1).

    python benchmarks/forward_extension.py [--events 100] [--repeat 3] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import sys
import time
from dataclasses import asdict
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "seeding"))
from forward_helpers import extension_metrics, simulate, truth_velo_tracks  # noqa: E402

from pkf.geometry import load_geometry  # noqa: E402
from pkf.geometry.detector import SUBDETECTORS  # noqa: E402
from pkf.params.parameter_set import shipped_parameters  # noqa: E402
from pkf.seeding.forward import ForwardOptions, extend_velo_tracks  # noqa: E402

PILEUPS = (1.0, 2.0, 4.0, 7.6)


def _searched_velo_tracks(geometry, h) -> dict:
    """VELO tracks of the triplet search, as the truth tracks' dict (state at the last hit)."""
    from pkf.seeding.velo_search import find_velo_tracks

    tracks = find_velo_tracks(h["event_id"], h["layer"], h["u"], h["v"], h["z"], h["sigma_u"], geometry)
    last = tracks.offsets[1:] - 1
    z_last = h["z"][tracks.hit_rows[last]]
    dz = z_last - tracks.z
    state = np.column_stack([tracks.x + tracks.tx * dz, tracks.y + tracks.ty * dz, tracks.tx, tracks.ty])
    return {"key": np.full(tracks.n_tracks, -1), "event": tracks.event_id, "z": z_last, "state": state}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--events", type=int, default=100, help="events per pile-up value")
    parser.add_argument("--repeat", type=int, default=3, help="timed runs (best is kept)")
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--velo", choices=("truth", "search"), default="truth",
                        help="VELO tracks from MC truth (default) or from the triplet search")
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    args = parser.parse_args()

    geometry = load_geometry("lhcb-like")
    ext = shipped_parameters(geometry).extrapolator(geometry)
    forward_layers = np.flatnonzero(geometry.layer_subdetector != SUBDETECTORS.index("velo"))
    samples = {}
    for nu in PILEUPS:
        h, p, m = simulate(geometry, args.events, nu, args.seed)
        velo = truth_velo_tracks(geometry, h, m) if args.velo == "truth" else _searched_velo_tracks(geometry, h)
        samples[nu] = (h, p, m, velo)

    def run(nu):
        h, _, _, velo = samples[nu]
        return extend_velo_tracks(velo["event"], velo["state"], velo["z"], h["event_id"], h["layer"],
                                  h["u"], h["sigma_u"], geometry, ext)

    # JIT warm-up (compilation, or loading numba's on-disk cache)
    h0, _, _, v0 = samples[PILEUPS[0]]
    extend_velo_tracks(v0["event"][:20], v0["state"][:20], v0["z"][:20], h0["event_id"], h0["layer"],
                       h0["u"], h0["sigma_u"], geometry, ext)

    walls = {nu: [] for nu in PILEUPS}
    cpus = {nu: [] for nu in PILEUPS}
    results = {}
    for _ in range(args.repeat):
        for nu in PILEUPS:
            w0, c0 = time.perf_counter(), time.process_time()
            results[nu] = run(nu)
            walls[nu].append(time.perf_counter() - w0)
            cpus[nu].append(time.process_time() - c0)

    rows = []
    for nu in PILEUPS:
        h, p, m, velo = samples[nu]
        res = results[nu]
        n_ev = args.events
        row = {
            "pileup": nu, "events": n_ev,
            "wall_ms_per_event": 1e3 * min(walls[nu]) / n_ev,
            "cpu_ms_per_event": 1e3 * min(cpus[nu]) / n_ev,
            "us_per_velo_track": 1e6 * min(walls[nu]) / max(res.n_tracks, 1),
            "velo_tracks_per_event": res.n_tracks / n_ev,
            "forward_hits_per_event": float(np.isin(h["layer"], forward_layers).sum()) / n_ev,
            "extensions_per_event": float(res.found.sum()) / n_ev,
        }
        if args.velo == "truth":
            met = extension_metrics(geometry, res, velo, h, p, m)
            row.update({k: v for k, v in met.items() if k != "masks"})
        rows.append(row)

    head = (f"{'nu':>5} {'ms/ev':>7} {'cpu ms':>7} {'us/trk':>7} {'VELO/ev':>8} {'hits/ev':>8} "
            f"{'ext/ev':>7} {'eff>5':>7} {'eff2-5':>7} {'noUT>5':>7} {'ghost':>6} {'dq/q':>6}")
    print(head)
    print("-" * len(head))
    for r in rows:
        quality = (f"{100 * r['efficiency_p_gt_5GeV']:6.2f}% {100 * r['efficiency_p_2_5GeV']:6.2f}% "
                   f"{100 * r['efficiency_no_ut_p_gt_5GeV']:6.2f}% {100 * r['ghost_rate']:5.2f}% "
                   f"{100 * r['qop_resolution_core_5_20GeV']:5.2f}%") if "ghost_rate" in r else ""
        print(f"{r['pileup']:5.1f} {r['wall_ms_per_event']:7.2f} {r['cpu_ms_per_event']:7.2f} "
              f"{r['us_per_velo_track']:7.1f} {r['velo_tracks_per_event']:8.1f} "
              f"{r['forward_hits_per_event']:8.0f} {r['extensions_per_event']:7.1f} {quality}")
    lo, hi = rows[0], rows[-1]
    t_ratio = hi["wall_ms_per_event"] / lo["wall_ms_per_event"]
    c_ratio = hi["cpu_ms_per_event"] / lo["cpu_ms_per_event"]
    h_ratio = hi["forward_hits_per_event"] / lo["forward_hits_per_event"]
    exponent = math.log(t_ratio) / math.log(h_ratio)
    print(f"time(7.6)/time(1) = {t_ratio:.2f} (cpu {c_ratio:.2f})   "
          f"UT+SciFi hits(7.6)/hits(1) = {h_ratio:.2f}   time ~ hits^{exponent:.2f}")
    if args.json:
        result = {
            "benchmark": "forward_extension",
            "description": "extend_velo_tracks on lhcb-like minbias, VELO tracks from "
                           f"{args.velo}, one core, after JIT warm-up",
            "machine": {"python": platform.python_version(), "processor": platform.processor(),
                        "cpus": os.cpu_count()},
            "options": asdict(ForwardOptions()),
            "seed": args.seed, "repeat": args.repeat, "velo": args.velo,
            "rows": rows,
            "time_ratio_7.6_over_1": t_ratio,
            "cpu_time_ratio_7.6_over_1": c_ratio,
            "hits_ratio_7.6_over_1": h_ratio,
            "scaling_exponent": exponent,
        }
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(result, indent=2) + "\n")
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
