"""Truth-seeded samples and metrics for the forward extension (tests and benchmarks).

The VELO input is built from MC truth (each particle's own VELO hits, a straight-line
least-squares fit in x–z and y–z, state at its last VELO hit), so that the forward
extension is measured independently of the VELO search. Metrics follow DESIGN §10
restricted to the hits the extension adds (UT + SciFi): an extension is correct if ≥ 70 %
of its added hits come from the VELO track's particle, a ghost if < 70 % come from any
single particle.
"""

from __future__ import annotations

import numpy as np

from pkf.geometry.detector import SUBDETECTORS
from pkf.pipeline.matching import reconstructible_particles
from pkf.pipeline.simulate import SimulationConfig, simulate_batch

KEY_SCALE = 1_000_000  # global particle key = event_id·KEY_SCALE + particle_id


def columns(table) -> dict:
    return {c: table.column(c).to_numpy(zero_copy_only=False) for c in table.column_names}


def simulate(geometry, events: int, pileup: float, seed: int):
    """(hits, particles, mc_hits) of lhcb-like minimum bias as dicts of numpy columns."""
    config = SimulationConfig(generator="minbias", events=events, pileup=pileup, seed=seed)
    hits, particles, mc_hits = simulate_batch(geometry, config, 0, events)
    return columns(hits), columns(particles), columns(mc_hits)


def truth_velo_tracks(geometry, h: dict, m: dict, min_hits: int = 3) -> dict:
    """One VELO track per particle with ≥ min_hits VELO hits: straight-line fit of its
    own hits (x–z, y–z, equal weights), state (x, y, tx, ty) at its last VELO hit."""
    velo = geometry.layer_subdetector[h["layer"]] == SUBDETECTORS.index("velo")
    sel = np.flatnonzero(velo & (m["particle_id"] > 0))
    key = h["event_id"][sel] * KEY_SCALE + m["particle_id"][sel]
    order = np.lexsort((h["z"][sel], key))
    sel, key = sel[order], key[order]
    z, x, y = h["z"][sel], h["u"][sel], h["v"][sel]
    keys, start, count = np.unique(key, return_index=True, return_counts=True)
    last = start + count - 1
    z_last = z[last]
    dz = z - np.repeat(z_last, count)
    s0 = count.astype(float)
    s1 = np.add.reduceat(dz, start)
    s2 = np.add.reduceat(dz * dz, start)
    det = s0 * s2 - s1 * s1
    good = (count >= min_hits) & (det > 0)

    def line(v):
        r0 = np.add.reduceat(v, start)
        r1 = np.add.reduceat(v * dz, start)
        with np.errstate(invalid="ignore", divide="ignore"):
            return (s2 * r0 - s1 * r1) / det, (s0 * r1 - s1 * r0) / det

    x0, tx = line(x)
    y0, ty = line(y)
    return {
        "key": keys[good], "event": keys[good] // KEY_SCALE, "z": z_last[good],
        "state": np.column_stack([x0, y0, tx, ty])[good],
    }


