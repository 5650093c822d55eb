"""Forward extension of VELO tracks into the UT and the SciFi (pkf.seeding.forward, DESIGN §7.4).

Physics performance on simulated lhcb-like minimum bias at ν = 7.6 with VELO tracks from
MC truth (so that it does not depend on the VELO search): efficiency of long-reconstructible
particles per momentum bin (≥ 70 % of the added UT + SciFi hits from the particle), also
without UT hits, ghost rate and the q/p resolution; the structure of the output; input
handling; and the parametrized transport of `pkf.seeding.forward_steps` against the
extrapolator of the Kalman fit.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np
import pytest

from pkf.errors import InputError
from pkf.geometry import load_geometry
from pkf.geometry.detector import SUBDETECTORS
from pkf.params.parameter_set import shipped_parameters
from pkf.params.transport import parametrized_step
from pkf.params.ut_to_scifi import localize_ut_to_scifi, ut_to_scifi_extrapolate_localized, without_soft_range
from pkf.seeding.forward import (
    STATUS_INVALID,
    STATUS_NO_SCIFI,
    STATUS_NO_UT,
    STATUS_NOT_FOUND,
    STATUS_OK,
    ForwardOptions,
    extend_velo_tracks,
)
from pkf.seeding.forward.hough import hough_grid, q_of_t, t_of_q
from pkf.seeding.forward_steps import (
    TRANSPORT_BELOW_P_MIN,
    TRANSPORT_FAILED,
    TRANSPORT_OK,
    new_table_buffers,
    reference_trajectory,
    scan_states,
)

sys.path.insert(0, str(Path(__file__).resolve().parent))
from forward_helpers import (  # noqa: E402
    KEY_SCALE,
    extension_metrics,
    simulate,
    truth_velo_tracks,
)

log = logging.getLogger(__name__)

EVENTS = 20
PILEUP = 7.6
SEED = 11


@pytest.fixture(scope="module")
def geometry():
    return load_geometry("lhcb-like")


@pytest.fixture(scope="module")
def ext(geometry):
    return shipped_parameters(geometry).extrapolator(geometry)


@pytest.fixture(scope="module")
def sample(geometry, ext):
    h, p, m = simulate(geometry, EVENTS, PILEUP, SEED)
    velo = truth_velo_tracks(geometry, h, m)
    result = extend_velo_tracks(velo["event"], velo["state"], velo["z"], h["event_id"], h["layer"],
                                h["u"], h["sigma_u"], geometry, ext)
    metrics = extension_metrics(geometry, result, velo, h, p, m)
    log.info("forward extension, %d lhcb-like minbias events at nu=%.1f: %s", EVENTS, PILEUP,
             {k: v for k, v in metrics.items() if k != "masks"})
    free = extend_velo_tracks(velo["event"], velo["state"], velo["z"], h["event_id"], h["layer"],
                              h["u"], h["sigma_u"], geometry, ext, take_hits=False)
    metrics_free = extension_metrics(geometry, free, velo, h, p, m)
    log.info("... without taken hits: %s", {k: v for k, v in metrics_free.items() if k != "masks"})
    return {"h": h, "p": p, "m": m, "velo": velo, "result": result, "metrics": metrics,
            "metrics_free": metrics_free}


# ------------------------------------------------------------------------------------
# physics performance
# ------------------------------------------------------------------------------------

def test_efficiency_and_ghost_rate(sample):
    """Long-reconstructible particles (DESIGN §10) are extended with ≥ 70 % correct hits;
    measured on this sample: 97.9 % above 5 GeV, 95.6 % at 2–5 GeV, 0.3 % ghosts (the VELO
    tracks are from MC truth: no VELO ghosts to extend)."""
    met = sample["metrics"]
    assert met["n_p_gt_5GeV"] > 2500 and met["n_p_2_5GeV"] > 700
    assert met["efficiency_p_gt_5GeV"] >= 0.95, met
    assert met["efficiency_p_2_5GeV"] >= 0.92, met
    assert met["ghost_rate"] <= 0.02, met


def test_tracks_without_ut_hits_are_found(sample):
    """Particles crossing the UT beam hole or gaps (no UT hit) are found by the q/p scan
    with the VELO state alone (≈ 85 % above 5 GeV)."""
    met = sample["metrics"]
    assert met["n_no_ut_p_gt_5GeV"] > 100
    assert met["efficiency_no_ut_p_gt_5GeV"] >= 0.72, met
    # and they are reported without UT hits, or with few
    masks = sample["metrics"]["masks"]
    res = sample["result"]
    sel = masks["correct"] & (masks["n_ut_true"] == 0)
    assert np.mean(res.status[sel] == STATUS_NO_UT) > 0.6


def test_qop_resolution(sample):
    """q/p of correct extensions: core resolution ≲ 0.5 % (the VELO–SciFi kink), unbiased,
    and its variance describes the core (pull width ≈ 1–1.4)."""
    met = sample["metrics"]
    for name in ("2_5GeV", "5_20GeV", "gt_20GeV"):
        assert met[f"qop_resolution_core_{name}"] < 0.006, (name, met)
        assert abs(met[f"qop_bias_{name}"]) < 0.001, (name, met)
        assert 0.8 < met[f"qop_pull_core_{name}"] < 1.6, (name, met)


def test_output_structure(sample, geometry):
    res = sample["result"]
    h = sample["h"]
    velo = sample["velo"]
    n = velo["key"].size
    assert res.n_tracks == n and res.offsets.shape == (n + 1,) and res.offsets[0] == 0
    assert np.all(np.diff(res.offsets) >= 0) and res.offsets[-1] == res.hit_rows.size
    assert np.array_equal(res.n_hits, res.n_ut + res.n_scifi)
    t = res.track_of_hit
    rows = res.hit_rows
    # hits of the track's event, on UT/SciFi layers, at most one per layer, sorted by z
    assert np.array_equal(h["event_id"][rows], velo["event"][t])
    sub = geometry.layer_subdetector[h["layer"][rows]]
    assert np.all((sub == SUBDETECTORS.index("ut")) | (sub == SUBDETECTORS.index("scifi")))
    n_ut = np.bincount(t, weights=sub == SUBDETECTORS.index("ut"), minlength=n)
    assert np.array_equal(n_ut, res.n_ut)
    layer_key = t * 1000 + h["layer"][rows]
    assert np.unique(layer_key).size == layer_key.size
    assert np.all(np.diff(layer_key) > 0)  # per track, increasing layer (z) order
    # statuses
    ok = res.status == STATUS_OK
    assert np.all(res.n_ut[ok] > 0) and np.all(res.n_scifi[ok] >= ForwardOptions().scifi_min_hits)
    no_ut = res.status == STATUS_NO_UT
    assert np.all(res.n_ut[no_ut] == 0) and np.all(res.n_scifi[no_ut] >= ForwardOptions().no_ut_min_hits)
    up = res.upstream  # STATUS_NO_SCIFI with UT hits; without them a VELO track (no hits, no q/p)
    assert np.all(res.status[up] == STATUS_NO_SCIFI) and np.all(res.n_scifi[up] == 0)
    assert np.all(res.n_ut[up] >= max(ForwardOptions().ut_min_hits, 4))
    velo_only = (res.status == STATUS_NO_SCIFI) & ~up
    assert velo_only.any() and np.all(res.n_hits[velo_only] == 0) and np.all(np.isnan(res.qop[velo_only]))
    none = res.status == STATUS_NOT_FOUND
    assert np.all(res.n_hits[none] == 0) and np.all(np.isnan(res.qop[none]))
    found = res.found
    assert np.all(np.isfinite(res.qop[found])) and np.all(res.qop_var[found] > 0)
    assert np.all(res.ndf[found] == res.n_hits[found] - 1)
    assert np.array_equal(res.below_table_p_min, np.abs(res.qop) > 1.0 / 3000.0)
    # most VELO tracks of long particles are extended; few of the others (ghost sources)
    masks = sample["metrics"]["masks"]
    assert found[masks["is_long"]].mean() > 0.9
    assert found[~masks["is_long"]].mean() < 0.25


def _same_extensions(sub, res, tracks, hit_perm):
    assert np.array_equal(sub.status, res.status[tracks])
    np.testing.assert_allclose(sub.qop, res.qop[tracks], rtol=1e-9, atol=0.0, equal_nan=True)
    for i, t in enumerate(tracks):
        mine = np.sort(hit_perm[sub.hit_rows[sub.offsets[i]:sub.offsets[i + 1]]])
        full = np.sort(res.hit_rows[res.offsets[t]:res.offsets[t + 1]])
        assert np.array_equal(mine, full)


def test_hit_order_and_batching_do_not_matter(sample, geometry, ext):
    """Hits in any order and events in any subset give the same extensions (the hit rows
    refer to the caller's arrays); without taken hits (take_hits=False) the tracks are
    independent and any subset of them gives the same extensions too."""
    h, velo, res = sample["h"], sample["velo"], sample["result"]
    events = np.unique(velo["event"])[1:8:2]
    in_events = np.isin(h["event_id"], events)
    rng = np.random.default_rng(5)
    perm = rng.permutation(np.flatnonzero(in_events))
    hits = (h["event_id"][perm], h["layer"][perm], h["u"][perm], h["sigma_u"][perm])
    tracks = np.flatnonzero(np.isin(velo["event"], events))
    sub = extend_velo_tracks(velo["event"][tracks], velo["state"][tracks], velo["z"][tracks], *hits,
                             geometry, ext)
    _same_extensions(sub, res, tracks, perm)
    free = dict(take_hits=False)
    all_free = extend_velo_tracks(velo["event"], velo["state"], velo["z"], h["event_id"], h["layer"], h["u"],
                                  h["sigma_u"], geometry, ext, **free)
    some = tracks[::2]
    sub_free = extend_velo_tracks(velo["event"][some], velo["state"][some], velo["z"][some], *hits,
                                  geometry, ext, **free)
    _same_extensions(sub_free, all_free, some, perm)


def test_good_extensions_take_their_hits(sample):
    """A good extension of the first pass (p-value ≥ good_pvalue, ≥ 11 SciFi hits, from a UT
    start) takes its hits: no later track of its event has any of them; and taking them
    lowers the ghost rate without losing efficiency (the second-pass scan sees fewer
    random hits)."""
    from scipy.stats import chi2 as chi2_dist

    res, velo = sample["result"], sample["velo"]
    options = ForwardOptions()
    good = res.found & (chi2_dist.sf(res.chi2, np.maximum(res.ndf, 1)) >= options.good_pvalue) \
        & (res.n_scifi >= 11) & ~res.from_scan
    assert good.mean() > 0.5 and 0.0 < res.from_scan[res.found].mean() < 0.3
    t = res.track_of_hit
    order = np.lexsort((t, res.hit_rows))  # by hit, then track
    rows, owner = res.hit_rows[order], t[order]
    shared = np.flatnonzero(rows[1:] == rows[:-1])
    assert shared.size > 0  # hits are shared, but never after a good extension took them
    assert not np.any(good[owner[shared]] & (owner[shared + 1] > owner[shared])
                      & (velo["event"][owner[shared + 1]] == velo["event"][owner[shared]]))
    free = sample["metrics_free"]
    met = sample["metrics"]
    assert met["ghost_rate"] < 0.85 * free["ghost_rate"], (met["ghost_rate"], free["ghost_rate"])
    assert met["efficiency_p_gt_5GeV"] >= free["efficiency_p_gt_5GeV"] - 0.003
    assert met["efficiency_p_2_5GeV"] >= free["efficiency_p_2_5GeV"] - 0.005


# ------------------------------------------------------------------------------------
# the UT outlier check of the final fit (pkf.seeding.forward.outliers, issue 15)
# ------------------------------------------------------------------------------------

#: the UT outlier check switched off (the search as before it existed), upstream tracks included
NO_UT_CHECK = dict(ut_outlier_chi2=np.inf, ut_swap_margin=np.inf, ut_ambiguous_chi2=0.0, upstream_ambiguous_chi2=0.0)


def _ut_hits_of_correct(sample, geometry, res):
    """Per UT hit of a correct extension: its track, UT layer index, whether it is foreign
    (another particle's or noise), and the extension metrics."""
    h, m, velo = sample["h"], sample["m"], sample["velo"]
    met = extension_metrics(geometry, res, velo, h, sample["p"], m)
    hit_key = np.where(m["particle_id"] > 0, h["event_id"] * KEY_SCALE + m["particle_id"], 0)
    ut_layers = np.flatnonzero(geometry.layer_subdetector == SUBDETECTORS.index("ut"))
    t = res.track_of_hit
    sel = met["masks"]["correct"][t] & np.isin(h["layer"][res.hit_rows], ut_layers)
    rows, t = res.hit_rows[sel], t[sel]
    return t, np.searchsorted(ut_layers, h["layer"][rows]), hit_key[rows] != velo["key"][t], met


def _foreign_ut_share(sample, geometry, res):
    t, _, foreign, met = _ut_hits_of_correct(sample, geometry, res)
    correct = met["masks"]["correct"]
    return float(np.isin(np.flatnonzero(correct), t[foreign]).mean()), met


@pytest.fixture(scope="module")
def no_ut_check(sample, geometry, ext):
    """The extension of the sample with the UT outlier check switched off."""
    h, velo = sample["h"], sample["velo"]
    return extend_velo_tracks(velo["event"], velo["state"], velo["z"], h["event_id"], h["layer"], h["u"],
                              h["sigma_u"], geometry, ext, **NO_UT_CHECK)


def test_foreign_ut_hits_are_rare(sample, geometry, no_ut_check):
    """Correct extensions that carry a UT hit of another particle: measured on this sample
    2.0 % with the UT outlier check (4.5 % with its ambiguity cut at 4 instead of 9), 24.9 %
    without (close tracks swap hits in the u-only UT); efficiency within 0.3–0.5 points (> 5 GeV
    97.96 vs 98.10 %, 2–5 GeV 95.41 vs 95.86 %), ghost rate 0.13 vs 0.29 %."""
    share, met = _foreign_ut_share(sample, geometry, sample["result"])
    off = no_ut_check
    share_off, met_off = _foreign_ut_share(sample, geometry, off)
    assert share < 0.035 and share_off > 0.18, (share, share_off)
    assert met["efficiency_p_gt_5GeV"] >= met_off["efficiency_p_gt_5GeV"] - 0.003
    assert met["efficiency_p_2_5GeV"] >= met_off["efficiency_p_2_5GeV"] - 0.005
    assert met["ghost_rate"] <= met_off["ghost_rate"] + 0.001


def _upstream_foreign_share(sample, geometry, res):
    """(upstream tracks, share of them with a UT hit of another particle or noise)."""
    h, m, velo = sample["h"], sample["m"], sample["velo"]
    hit_key = np.where(m["particle_id"] > 0, h["event_id"] * KEY_SCALE + m["particle_id"], 0)
    ut = geometry.layer_subdetector[h["layer"][res.hit_rows]] == SUBDETECTORS.index("ut")
    t = res.track_of_hit
    bad = ut & (hit_key[res.hit_rows] != velo["key"][t])
    foreign = np.bincount(t[bad], minlength=res.upstream.size) > 0
    up = res.upstream
    return int(up.sum()), float(foreign[up].mean())


def test_upstream_tracks_rarely_carry_foreign_ut_hits(sample, geometry, no_ut_check):
    """Upstream tracks (no SciFi extension, VELO + UT hits) are made after every long track
    took its UT hits (`pkf.seeding.forward.upstream`), pass the UT outlier check against
    their VELO + UT fit and need 4 UT hits after it, else they stay VELO tracks (issue 15).
    Measured on this sample: 1.7 % of 475 upstream tracks carry a foreign UT hit, 14.8 % of
    683 without the check; before the upstream pass (UT candidates of the first pass, taken
    by no long track): 12.1 % of 481, 30.9 % of 719 without the check."""
    n_up, share = _upstream_foreign_share(sample, geometry, sample["result"])
    n_off, share_off = _upstream_foreign_share(sample, geometry, no_ut_check)
    assert n_up > 400, n_up
    assert share < 0.04 and share_off > 0.1, (share, share_off)


def test_upstream_tracks_share_no_ut_hit(sample, geometry):
    """No UT hit of an upstream track is a UT hit of a long track or of another upstream
    track: the long tracks take theirs before the upstream search, and a hit two upstream
    tracks hold goes to the one with the lower χ² (the other searches again). Before, on 60
    events at ν = 7.6, 78 of the 95 upstream tracks with four foreign UT hits held the hits
    of a long track."""
    res = sample["result"]
    ut = geometry.layer_subdetector[sample["h"]["layer"][res.hit_rows]] == SUBDETECTORS.index("ut")
    t = res.track_of_hit
    up_rows = res.hit_rows[ut & res.upstream[t]]
    long_rows = res.hit_rows[ut & (res.status[t] == STATUS_OK)]
    assert up_rows.size > 1600
    assert np.unique(up_rows).size == up_rows.size
    assert not np.isin(up_rows, long_rows).any()


def test_ut_hit_chi2_is_calibrated(sample, geometry):
    """The χ² of a UT hit against the rest of its extension (ut_chi2) follows χ²(1) for the
    particle's own hits (measured: mean 0.99, 90 % quantile 2.7); it is given for every UT
    hit of an extension and NaN on the layers without one."""
    res = sample["result"]
    t, j, foreign, _ = _ut_hits_of_correct(sample, geometry, res)
    chi = res.ut_chi2[t, j]
    assert np.all(np.isfinite(chi))
    own = chi[~foreign]
    assert 0.85 < own.mean() < 1.15 and 2.2 < np.quantile(own, 0.9) < 3.2, (own.mean(), np.quantile(own, 0.9))
    has_hit = np.zeros(res.ut_chi2.shape, dtype=bool)
    has_hit[t, j] = True
    correct = np.zeros(res.n_tracks, dtype=bool)
    correct[t] = True
    assert np.all(np.isnan(res.ut_chi2[correct][~has_hit[correct]]))
    assert np.mean(chi > ForwardOptions().ut_outlier_chi2) < 0.002


def _move_first_ut_hit(sample, geometry, t, shift):
    """The hits of track t's event with its hit on the first UT layer moved by shift [mm]
    towards the VELO track's straight line: (extend_velo_tracks arguments, the moved row)."""
    h, velo, res = sample["h"], sample["velo"], sample["result"]
    mine = res.hit_rows[res.offsets[t]:res.offsets[t + 1]]
    ut_layer0 = np.flatnonzero(geometry.layer_subdetector == SUBDETECTORS.index("ut"))[0]
    row = int(mine[h["layer"][mine] == ut_layer0][0])
    x, y, tx, ty = velo["state"][t]
    dz = h["z"][row] - velo["z"][t]
    u_line = geometry.layer_cos[ut_layer0] * (x + tx * dz) + geometry.layer_sin[ut_layer0] * (y + ty * dz)
    in_event = np.flatnonzero(h["event_id"] == velo["event"][t])
    u = h["u"][in_event].copy()
    moved = int(np.flatnonzero(in_event == row)[0])
    u[moved] += shift * np.sign(u_line - u[moved])
    return (velo["event"][t:t + 1], velo["state"][t:t + 1], velo["z"][t:t + 1], h["event_id"][in_event],
            h["layer"][in_event], u, h["sigma_u"][in_event]), moved


def test_ut_hit_off_the_velo_scifi_track_is_dropped(sample, geometry, ext):
    """3–6 GeV long tracks with their four own UT hits; the hit on the first UT layer is
    moved 0.3 or 0.4 mm towards the VELO track's straight line (a hit of another particle
    inside the UT windows the VELO state opens). Where the search without the check takes
    it and its χ² against the rest of the track exceeds the cut and is the track's largest
    (4 of the 24 cases of this sample; in the others the final fit's window already rejects
    it, or the track bends to it, or — one case at 0.3 mm, χ² 9.0 against its neighbour's
    9.5 — the check's rule, the largest χ² first, takes the neighbour), the check removes
    it and keeps the SciFi hits."""
    res = sample["result"]
    t_hit, _, foreign, met = _ut_hits_of_correct(sample, geometry, res)
    p_true = met["masks"]["p_true"]
    clean4 = np.bincount(t_hit[~foreign], minlength=res.n_tracks) == 4
    cut = ForwardOptions().ut_outlier_chi2
    tested = 0
    for shift in (0.3, 0.4):
        for t in np.flatnonzero(clean4 & (res.n_ut == 4) & (p_true > 3000) & (p_true < 6000))[:12]:
            args, moved = _move_first_ut_hit(sample, geometry, int(t), shift)
            off = extend_velo_tracks(*args, geometry, ext, **NO_UT_CHECK)
            worst = off.ut_chi2[0, 0] >= np.nanmax(off.ut_chi2[0])
            if not (off.status[0] == STATUS_OK and moved in off.hit_rows and off.ut_chi2[0, 0] > cut and worst):
                continue
            tested += 1
            on = extend_velo_tracks(*args, geometry, ext)
            assert on.found[0] and moved not in on.hit_rows, (shift, t, off.ut_chi2[0], on.ut_chi2[0])
            assert on.n_scifi[0] >= off.n_scifi[0] - 1
            assert np.all(on.ut_chi2[0][np.isfinite(on.ut_chi2[0])] <= cut)
    assert tested >= 1


# ------------------------------------------------------------------------------------
# input handling
# ------------------------------------------------------------------------------------

def test_invalid_and_empty_inputs(sample, geometry, ext):
    h, velo = sample["h"], sample["velo"]
    hits = (h["event_id"], h["layer"], h["u"], h["sigma_u"])
    state = velo["state"][:3].copy()
    z = velo["z"][:3].copy()
    state[0, 2] = np.nan  # NaN slope
    z[1] = 5000.0  # not in the VELO
    res = extend_velo_tracks(velo["event"][:3], state, z, *hits, geometry, ext)
    assert res.status[0] == STATUS_INVALID and res.status[1] == STATUS_INVALID
    assert res.status[2] != STATUS_INVALID
    # no tracks; a track of an event without hits
    empty = extend_velo_tracks(np.zeros(0, dtype=np.int64), np.zeros((0, 4)), np.zeros(0), *hits,
                               geometry, ext)
    assert empty.n_tracks == 0 and empty.hit_rows.size == 0
    lonely = extend_velo_tracks(np.array([10**9]), velo["state"][:1], velo["z"][:1], *hits, geometry, ext)
    assert lonely.status[0] == STATUS_NOT_FOUND and lonely.hit_rows.size == 0
    with pytest.raises(ValueError):
        extend_velo_tracks(velo["event"][:3], velo["state"][:2], velo["z"][:3], *hits, geometry, ext)
    with pytest.raises(ValueError):
        ForwardOptions(p_min=-1.0)
    telescope = load_geometry("telescope")
    with pytest.raises(InputError):
        extend_velo_tracks(velo["event"][:1], velo["state"][:1], velo["z"][:1], *hits, telescope,
                           shipped_parameters(telescope).extrapolator(telescope))


def test_a_scan_whose_derivatives_overflow_fails(geometry, ext):
    """The full-range scan of a steep VELO track (minimum bias, ν = 2, seed 2024, event 18 of
    40): at the lowest q/p node its state at the last SciFi layer is finite but its
    derivative d/dq is not. The scan must fail there; it returned "below p_min" with
    non-finite derivatives, from which a hit's implied q/p was NaN, whose Hough cell index
    (an undefined integer conversion) read out of bounds: a ZeroDivisionError or garbage,
    depending on the memory next to the table."""
    search_ext = ext._replace(uts_meta=without_soft_range(ext.uts_meta))
    sub = geometry.layer_subdetector
    ut = np.flatnonzero(sub == SUBDETECTORS.index("ut"))
    scifi = np.flatnonzero(sub == SUBDETECTORS.index("scifi")).astype(np.int64)
    s0 = np.array([-590.1448802120352, 567.5072790529027, -0.2259109470610586, 0.21716747641854234, 0.0])
    ds0 = np.array([11579.58901139595, -2723.578252251812, 24.141367825237655, -9.593494038876399, 1.0])
    q = np.linspace(-1.0, 1.0, 9) / 1500.0
    poly, ref = new_table_buffers(search_ext)
    localize_ut_to_scifi(search_ext.uts_meta, search_ext.uts_cells, s0[0], s0[1], poly, ref)
    xs, dxs, ys, dys = (np.zeros((q.size, scifi.size)) for _ in range(4))
    status = scan_states(search_ext, poly, ref, True, int(ut[-1]), scifi, s0, ds0, q, xs, dxs, ys, dys,
                         np.zeros((4, 5, 5)))
    assert status == TRANSPORT_FAILED
    # the higher momenta alone transport (the failing node is the lowest momentum's)
    status = scan_states(search_ext, poly, ref, True, int(ut[-1]), scifi, s0, ds0, q[2:], xs, dxs, ys, dys,
                         np.zeros((4, 5, 5)))
    assert status != TRANSPORT_FAILED
    assert np.isfinite(xs[: q.size - 2]).all() and np.isfinite(dxs[: q.size - 2]).all()


def test_hough_coordinates_of_non_finite_values_stay_in_the_table():
    """t_of_q/q_of_t of NaN is NaN and of ±inf is ±inf, from the last interval: no cell is
    looked up from an undefined integer conversion (they read out of bounds)."""
    hough = hough_grid(1e-7, 3e-3, 1.0 / 1500.0)
    out = np.array([[t_of_q(v, hough), q_of_t(v, hough)] for v in (np.nan, np.inf, -np.inf, 1e300, 2e-4)])
    assert np.isnan(out[0]).all()
    assert (out[1] == np.inf).all() and (out[2] == -np.inf).all() and (out[3] > 0).all()
    np.testing.assert_allclose(q_of_t(t_of_q(2e-4, hough), hough), 2e-4, rtol=1e-12)


# ------------------------------------------------------------------------------------
# the parametrized transport of the search
# ------------------------------------------------------------------------------------

def _chain(ext, s, z_from, z_to):
    out, jac, noise, work = np.zeros(5), np.zeros((5, 5)), np.zeros((5, 5)), np.zeros((6, 5, 5))
    status = parametrized_step(ext, s, z_from, z_to, out, jac, noise, work)
    return status, out, jac, noise


def test_reference_trajectory_equals_parametrized_step(geometry, ext):
    """Above the table's p_min the reference trajectory is the Kalman fit's extrapolation:
    same states, Jacobians and noise (the table localised at the last UT state), except
    for the scattering of VELO layers crossed without a hit, which the Kalman step adds
    (`pkf.params.transport.add_crossed_velo_layers`) and the search does not: it starts
    at the VELO track's first hit and carries the VELO state's scattering error in its
    own start covariance (ForwardOptions' VELO terms); with that term it found 0.6 points
    fewer long tracks and 1.0 point more ghosts (60 minimum-bias events, ν = 7.6). So the
    Kalman step is taken here with no layer counted as crossed."""
    area = ext.layer_area.copy()
    area[:, 0] = -1.0  # no point lies on a layer: no crossed-layer term
    kalman_ext = ext._replace(layer_area=area)
    layer_z = geometry.layer_z
    sub = geometry.layer_subdetector
    velo = np.flatnonzero(sub == 0)
    f_layer = np.flatnonzero(sub > 0).astype(np.int64)
    n_ut = int(np.sum(sub == 1))
    poly, ref = new_table_buffers(ext)
    rng = np.random.default_rng(3)
    for _ in range(20):
        a = int(rng.choice(velo[-10:]))
        q = rng.uniform(-1.0, 1.0) / 3200.0
        s = np.array([rng.normal(0, 5), rng.normal(0, 5), rng.normal(0, 0.08), rng.normal(0, 0.06), q])
        _, s_ut, _, _ = _chain(kalman_ext, s, layer_z[a], layer_z[f_layer[n_ut - 1]])
        localize_ut_to_scifi(ext.uts_meta, ext.uts_cells, s_ut[0], s_ut[1], poly, ref)
        ref_s = np.zeros((f_layer.size, 5))
        ref_f = np.zeros((f_layer.size, 5, 5))
        ref_q = np.zeros((f_layer.size, 5, 5))
        status = reference_trajectory(ext, poly, ref, True, a, f_layer, n_ut, f_layer.size, s, abs(q),
                                      ref_s, ref_f, ref_q, np.zeros(5))
        assert status == TRANSPORT_OK
        prev_z, prev_s = layer_z[a], s
        for j, lay in enumerate(f_layer):
            st, out, jac, noise = _chain(kalman_ext, prev_s, prev_z, layer_z[lay])
            assert st == 0
            np.testing.assert_allclose(ref_s[j], out, rtol=1e-12, atol=1e-9)
            np.testing.assert_allclose(ref_f[j], jac, rtol=1e-10, atol=1e-12)
            np.testing.assert_allclose(ref_q[j], noise, rtol=1e-10, atol=1e-20)
            prev_z, prev_s = layer_z[lay], out


def test_table_continuation_below_p_min(ext, sample, geometry):
    """The table covers p ≥ 1.5 GeV (its soft range below p_min = 3 GeV, `pkf.params.ut_to_scifi`):
    the localised evaluation is continuous at 3 GeV and at 1.5 GeV, below 1.5 GeV the
    quadratic continuation's Jacobian is the derivative of what it returns, and 2–2.5 GeV
    particles are predicted at the first SciFi layer by the table itself (status OK, the
    same with either continuation), to the scattering (median 11 mm from the VELO state;
    the 3 GeV table's quadratic continuation: ≈ 15 mm, its linear one ≈ 30 mm)."""
    poly, ref = new_table_buffers(ext)
    s = np.array([150.0, -80.0, 0.07, -0.03, 0.0])
    localize_ut_to_scifi(ext.uts_meta, ext.uts_cells, s[0], s[1], poly, ref)
    eloss = ext.extrapolation[int(np.flatnonzero(geometry.layer_subdetector == 1)[-1]), 0]
    out, jac = np.zeros(5), np.zeros((5, 5))

    def f(state):
        o, j = np.zeros(5), np.zeros((5, 5))
        st = ut_to_scifi_extrapolate_localized(ext.uts_meta, poly, ref, eloss, state, o, j, True)
        return st, o, j

    # continuity at 3 GeV (w = ±1 at the energy-loss corrected q/p) and at 1.5 GeV (w = ±2)
    for p_edge, beyond in ((3000.0, TRANSPORT_OK), (1500.0, TRANSPORT_BELOW_P_MIN)):
        for sign in (1.0, -1.0):
            q_edge = sign / (p_edge + eloss)
            lo = s.copy()
            lo[4] = q_edge * (1 - 1e-9)
            hi = s.copy()
            hi[4] = q_edge * (1 + 1e-9)
            st_lo, o_lo, _ = f(lo)
            st_hi, o_hi, _ = f(hi)
            assert st_lo == TRANSPORT_OK and st_hi == beyond
            np.testing.assert_allclose(o_lo, o_hi, atol=1e-5)
    # Jacobian of the continuation = finite differences
    s2 = s.copy()
    s2[4] = 1.0 / 1300.0
    st, out, jac = f(s2)
    assert st == TRANSPORT_BELOW_P_MIN
    eps = np.array([1e-3, 1e-3, 1e-6, 1e-6, 1e-9])
    for k in range(5):
        up, dn = s2.copy(), s2.copy()
        up[k] += eps[k]
        dn[k] -= eps[k]
        num = (f(up)[1] - f(dn)[1]) / (2 * eps[k])
        np.testing.assert_allclose(jac[:4, k], num[:4], rtol=1e-5, atol=1e-6 * max(1.0, np.abs(num).max()))
    # against MC truth: x at the first SciFi layer of 2–2.5 GeV pions (true q/p)
    h, p, m, velo = sample["h"], sample["p"], sample["m"], sample["velo"]
    p_key = p["event_id"] * KEY_SCALE + p["particle_id"]
    idx = np.searchsorted(p_key, velo["key"])
    mom = np.sqrt(p["px"] ** 2 + p["py"] ** 2 + p["pz"] ** 2)[idx]
    pion = np.abs(p["pdg"][idx]) == 211
    first_sf = int(np.flatnonzero(geometry.layer_subdetector == 2)[0])
    last_ut = first_sf - 1
    hit_key = np.where(m["particle_id"] > 0, h["event_id"] * KEY_SCALE + m["particle_id"], 0)
    at_t1 = h["layer"] == first_sf
    t1_key, t1_row = np.unique(hit_key[at_t1], return_index=True)
    t1_x = m["x"][np.flatnonzero(at_t1)[t1_row]]
    errors = {True: [], False: []}
    for t in np.flatnonzero(pion & (mom > 2000) & (mom < 2500))[:60]:
        k = np.searchsorted(t1_key, velo["key"][t])
        if k >= t1_key.size or t1_key[k] != velo["key"][t]:
            continue
        state = np.array([*velo["state"][t], p["charge"][idx[t]] / mom[t]])
        a = int(np.argmin(np.abs(geometry.layer_z - velo["z"][t])))
        _, s_ut, _, _ = _chain(ext, state, geometry.layer_z[a], geometry.layer_z[last_ut])
        localize_ut_to_scifi(ext.uts_meta, ext.uts_cells, s_ut[0], s_ut[1], poly, ref)
        for quad in (True, False):
            o, j = np.zeros(5), np.zeros((5, 5))
            assert ut_to_scifi_extrapolate_localized(ext.uts_meta, poly, ref, eloss, s_ut, o, j, quad) == TRANSPORT_OK
            errors[quad].append(abs(o[0] - t1_x[k]))
    assert len(errors[True]) > 20
    assert errors[True] == errors[False]
    # median 11.2 mm on this sample, dominated by the VELO state and the scattering between
    # the VELO and the SciFi (≈ 4 mrad over ≈ 5 m at 2 GeV); the 3 GeV table's quadratic
    # continuation gave ≈ 15 mm and its linear one ≈ 30 mm on the same particles
    assert np.median(errors[True]) < 13.0, (np.median(errors[True]), np.percentile(errors[True], [25, 75]))
