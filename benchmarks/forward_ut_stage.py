"""Cost of the forward extension's UT stage (step 1) per VELO track vs pile-up (issue 18.3).

Simulates lhcb-like minimum-bias events at each pile-up, finds the VELO tracks
(`pkf.seeding.velo_search.find_velo_tracks`), prepares the forward extension's inputs as
`pkf.seeding.forward.extend_velo_tracks` does (`kernel_setup`), and times compiled loops over all VELO
tracks that run step 1 of the forward extension in parts (CPU time, best of --repeat,
after JIT warm-up; pile-up values interleaved):

- ``reference``: one reference trajectory VELO → last UT layer (`kalman.reference`, q/p = 0);
- ``start``: `ut.ut_start` (two reference trajectories and two fits through the UT without
  hits: the start state given q/p and its conditional covariance);
- ``search``: ``start`` + the UT search (`ut.ut_search`);
- ``candidates``: ``start`` + `ut.ut_candidates` (the search and the refit of its leaves);

and the whole forward extension for comparison. Prints µs per VELO track and ms per
event, and writes JSON with --json. Measured (2026-12-07, 100/100/30 events): the UT stage
costs 7.2, 7.9 and 8.5 µs per VELO track at ν = 1, 4 and 7.6, the UT search alone 3.1, 4.1
and 4.4: it hardly depends on the density (4.5 hits per UT search layer at ν = 7.6), its
cost is that of a search node.

    python benchmarks/forward_ut_stage.py [--pileups 1 4 7.6] [--events 50] [--repeat 5] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numba as nb
import numpy as np
from pattern_recognition import _sample

from pkf.geometry import load_geometry
from pkf.jit import NO_REFCOUNT
from pkf.params.parameter_set import shipped_parameters
from pkf.seeding.forward import ForwardOptions, extend_velo_tracks, kernel_setup
from pkf.seeding.forward.kalman import reference
from pkf.seeding.forward.kernel import _valid_state
from pkf.seeding.forward.records import Hits, Track
from pkf.seeding.forward.ut import ut_candidates, ut_search, ut_start
from pkf.seeding.velo_search import find_velo_tracks

PARTS = ("reference", "start", "search", "candidates")


@nb.njit(**NO_REFCOUNT)
def _ut_parts(tr, lay, cfg, w, pw, inp, part):
    """Step 1 of every track of inp up to `PARTS`[part]; returns the UT leaves or candidates found."""
    t_ev, t_state, t_layer, lay_off, hu, hsig = inp
    top_ut, utc, start, s_v, ut_best, _, _, used = pw
    found = 0
    for t in range(t_ev.shape[0]):
        hits = Hits(lay_off[t_ev[t]], hu, hsig, used)
        for i in range(4):
            s_v[i] = t_state[t, i]
        s_v[4] = 0.0
        track = Track(t, t_layer[t], s_v)
        if not _valid_state(track.a, s_v):
            continue
        if part == 0:
            reference(tr, lay, w.filt.ref, track.a, lay.n_ut, track.s_v, 0.0, 0.0)
            continue
        if not ut_start(tr, lay, hits, cfg, w, track, start):
            continue
        if part == 2:
            found += ut_search(lay, hits, cfg, w, top_ut)
        elif part == 3:
            found += ut_candidates(tr, lay, hits, cfg, w, track, top_ut, utc, ut_best)
    return found


class Stage:
    """The prepared inputs and scratch of the forward extension for one sample."""

    def __init__(self, geometry, ext, h):
        self.h = h
        self.geometry = geometry
        self.ext = ext
        self.velo = find_velo_tracks(h["event_id"], h["layer"], h["u"], h["v"], h["z"],
                                     np.column_stack([h["sigma_u"], h["sigma_v"]]), geometry)
        v = self.velo
        self.state = np.column_stack([v.x, v.y, v.tx, v.ty])
        prep, self.args = kernel_setup(v.event_id, self.state, v.z, h["event_id"], h["layer"], h["u"], h["sigma_u"],
                                       geometry, ext, ForwardOptions())
        self.n_tracks = prep.n_tracks

    def part(self, index: int) -> float:
        c = time.process_time()
        _ut_parts(*self.args, index)
        return time.process_time() - c

    def forward(self) -> float:
        v, h = self.velo, self.h
        c = time.process_time()
        extend_velo_tracks(v.event_id, self.state, v.z, h["event_id"], h["layer"], h["u"], h["sigma_u"],
                           self.geometry, self.ext)
        return time.process_time() - c


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--pileups", type=float, nargs="+", default=[1.0, 4.0, 7.6])
    parser.add_argument("--events", type=int, default=50, help="events per pile-up value")
    parser.add_argument("--repeat", type=int, default=5, help="timed runs (best is kept)")
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--json", type=Path, default=None, help="write the results here")
    args = parser.parse_args()

    geometry = load_geometry("lhcb-like")
    ext = shipped_parameters(geometry).extrapolator(geometry)
    stages = {nu: Stage(geometry, ext, _sample(geometry, args.events, nu, args.seed)["h"]) for nu in args.pileups}
    names = (*PARTS, "forward")
    best = {nu: dict.fromkeys(names, np.inf) for nu in args.pileups}
    for round_ in range(args.repeat + 1):
        for nu, stage in stages.items():
            times = [stage.part(i) for i in range(len(PARTS))] + [stage.forward()]
            if round_:  # round 0 compiles or loads the kernels
                for name, t in zip(names, times):
                    best[nu][name] = min(best[nu][name], t)

    rows = []
    print("UT stage (step 1) per VELO track, µs (CPU, best of repeat); forward: the whole extension")
    print(f"{'nu':>4} {'tracks/ev':>9} " + " ".join(f"{n:>10}" for n in names) + f" {'fwd ms/ev':>10}")
    for nu, stage in stages.items():
        us = {n: 1e6 * best[nu][n] / max(stage.n_tracks, 1) for n in names}
        rows.append({"pileup": nu, "events": args.events, "velo_tracks_per_event": stage.n_tracks / args.events,
                     "cpu_us_per_velo_track": us,
                     "forward_cpu_ms_per_event": 1e3 * best[nu]["forward"] / args.events})
        print(f"{nu:4.1f} {stage.n_tracks / args.events:9.1f} " + " ".join(f"{us[n]:10.2f}" for n in names)
              + f" {rows[-1]['forward_cpu_ms_per_event']:10.2f}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"benchmark": "forward_ut_stage", "seed": args.seed, "repeat": args.repeat,
                                         "parts": list(PARTS), "rows": rows}, indent=2) + "\n")


if __name__ == "__main__":
    main()
