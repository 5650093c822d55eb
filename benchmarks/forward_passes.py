"""Why the forward extension's second pass runs: the tracks its full-range scans extend (issue 18.3).

The second pass (`pkf.seeding.forward`, step 6) scans the whole q/p range for every VELO
track the first pass (the UT starts) did not extend; its cost grows faster with the density
than the first pass's (`benchmarks/pattern_recognition.py --split-forward`). Here, on
lhcb-like minimum-bias events with MC-truth VELO tracks (`forward_helpers.truth_velo_tracks`:
the forward extension alone), for the tracks the second pass extends:

- their number of true UT hits (a track without ≥ 3 can only be found by the scan);
- the first pass alone on just these tracks (the event's hits all there, nothing taken by
  other tracks): how many it extends then (the rest are not lost to hits other tracks took);
- for those with 4 true UT hits, the first pass's UT candidates (`ut.ut_candidates`, the
  same kernels): none, one whose hits are the final extension's UT hits, or whose q/p range
  holds the final q/p (the extension's UT hits are re-collected with the SciFi q/p, step 4).

Prints a table per pile-up; JSON with --json. Measured (2026-12-08, 60 events, seed 2024):

| ν | VELO tracks | pass 1 | pass 2 | of them 4 true UT hits | pass 1 alone on those | no UT candidate | candidate = final UT hits | final q/p in a candidate's range |
|---|---|---|---|---|---|---|---|---|
| 1 | 4,216 | 2,927 | 436 | 78 | 17 | 27 | 9 | 27 |
| 7.6 | 20,294 | 12,314 | 3,707 | 1,997 | 304 | 302 | 43 | 399 |

The second pass's tracks with all 4 UT hits grow ×26 for ×4.8 VELO tracks: in the dense UT
the search's best leaves (most hits, then χ², ``ut_candidates`` of them) are combinations of
other particles' hits, and their q/p ranges miss the track's; the hits other tracks took
are not the cause (alone, the first pass finds 15 % of them). More candidates trade
first-pass scans for second-pass ones at no saving (ν = 7.6, the same events, interleaved,
best of 2–3: ``ut_candidates`` 3, 4, 6 leave 3,258, 3,060, 2,735 tracks to the scan at 1.01,
1.15, 1.31 × the forward time; ``ut_first_branches`` 8 with 4 or 6 candidates 2,770, 2,505
at 1.18, 1.27 ×, efficiencies within ±0.25 points).

    python benchmarks/forward_passes.py [--pileups 1 7.6] [--events 60] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numba as nb
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "seeding"))
from forward_helpers import extension_metrics, simulate, truth_velo_tracks  # noqa: E402

from pkf.geometry import load_geometry  # noqa: E402
from pkf.jit import NO_REFCOUNT  # noqa: E402
from pkf.params.parameter_set import shipped_parameters  # noqa: E402
from pkf.seeding.forward import ForwardOptions, extend_velo_tracks, kernel_setup  # noqa: E402
from pkf.seeding.forward.kernel import _valid_state  # noqa: E402
from pkf.seeding.forward.options import I_UT_CANDIDATES  # noqa: E402
from pkf.seeding.forward.records import Hits, Track  # noqa: E402
from pkf.seeding.forward.ut import ut_candidates, ut_start  # noqa: E402


@nb.njit(**NO_REFCOUNT)
def _first_pass_candidates(tr, lay, cfg, w, pw, inp, tracks, n_cand, lo, hi, paths):
    """Step 1 of the forward extension for each of `tracks`, as the first pass runs it
    (nothing taken): the number of UT candidates (−1: invalid start), their q/p ranges and
    UT hit rows (sorted-hit indices, −1 none)."""
    t_ev, t_state, t_layer, lay_off, hu, hsig = inp
    top_ut, utc, start, s_v, ut_best, _, _, used = pw
    for i in range(tracks.shape[0]):
        t = tracks[i]
        hits = Hits(lay_off[t_ev[t]], hu, hsig, used)
        for k in range(4):
            s_v[k] = t_state[t, k]
        s_v[4] = 0.0
        track = Track(t, t_layer[t], s_v)
        if not _valid_state(track.a, s_v) or not ut_start(tr, lay, hits, cfg, w, track, start):
            n_cand[i] = -1
            continue
        n = ut_candidates(tr, lay, hits, cfg, w, track, top_ut, utc, ut_best)
        n_cand[i] = n
        for c in range(n):
            lo[i, c] = utc.lo[c]
            hi[i, c] = utc.hi[c]
            for j in range(lay.n_ut):
                paths[i, c, j] = top_ut.paths[utc.leaf[c], j]


def true_ut_hits(geometry, out, velo: dict, h: dict, p: dict, m: dict) -> np.ndarray:
    """Each VELO track's particle's number of UT hits (`forward_helpers.extension_metrics`)."""
    return extension_metrics(geometry, out, velo, h, p, m)["masks"]["n_ut_true"]


def first_pass_candidates(args: tuple, out, tracks: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The first pass's UT candidates of `tracks` (indices of the VELO tracks of
    `extend_velo_tracks(*args)`, whose result is `out`): their number (−1: invalid start),
    whether one's q/p range holds the final q/p, whether one's UT hits (≥ 3) are among the
    final extension's."""
    prep, kargs = kernel_setup(*args, ForwardOptions())
    k = int(prep.cfg.iopt[I_UT_CANDIDATES])
    n = tracks.size
    n_cand = np.zeros(n, dtype=np.int64)
    lo, hi = np.full((n, k), np.nan), np.full((n, k), np.nan)
    paths = np.full((n, k, prep.lay.n_ut), -1, dtype=np.int64)
    _first_pass_candidates(*kargs, tracks.astype(np.int64), n_cand, lo, hi, paths)
    q = out.qop[tracks][:, None]
    has = np.arange(k)[None, :] < n_cand[:, None]
    in_range = (has & (lo <= q) & (q <= hi)).any(axis=1)
    final_ut = [set(out.hit_rows[out.offsets[t]:out.offsets[t] + out.n_ut[t]].tolist()) for t in tracks]
    same_hits = np.array([any(has[i, c] and (paths[i, c] >= 0).sum() >= 3
                              and set(prep.rows[paths[i, c][paths[i, c] >= 0]].tolist()) <= final_ut[i]
                              for c in range(k)) for i in range(n)], dtype=bool)
    return n_cand, in_range, same_hits


