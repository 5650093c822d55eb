"""The global χ² fitter on the lhcb-like detector (issue 7)."""


import numpy as np
import pytest
from fit_helpers import TruthSample, recorded_track

from pkf.fit.options import GX2FOptions
from pkf.fit.seed import TRACK_VELO
from pkf.fit.gx2f import MAX_PREDICTED_DECREASE, MAX_UPDATES, _propagate, _solve, fit_batch_gx2f
from pkf.fit.reference import reference_extrapolator
from pkf.physics.linalg import search_sorted
from pkf.fit.status import STATUS_NOT_CONVERGED
from pkf.fit.tracks import FitOptions, fit_batch
from pkf.geometry import load_geometry
from pkf.params.gauss import gaussian_core


@pytest.fixture(scope="module")
def pions():
    return TruthSample(load_geometry("lhcb-like"), events=250, seed=37, particles=10,
                       p_min=2000.0, p_max=100000.0, eta_min=2.0, eta_max=5.0)


@pytest.fixture(scope="module")
def fits(pions):
    gx2f = fit_batch_gx2f(pions.extrapolator, pions.batch, FitOptions(), pions.seeds, pions.seed_covs,
                          pions.beamline)
    # the reference Kalman fit iterated once (linearised around its own first optimal
    # states), i.e. at the minimum of the same χ²; see test_single_pass_kalman below
    kalman = pions.fit(iterations=2)
    return gx2f, kalman


def test_first_hit_state_equals_the_reference_kalman(pions, fits):
    gx2f, kalman = fits
    long = pions.long_tracks()
    assert long.sum() > 1500
    same = long & (gx2f.status == 0) & (kalman.status == 0)
    # same outliers removed (the comparison is of the same χ² minimum)
    track = np.repeat(np.arange(pions.batch.n_tracks), pions.batch.n_nodes)
    differs = np.bincount(track, weights=gx2f.node_active != kalman.node_active, minlength=same.size) > 0
    assert np.mean(differs[long]) < 0.01
    same &= ~differs
    _, sg, _ = gx2f.locations["first_hit"]
    _, sk, ck = kalman.locations["first_hit"]
    sigma = np.sqrt(np.einsum("nii->ni", ck[same]))
    rms = np.sqrt(np.mean(((sg[same] - sk[same]) / sigma) ** 2, axis=0))
    assert np.all(rms < 0.1), rms
    # and the covariance, χ² and ndf agree
    _, _, cg = gx2f.locations["first_hit"]
    ratio = np.sqrt(np.einsum("nii->ni", cg[same])) / sigma
    assert np.all(np.abs(np.median(ratio, axis=0) - 1.0) < 0.01)
    np.testing.assert_array_equal(gx2f.ndf[same], kalman.ndf[same])
    assert np.median(np.abs(gx2f.chi2[same] - kalman.chi2[same])) < 0.01


def test_pulls_and_convergence(pions, fits):
    gx2f, _ = fits
    long = pions.long_tracks()
    assert np.mean(gx2f.status[long] == 0) > 0.999
    pulls, _, _ = pions.first_hit_pulls(gx2f, long)
    for i, name in enumerate(("x", "y", "tx", "ty", "qop")):
        core = gaussian_core(pulls[:, i])
        assert 0.95 <= core.sigma <= 1.10, (name, core)
        assert abs(core.mean) < 0.1, (name, core)
    ok = long & (gx2f.status == 0)
    assert np.mean(gx2f.converged[ok]) >= 0.99
    # a converged fit is at its minimum: its next step predicts no χ² decrease
    assert np.all(gx2f.decrease[ok & gx2f.converged] < 1e-6)
    assert gx2f.iterations[ok].max() <= MAX_UPDATES
    assert 0.9 <= np.mean(gx2f.chi2[ok] / gx2f.ndf[ok]) <= 1.15
    # the beamline state exists for every good track
    assert np.all(np.isfinite(gx2f.locations["beamline"][1][ok]))


