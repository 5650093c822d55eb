"""The multiple-scattering momentum of VELO-only tracks (`pkf.fit.seed.velo_momentum_estimate`).

Straight tracks through 15 VELO-like planes (x/X0 = 0.01 every 25 mm, σ = 12.5 µm in x and y),
scattered with the Highland width the estimate assumes: the estimate recovers the momentum
(measured on 200 tracks each, slopes (0.1, 0.05), i.e. a prior centred at 2.25 GeV: median
p̂/p 1.01 / 1.01 / 0.92 / 0.68 at 0.3 / 1 / 3 / 10 GeV, 16–84 % of p̂ 274–359 MeV at 0.3 GeV;
at 10 GeV the scattering is below the hit resolution and the prior decides) and its posterior
σ(1/p) covers it; a track without scattering has no momentum scale (the likelihood's maximum at
the top of the scan, p̂ on the prior's high side).
"""

import math

import numpy as np
import pytest

from pkf.fit.seed import (
    VELO_P_MAX,
    VELO_PT_PRIOR,
    MaterialPlanes,
    _scan_filter,
    momentum_at_pt,
    velo_momentum_estimate,
    velo_scattering_nll,
)
from pkf.physics.constants import MASS_PION
from pkf.physics.materials import highland_theta0

Z = np.arange(-50.0, 300.0, 25.0)
SIGMA = 0.0125
TX, TY = 0.1, 0.05


def _track(rng, p):
    """Hits (m (n, 2)) of a pion of momentum p [MeV] [inf: no scattering] scattered at every plane."""
    n = Z.size
    n2 = 1.0 + TX * TX + TY * TY
    x, y, tx, ty = 1.0, 2.0, TX, TY
    m = np.empty((n, 2))
    for k in range(n):
        if k > 0:
            x += tx * (Z[k] - Z[k - 1])
            y += ty * (Z[k] - Z[k - 1])
        m[k] = (x, y)
        theta0 = 0.0 if math.isinf(p) else highland_theta0(p, MASS_PION, 1.0, 0.01 * math.sqrt(n2))
        tx += rng.normal() * theta0 * math.sqrt(n2 * (1.0 + TX * TX))
        ty += rng.normal() * theta0 * math.sqrt(n2 * (1.0 + TY * TY))
    return m + rng.normal(size=m.shape) * SIGMA


def _estimate(m):
    n = Z.size
    big = np.full(n, 1e9)
    zero = np.zeros(n)
    out = np.empty(3)
    ok = velo_momentum_estimate(
        Z,
        np.full(n, 2, dtype=np.int64),
        np.tile([1.0, 0.0], (n, 1)),
        np.tile([0.0, 1.0], (n, 1)),
        m,
        np.full((n, 2), SIGMA),
        1.0,
        2.0,
        TX,
        TY,
        MaterialPlanes(Z.copy(), np.full(n, 0.01), big, big, zero, zero, zero, np.zeros(n, dtype=np.int64), zero),
        out,
    )
    assert ok
    return out


@pytest.mark.parametrize("p, most", [(300.0, 1.25), (1000.0, 1.25), (3000.0, 1.6)])
def test_estimate_recovers_the_momentum(p, most):
    """p̂ = 1/⟨κ⟩ near p, its scattering variance ∝ 1/p̂² right on average, and the posterior
    σ(κ) the size of the error of 1/p̂. At 3 GeV the scattering is 1/5 of the hit error per
    kink: the likelihood is open towards high p and the posterior leans to its low-p side
    (measured ⟨p²/p̂²⟩ 0.96 / 1.00 / 1.22; pull RMS 1.14 / 1.16 / 0.97)."""
    rng = np.random.default_rng(7)
    est = np.array([_estimate(_track(rng, p)) for _ in range(100)])
    assert 0.75 < np.median(est[:, 0]) / p < 1.15, np.median(est[:, 0])
    assert 0.8 < np.mean(p**2 / est[:, 0] ** 2) < most
    pull = (1.0 / est[:, 0] - 1.0 / p) / est[:, 1]
    assert 0.5 < np.sqrt(np.mean(pull**2)) < 1.6, np.sqrt(np.mean(pull**2))


def test_no_scattering_gives_no_momentum_scale():
    """Without scattering only low momenta are excluded: the likelihood peaks at the top of the
    scan and p̂ lies on the high side of the prior (measured median 9.0 GeV, centre 2.25 GeV)."""
    rng = np.random.default_rng(8)
    est = np.array([_estimate(_track(rng, math.inf)) for _ in range(30)])
    assert np.median(est[:, 2]) > 0.5 * VELO_P_MAX  # the likelihood's maximum: no scattering
    assert np.median(est[:, 0]) > 2.0 * momentum_at_pt(VELO_PT_PRIOR, TX, TY), np.median(est[:, 0])