def extension_metrics(geometry, result, velo: dict, h: dict, p: dict, m: dict) -> dict:
    """Efficiency (correct extensions of long-reconstructible particles) per momentum
    bin, also for particles without UT hits, ghost rate, and the q/p resolution."""
    hit_key = np.where(m["particle_id"] > 0, h["event_id"] * KEY_SCALE + m["particle_id"], 0)
    long_keys = reconstructible_particles(geometry, hit_key, h["layer"])
    p_key = p["event_id"] * KEY_SCALE + p["particle_id"]
    mom = np.sqrt(p["px"] ** 2 + p["py"] ** 2 + p["pz"] ** 2)
    idx = np.searchsorted(p_key, velo["key"])
    p_true = mom[idx]
    qop_true = p["charge"][idx] / p_true
    is_long = np.isin(velo["key"], long_keys)
    ut = geometry.layer_subdetector[h["layer"]] == SUBDETECTORS.index("ut")
    ut_keys, ut_count = np.unique(hit_key[ut & (hit_key > 0)], return_counts=True)
    pos = np.clip(np.searchsorted(ut_keys, velo["key"]), 0, max(ut_keys.size - 1, 0))
    n_ut_true = np.where(ut_keys[pos] == velo["key"], ut_count[pos], 0) if ut_keys.size else 0

    n = result.n_tracks
    track = result.track_of_hit
    added = hit_key[result.hit_rows]
    n_added = result.n_hits
    own = np.bincount(track, weights=added == velo["key"][track], minlength=n)
    found = result.found  # extended into the SciFi (UT-only "upstream" tracks do not count)
    correct = found & (own >= 0.7 * np.maximum(n_added, 1))
    # largest fraction of the added hits from a single particle (noise never counts)
    best = np.zeros(n)
    if added.size:
        pairs, cnt = np.unique(np.column_stack([track, added]), axis=0, return_counts=True)
        cnt = np.where(pairs[:, 1] > 0, cnt, 0)
        np.maximum.at(best, pairs[:, 0], cnt)
    ghost = found & (best < 0.7 * np.maximum(n_added, 1))

    def eff(mask):
        return (float(correct[mask].mean()) if mask.any() else float("nan")), int(mask.sum())

    bins = {"p_gt_5GeV": is_long & (p_true > 5000), "p_2_5GeV": is_long & (p_true > 2000) & (p_true <= 5000),
            "p_lt_2GeV": is_long & (p_true <= 2000),
            "no_ut_p_gt_5GeV": is_long & (p_true > 5000) & (n_ut_true == 0),
            "no_ut_p_2_5GeV": is_long & (p_true > 2000) & (p_true <= 5000) & (n_ut_true == 0),
            "p_gt_2GeV": is_long & (p_true > 2000)}
    out = {"velo_tracks": int(n), "long": int(is_long.sum()), "extensions": int(found.sum()),
           "ghosts": int(ghost.sum()),
           "ghost_rate": float(ghost.sum() / max(found.sum(), 1))}
    for name, mask in bins.items():
        out[f"efficiency_{name}"], out[f"n_{name}"] = eff(mask)
    ok = correct & is_long & (p_true > 2000) & np.isfinite(result.qop)
    rel = (result.qop[ok] - qop_true[ok]) / np.abs(qop_true[ok])
    pull = (result.qop[ok] - qop_true[ok]) / np.sqrt(result.qop_var[ok])
    for name, lo, hi in (("2_5GeV", 2000, 5000), ("5_20GeV", 5000, 20000), ("gt_20GeV", 20000, np.inf)):
        sel = (p_true[ok] > lo) & (p_true[ok] <= hi)
        r = rel[sel]
        out[f"qop_resolution_core_{name}"] = (float(0.5 * np.diff(np.percentile(r, [15.87, 84.13]))[0])
                                              if r.size > 10 else float("nan"))
        out[f"qop_resolution_rms_{name}"] = float(np.sqrt(np.mean(r ** 2))) if r.size else float("nan")
        out[f"qop_bias_{name}"] = float(np.median(r)) if r.size else float("nan")
        out[f"qop_pull_core_{name}"] = (float(0.5 * np.diff(np.percentile(pull[sel], [15.87, 84.13]))[0])
                                        if r.size > 10 else float("nan"))
    out["masks"] = {"correct": correct, "ghost": ghost, "is_long": is_long, "p_true": p_true,
                    "n_ut_true": n_ut_true}
    return out


def random_reference(n_fwd: int, rng) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A reference for filters on synthetic hits (n_fwd forward layers): the straight
    trajectory at (x, y) = (300, 200) mm, slopes (0.04, 0.025), 8 GeV, Jacobians near the
    identity with q/p kept (row 4 = e₄) and 70 mm lever arms, process noise in position and
    slope. Returns (states (n_fwd, 5), F (n_fwd, 5, 5), Q (n_fwd, 5, 5))."""
    ref_s = np.tile([300.0, 200.0, 0.04, 0.025, 1.0 / 8000.0], (n_fwd, 1))
    F = np.tile(np.eye(5), (n_fwd, 1, 1))
    F[:, :4, :] += rng.normal(scale=[[1e-3, 1e-3, 1e-4, 1e-4, 1.0]] * 4, size=(n_fwd, 4, 5))
    F[:, 0, 2] += 70.0
    F[:, 1, 3] += 70.0
    Q = np.zeros((n_fwd, 5, 5))
    for j in range(n_fwd):
        a = rng.normal(size=(4, 4)) * [1e-2, 1e-2, 1e-5, 1e-5]
        Q[j, :4, :4] = a @ a.T
    return ref_s, F, Q