def _trajectory(ext, batch, t, alpha, theta):
    lo, hi = batch.offsets[t], batch.offsets[t + 1]
    n = hi - lo
    slots = ext.plane_z.size + 1
    arrays = {"node_state": np.zeros((n, 5)), "jac": np.zeros((n, 5, 5)), "g": np.zeros((slots, 5, 2)),
              "theta0": np.zeros(slots), "step_plane": np.zeros(n + 1, dtype=np.int64)}
    plane_lo = search_sorted(ext.plane_z, batch.z[lo], True)
    status = _propagate(ext, alpha, theta, batch.z[lo:hi], n, plane_lo, arrays["node_state"], arrays["jac"],
                        arrays["g"], arrays["theta0"], arrays["step_plane"], np.zeros((5, 5)), np.zeros((5, 5)),
                        np.zeros(2, dtype=np.int64), np.zeros((4, 5, 5)), np.zeros(slots, dtype=np.bool_))
    assert status == 0
    return lo, hi, n, arrays


def test_linear_time_solve_equals_the_dense_normal_equations(pions):
    """The backward elimination of the angles + forward substitution gives the same
    Gauss–Newton step, marginal covariance at the first node, node covariances and
    predicted χ² decrease bᵀA⁻¹b as solving the dense normal equations A·δ = b over
    (α, θ_1 … θ_M)."""
    ext, batch = pions.extrapolator, pions.batch
    t = int(np.flatnonzero(pions.long_tracks())[3])
    alpha = pions.seeds[t].copy()
    slots = ext.plane_z.size + 1
    lo, hi, n, a = _trajectory(ext, batch, t, alpha, np.zeros((slots, 2)))
    rng = np.random.default_rng(5)
    theta = a["theta0"][:, None] * rng.normal(size=(slots, 2))  # non-zero current angles
    lo, hi, n, a = _trajectory(ext, batch, t, alpha, theta)
    n_slots = int(a["step_plane"][n])
    used = np.flatnonzero(a["theta0"][:n_slots] > 0)
    assert used.size > 10
    # dense Jacobian D_k = ∂s_k/∂(α, θ_used) by the chain rule of the step pieces
    n_par = 5 + 2 * used.size
    col = {p: 5 + 2 * i for i, p in enumerate(used)}
    d = np.zeros((n, 5, n_par))
    d[0, :, :5] = np.eye(5)
    for k in range(1, n):
        d[k] = a["jac"][k] @ d[k - 1]
        for p in range(a["step_plane"][k], a["step_plane"][k + 1]):
            if p in col:
                d[k][:, col[p]:col[p] + 2] += a["g"][p]
    rows, rhs = [], []
    for k in range(n):
        for j in range(batch.n_meas[lo + k]):
            h = np.array([batch.hx[lo + k, j], batch.hy[lo + k, j], 0, 0, 0])
            s = batch.sigma[lo + k, j]
            rows.append(h @ d[k] / s)
            rhs.append((batch.m[lo + k, j] - h @ a["node_state"][k]) / s)
    jac = np.array(rows)
    lam = np.zeros(n_par)
    prior = np.zeros(n_par)
    for p, c in col.items():
        lam[c:c + 2] = 1.0 / a["theta0"][p] ** 2
        prior[c:c + 2] = theta[p] / a["theta0"][p] ** 2
    normal = jac.T @ jac + np.diag(lam)
    gradient = jac.T @ np.array(rhs) - prior
    step = np.linalg.solve(normal, gradient)
    cov = np.linalg.inv(normal)
    # the linear-time solver
    d_alpha = np.zeros(5)
    d_theta = np.zeros((slots, 2))
    node_cov = np.zeros((n, 5, 5))
    decrease = _solve(n, batch.n_meas[lo:hi], batch.hx[lo:hi], batch.hy[lo:hi], batch.m[lo:hi], batch.sigma[lo:hi],
                np.ones(n, dtype=np.bool_), a["node_state"], a["jac"], a["g"], theta, a["theta0"],
                a["step_plane"], np.zeros((slots, 2, 5)), np.zeros((slots, 2)), np.zeros((slots, 2, 2)), d_alpha,
                d_theta, node_cov, *(np.zeros((5, 5)) for _ in range(1)), np.zeros(5), np.zeros((5, 2)),
                *(np.zeros((5, 5)) for _ in range(4)), np.zeros(10))
    np.testing.assert_allclose(decrease, step @ gradient, rtol=1e-6)
    assert decrease > 0.0
    scale = np.sqrt(np.diag(cov))
    np.testing.assert_allclose(d_alpha / scale[:5], step[:5] / scale[:5], atol=1e-6)
    dense_theta = np.array([step[col[p]:col[p] + 2] for p in used])
    np.testing.assert_allclose(d_theta[used], dense_theta, atol=1e-6 * a["theta0"][used].max())
    np.testing.assert_allclose(node_cov[0], cov[:5, :5], rtol=1e-6, atol=0)
    k = n - 1  # the last node's posterior covariance: D_k·Cov·D_kᵀ
    np.testing.assert_allclose(node_cov[k], d[k] @ cov @ d[k].T, rtol=1e-5,
                               atol=1e-9 * np.sqrt(np.outer(np.diag(node_cov[k]), np.diag(node_cov[k]))).max())