def measure(geometry, ext, pileup: float, events: int, seed: int) -> dict:
    """One pile-up's row of the table (module docstring)."""
    h, p, m = simulate(geometry, events, pileup, seed)
    velo = truth_velo_tracks(geometry, h, m)
    args = (velo["event"], velo["state"], velo["z"], h["event_id"], h["layer"], h["u"], h["sigma_u"], geometry, ext)
    out = extend_velo_tracks(*args)
    n_ut_true = true_ut_hits(geometry, out, velo, h, p, m)
    second = np.flatnonzero(out.from_scan & out.found)
    res = {"pileup": pileup, "events": events, "velo_tracks": int(velo["key"].size),
           "first_pass": int((out.found & ~out.from_scan).sum()), "second_pass": int(second.size),
           "second_pass_by_true_ut_hits": np.bincount(n_ut_true[second], minlength=5)[:5].tolist()}
    alone = extend_velo_tracks(velo["event"][second], velo["state"][second], velo["z"][second], *args[3:],
                               no_ut_fallback=False)
    res["first_pass_alone"] = int(alone.found.sum())
    res["first_pass_alone_4_ut_hits"] = int(alone.found[n_ut_true[second] == 4].sum())

    four = second[n_ut_true[second] == 4]
    n_cand, in_range, same_hits = first_pass_candidates(args, out, four)
    res.update({"four_ut_hits": int(four.size), "no_candidate": int((n_cand == 0).sum()),
                "candidate_with_final_ut_hits": int(same_hits.sum()),
                "candidate_range_holds_final_qop": int(in_range.sum())})
    return res


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pileups", type=float, nargs="+", default=[1.0, 7.6])
    parser.add_argument("--events", type=int, default=60)
    parser.add_argument("--seed", type=int, default=2024)
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    geometry = load_geometry("lhcb-like")
    ext = shipped_parameters(geometry).extrapolator(geometry)
    rows = [measure(geometry, ext, nu, args.events, args.seed) for nu in args.pileups]
    print("  nu   VELO  pass1  pass2  pass2 by true UT hits 0/1/2/3/4   pass1 alone (4 UT)   "
          "4-UT tracks: no cand, cand = final UT hits, final q/p in range")
    for r in rows:
        print(f"{r['pileup']:4.1f} {r['velo_tracks']:6d} {r['first_pass']:6d} {r['second_pass']:6d}   "
              f"{'/'.join(str(c) for c in r['second_pass_by_true_ut_hits']):>24s}   "
              f"{r['first_pass_alone']:6d} ({r['first_pass_alone_4_ut_hits']:5d})   "
              f"{r['four_ut_hits']:6d}: {r['no_candidate']:5d} {r['candidate_with_final_ut_hits']:5d} "
              f"{r['candidate_range_holds_final_qop']:5d}")
    if args.json:
        args.json.write_text(json.dumps(rows, indent=2))
        print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