def test_seed_batch_changes_only_velo_only_seeds():
    """With the geometry, `seed_batch` gives VELO-only tracks the scattering momentum (whose
    logarithm follows the true one's) and leaves every other track's seed bitwise as it was."""
    from pkf.fit.seed import TRACK_VELO
    from pkf.fit.tracks import TrackBatch, seed_batch
    from pkf.geometry import load_geometry
    from pkf.pipeline.simulate import SimulationConfig, simulate_batch
    from pkf.pipeline.truth_pattern import truth_candidates

    geometry = load_geometry("lhcb-like")
    config = SimulationConfig(generator="minbias", pileup=7.6, events=25, seed=5)
    hits, _, mc = simulate_batch(geometry, config, 0, config.events)
    col = lambda t, c: t.column(c).to_numpy(zero_copy_only=False)  # noqa: E731
    layer = col(hits, "layer").astype(np.int64)
    candidates = truth_candidates(
        col(hits, "event_id").astype(np.int64), layer, col(mc, "particle_id").astype(np.int64)
    )
    batch = TrackBatch.from_candidates(
        geometry, candidates, layer, *(col(hits, c).astype(float) for c in ("u", "v", "sigma_u", "sigma_v"))
    )
    field = geometry.reconstruction_field()
    old, old_covs, _ = seed_batch(batch, field)
    new, new_covs, _ = seed_batch(batch, field, geometry)
    velo = batch.track_type == TRACK_VELO
    assert velo.sum() > 40 and (~velo).sum() > 40, velo.sum()
    np.testing.assert_array_equal(new[~velo], old[~velo])
    np.testing.assert_array_equal(new_covs[~velo], old_covs[~velo])
    true_qop = col(mc, "qop")[batch.hit_row[batch.offsets[:-1]]]
    sel = velo & (batch.n_nodes >= 4) & np.isfinite(true_qop)
    corr = np.corrcoef(np.log(np.abs(new[sel, 4])), np.log(np.abs(true_qop[sel])))[0, 1]
    assert corr > 0.7, corr
    # wide-angle tracks (0.3–5 GeV here): the scattering measures p, the fixed pT does not
    # (measured: spread of ln(p_seed/p) 0.50 against 0.87, 86 tracks). The forward ones (slope ≈ 0.012,
    # 35–80 GeV, 4–7 hits) scatter below the hit resolution: their p̂ = 1/√⟨1/p²⟩ is the
    # lowest momentum the hits allow, 2.6–17 GeV (the assumption: 15–18 GeV)
    wide = sel & (np.hypot(new[:, 2], new[:, 3]) > 0.1)
    spread_new = np.std(np.log(np.abs(new[wide, 4] / true_qop[wide])))
    spread_old = np.std(np.log(np.abs(old[wide, 4] / true_qop[wide])))
    assert wide.sum() > 40 and spread_new < 0.7 * spread_old, (wide.sum(), spread_new, spread_old)
    forward = sel & (np.hypot(new[:, 2], new[:, 3]) < 0.03)
    assert np.all(1.0 / np.abs(new[forward, 4]) > 2000.0)


def _nll_one_momentum(theta0, z, meas, tx, ty, scat_z):
    """−2 ln L of one momentum, the filter written out per projection as in docs/physics.md
    (meas: per node a list of (projection, value, variance); theta0 per plane)."""
    n2 = 1.0 + tx * tx + ty * ty
    total = 0.0
    for proj, slope in ((0, tx), (1, ty)):
        hits = [(zk, m, v) for zk, node in zip(z, meas) for p, m, v in node if p == proj]
        if not hits:
            continue
        u, t, puu, put, ptt = hits[0][1], slope, hits[0][2], 0.0, 1.0
        zc = hits[0][0]
        planes = [(zp, th) for zp, th in zip(scat_z, theta0) if zp > zc]
        for i, (zk, m, v) in enumerate(hits[1:], start=1):
            while True:
                z_next, kick = zk, None
                if planes and planes[0][0] <= zk:
                    z_next, kick = planes.pop(0)
                d = z_next - zc
                u += t * d
                puu += 2.0 * d * put + d * d * ptt
                put += d * ptt
                zc = z_next
                if kick is None:
                    break
                ptt += kick * kick * n2 * (1.0 + slope * slope)
            r, s = m - u, puu + v
            if i >= 2:
                total += r * r / s + math.log(s)
            ku, kt = puu / s, put / s
            u, t = u + ku * r, t + kt * r
            ptt, put, puu = ptt - kt * put, put - ku * put, puu - ku * puu
    return total


def test_scan_filters_side_by_side_equal_one_momentum_at_a_time():
    """The likelihood scan runs the filters of all its momenta side by side (SIMD over the
    momenta); each equals the filter of that momentum alone: strip and pixel nodes, nodes
    without a projection, planes between hits and before the first one."""
    rng = np.random.default_rng(3)
    n = 9
    z = np.sort(rng.uniform(0.0, 300.0, n))
    hx = np.array([[1.0, 0.0]] * n)
    hy = np.array([[0.0, 1.0]] * n)
    n_meas = np.full(n, 2, dtype=np.int64)
    hx[3], hy[3], n_meas[3] = (0.0, 0.0), (1.0, 0.0), 1  # a y strip only
    hx[5], hy[5], n_meas[5] = (0.6, 0.0), (0.8, 0.0), 1  # a stereo strip: in neither projection
    m = rng.normal(0.0, 1.0, (n, 2))
    sigma = rng.uniform(0.01, 0.05, (n, 2))
    meas = [[(0 if (hx[k, j], hy[k, j]) == (1.0, 0.0) else 1, m[k, j], sigma[k, j] ** 2)
             for j in range(n_meas[k]) if (hx[k, j], hy[k, j]) in ((1.0, 0.0), (0.0, 1.0))] for k in range(n)]
    scat_z = np.sort(np.concatenate([[z[0] - 5.0], rng.uniform(z[0], z[-1], 6)]))
    momenta = np.exp(np.linspace(np.log(50.0), np.log(2e5), 13))
    theta0 = np.array([[highland_theta0(p, MASS_PION, 1.0, 0.01 * (1 + i)) for p in momenta]
                       for i in range(scat_z.size)])
    f = _scan_filter(momenta.size, n)
    velo_scattering_nll(theta0, z, n_meas, hx, hy, m, sigma, 0.1, -0.05, scat_z, scat_z.size, f)
    expected = [_nll_one_momentum(theta0[:, g], z, meas, 0.1, -0.05, scat_z) for g in range(momenta.size)]
    np.testing.assert_allclose(f.total, expected, rtol=1e-13, atol=0.0)
    assert np.ptp(f.total) > 10.0  # the momenta differ