def test_single_pass_kalman_is_not_at_the_minimum_for_low_momenta(pions, fits):
    """For information (issue 7 note): the one-pass Kalman fit (linearised at its forward
    filtered states) differs from the χ² minimum in q/p by up to several σ for 2–3 GeV
    tracks whose seed q/p is 5–15% off; the GX2F and the iterated Kalman fit agree."""
    gx2f, _ = fits
    kalman1 = pions.fit(iterations=1)
    long = pions.long_tracks() & (gx2f.status == 0) & (kalman1.status == 0)
    _, sg, _ = gx2f.locations["first_hit"]
    _, sk, ck = kalman1.locations["first_hit"]
    q = np.abs(sg[long, 4] - sk[long, 4]) / np.sqrt(ck[long, 4, 4])
    assert np.median(q) < 0.02


def test_velo_only_tracks_converge_at_the_momentum_assumption():
    """VELO-only tracks (q/p prior only): Highland widths at the momentum assumption, so
    Gauss–Newton converges and its result does not depend on the number of updates. With
    widths at the free q/p it alternated between two trajectories (|q/p| ×10 and back):
    22 % converged within 5 updates on the real VELO-only tracks of 15 minbias events."""
    low = TruthSample(load_geometry("lhcb-like"), events=60, seed=5, particles=10,
                      p_min=200.0, p_max=1000.0, eta_min=1.6, eta_max=3.0)
    velo = (low.batch.track_type == TRACK_VELO) & (low.batch.n_nodes >= 4)
    assert velo.sum() >= 30, velo.sum()
    results = {}
    for updates in (4, 5, 30):
        options = FitOptions(gx2f=GX2FOptions(max_updates=updates))
        results[updates] = fit_batch_gx2f(low.extrapolator, low.batch, options, low.seeds, low.seed_covs,
                                          low.beamline)
    fit = results[5]
    ok = velo & (fit.status == 0)
    assert ok.sum() >= 0.95 * velo.sum()
    assert np.mean(fit.converged[ok]) > 0.95, np.mean(fit.converged[ok])
    chi2_4, chi2_30 = results[4].chi2[ok], results[30].chi2[ok]
    assert np.quantile(np.abs(fit.chi2[ok] - chi2_4) / fit.chi2[ok], 0.99) < 1e-3
    assert np.quantile(np.abs(fit.chi2[ok] - chi2_30) / fit.chi2[ok], 0.99) < 1e-3
    # q/p stays the prior's (the hits do not measure it)
    first = low.batch.offsets[:-1][ok]
    assert np.median(np.abs(fit.node_state[first, 4] / low.seeds[ok, 4] - 1.0)) < 0.2


def test_the_material_of_a_fit_is_that_of_its_first_trajectory():
    """A VELO-only track at the edge of the VELO's inner hole (Pythia pp, ν = 7.6, seed 31,
    event 58: r ≈ 5.2–5.5 mm against the 5.1 mm hole, two wrong first hits, 77 % matched).
    Its Gauss–Newton iterates crossed in and out of the modules' active area, so planes —
    and the angles fitted at them — came and went between updates: 7,407 after 5 updates
    (46,000 after the outlier removal; 2,902 after 50, not converged) where the
    parametrized Kalman fit has 22.8. With the crossings of each fit's first trajectory
    kept for its updates, it converges in 4 updates to χ² 22.45 / 21, whatever the
    update limit. On 60 minbias events (ν = 7.6) this changed 271 of 16,546 fits, e.g.
    χ² 1,857 → 162, 261 → 38 (a real long track); on 60 Pythia events 152 of 11,468,
    real VELO-only χ²/ndf mean 1.82 → 1.00 and one 'extrapolation failed' now fitted."""
    geometry, batch, data = recorded_track("gx2f_velo_track_at_the_hole_edge")
    assert batch.track_type[0] == TRACK_VELO
    ext = reference_extrapolator(geometry)
    chi2 = {}
    for updates in (5, 50):
        fit = fit_batch_gx2f(ext, batch, FitOptions(gx2f=GX2FOptions(max_updates=updates)), data["seed"][None],
                             data["seed_cov"][None])
        assert fit.status[0] == 0 and fit.converged[0], (fit.status, fit.iterations)
        chi2[updates] = fit.chi2[0] / fit.ndf[0]
    assert chi2[5] < 1.5, chi2
    assert chi2[50] == chi2[5]


def test_a_fit_far_from_its_minimum_after_its_updates_fails():
    """An upstream track of minimum bias (ν = 7.6, seed 31, truth pattern) whose q/p only
    the VELO–UT kick measures: after 5 updates its next Gauss–Newton step still predicts
    a χ² decrease of ~1,000 (and ~370 after 50), so it is "did not converge" with NaN
    states rather than a 5th-update state reported as fitted."""
    geometry, batch, data = recorded_track("gx2f_does_not_converge")
    ext = reference_extrapolator(geometry)
    for updates in (5, 50):
        fit = fit_batch_gx2f(ext, batch, FitOptions(gx2f=GX2FOptions(max_updates=updates)), data["seed"][None],
                             data["seed_cov"][None])
        assert fit.status[0] == STATUS_NOT_CONVERGED and not fit.converged[0]
        assert fit.decrease[0] > 100 * MAX_PREDICTED_DECREASE, fit.decrease
        assert np.all(np.isnan(fit.node_state)) and np.isnan(fit.chi2[0])
        assert fit.status_names()[0] == "did not converge"


def test_the_line_search_judges_a_step_by_the_chi2_it_minimised():
    """An upstream track of the same sample that stalled (status "did not converge",
    predicted decrease 12 after 5 updates) while its line search compared χ² with the
    Highland widths of the new trajectory: judged with the widths the update was
    linearised on, it converges in 5 updates to the χ² minimum the iterated reference
    Kalman fit of the same hits finds (45.5 and 45.8 for 11 degrees of freedom)."""
    geometry, batch, data = recorded_track("gx2f_line_search_at_fixed_widths")
    ext = reference_extrapolator(geometry)
    seed, seed_cov = data["seed"][None], data["seed_cov"][None]
    fit = fit_batch_gx2f(ext, batch, FitOptions(), seed, seed_cov)
    kalman = fit_batch(ext, batch, FitOptions.from_flat(iterations=2), seed, seed_cov)
    assert fit.status[0] == 0 and fit.converged[0], (fit.status, fit.iterations)
    assert fit.decrease[0] < 1e-6
    assert fit.ndf[0] == kalman.ndf[0]
    assert abs(fit.chi2[0] - kalman.chi2[0]) < 1.0, (fit.chi2, kalman.chi2)
