"""Triplet fit (pkf.seeding.triplet_fit): geometry, exact helices, App. C cubic, zero field.

Truth is an exact helix in the homogeneous field of the `telescope` geometry (1 T along
y, planes every 100 mm); the hits come from `triplet_helpers` (analytic, checked here
against the package's RK4 transport).
"""

import math

import numpy as np
import pytest
from scipy import optimize

from pkf.geometry import load_geometry
from pkf.physics.transport import rk4_propagate
from pkf.seeding import triplet_fit as tf
from triplet_helpers import C_LIGHT, random_tracks, track_hits

TELESCOPE = load_geometry("telescope")
B = TELESCOPE.field.evaluate(0.0, 0.0, 500.0)[0]  # (0, 1, 0) T
PLANES = TELESCOPE.planes.z
X_OVER_X0 = 0.01
SIGMA = 0.01
HIT_VAR = (SIGMA**2, SIGMA**2, 0.0)
COL = {name: i for i, name in enumerate(tf.GEOMETRY_COLUMNS)}


def test_telescope_is_what_the_tests_assume():
    assert np.allclose(B, (0.0, 1.0, 0.0))
    assert np.allclose(PLANES, np.arange(100.0, 1001.0, 100.0))


def test_helix_generator_agrees_with_rk4_transport():
    """The analytic helices follow DESIGN §2's equations of motion (q/p sign included)."""
    rng = np.random.default_rng(1)
    p, q, pos, d = random_tracks(rng, 6, p_range=(500.0, 5000.0))
    hits, dirs = track_hits(p, q, pos, d, B, PLANES[:3])
    args = TELESCOPE.field.args
    for i in range(6):
        state = np.array([pos[i, 0], pos[i, 1], d[i, 0] / d[i, 2], d[i, 1] / d[i, 2], q[i] / p[i]])
        state = rk4_propagate(state, 0.0, PLANES[0], 1.0, *args)
        for k in (1, 2):
            state = rk4_propagate(state, PLANES[k - 1], PLANES[k], 1.0, *args)
            assert state[0] == pytest.approx(hits[i, k, 0], abs=1e-9)
            assert state[1] == pytest.approx(hits[i, k, 1], abs=1e-9)
            assert state[2] == pytest.approx(dirs[i, k, 0] / dirs[i, k, 2], abs=1e-12)


# --- geometry -------------------------------------------------------------------------


def test_geometry_matches_the_design_formulas():
    """d_i, R_C (Heron form), Φ_iC = 2 asin(d/2R_C), R3D_iC, θ_iC, α_i, Φ̃, η, Θ̃, β, ϑ."""
    rng = np.random.default_rng(2)
    p, q, pos, d = random_tracks(rng, 20, p_range=(300.0, 3000.0), slope=0.4)
    hits, _ = track_hits(p, q, pos, d, B, (100.0, 250.0, 300.0))
    geo = tf.triplet_geometry(hits, B)
    for h, g in zip(hits, geo):
        # fit frame: z' = ŷ (field), transverse plane = (x, z)
        t = h[:, [0, 2]]
        zl = h[:, 1]
        d01, d12, d02 = (np.linalg.norm(t[1] - t[0]), np.linalg.norm(t[2] - t[1]),
                         np.linalg.norm(t[2] - t[0]))
        z = (zl[1] - zl[0], zl[2] - zl[1])
        heron = math.sqrt(2 * d01**2 * d12**2 + 2 * d12**2 * d02**2 + 2 * d02**2 * d01**2
                          - d01**4 - d12**4 - d02**4)
        rc = d01 * d12 * d02 / heron
        phi = [2 * math.asin(di / (2 * rc)) for di in (d01, d12)]
        r3d = [math.sqrt(rc**2 + zi**2 / ph**2) for zi, ph in zip(z, phi)]
        theta = [math.acos(zi / (ph * r)) for zi, ph, r in zip(z, phi, r3d)]
        alpha = [(rc**2 * ph**2 + zi**2) / (0.5 * rc**2 * ph**3 / math.tan(ph / 2) + zi**2)
                 for ph, zi in zip(phi, z)]
        phi_t = -0.5 * (phi[0] * alpha[0] + phi[1] * alpha[1])
        eta = 0.5 * (phi[0] * alpha[0] / r3d[0] + phi[1] * alpha[1] / r3d[1])
        theta_t = (theta[1] - theta[0] - (1 - alpha[1]) / math.tan(theta[1])
                   + (1 - alpha[0]) / math.tan(theta[0]))
        beta = ((1 - alpha[1]) / (r3d[1] * math.tan(theta[1]))
                - (1 - alpha[0]) / (r3d[0] * math.tan(theta[0])))
        expected = {
            "d01": d01, "d12": d12, "d02": d02, "z01": z[0], "z12": z[1], "r_c": rc,
            "phi1c": phi[0], "phi2c": phi[1], "r3d1c": r3d[0], "r3d2c": r3d[1],
            "theta1c": theta[0], "theta2c": theta[1], "alpha1": alpha[0],
            "alpha2": alpha[1], "phi_tilde": phi_t, "eta": eta, "vartheta": np.mean(theta),
        }
        for name, value in expected.items():
            assert g[COL[name]] == pytest.approx(value, rel=1e-9, abs=1e-12), name
        # Θ̃ and β involve 1 − α ~ Φ²/12: compare with a tolerance on that scale
        assert g[COL["theta_tilde"]] == pytest.approx(theta_t, abs=1e-9 * max(1, abs(theta_t)))
        assert g[COL["beta"]] == pytest.approx(beta, rel=1e-6, abs=1e-15)
        assert g[COL["status"]] == 0


def test_geometry_is_finite_for_collinear_hits_and_zero_field():
    h = np.array([[[0.0, 0.0, 100.0], [1.0, 2.0, 200.0], [2.0, 4.0, 300.0]]])
    for bvec in ((0.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 1e-9, 0.0)):
        g = tf.triplet_geometry(h, bvec, hit_var=HIT_VAR)[0]
        finite = np.delete(g, [COL["r_c"], COL["r3d1c"], COL["r3d2c"]])
        assert np.all(np.isfinite(finite))
        assert g[COL["r_c"]] == np.inf
        assert g[COL["phi1c"]] == 0.0 and g[COL["psi_phi"]] == 0.0
        assert g[COL["alpha1"]] == 1.0
        assert g[COL["tx_c"]] == pytest.approx(0.01) and g[COL["ty_c"]] == pytest.approx(0.02)


def test_hit_error_propagation_reduces_to_paper_eq7():
    """Straight track along z, B along y, σ_x only: σ²_φhit of eq. 7 with ω = 90°."""
    h = np.array([[[0.0, 0.0, 100.0], [0.0, 0.0, 200.0], [0.0, 0.0, 400.0]]])
    sx = np.array([0.01, 0.02, 0.03])
    hv = np.zeros((1, 3, 3))
    hv[0, :, 0] = sx**2
    g = tf.triplet_geometry(h, B, hit_var=hv)[0]
    d01, d12 = 100.0, 200.0
    v_phi = (sx[0]**2 / d01**2 + sx[2]**2 / d12**2 + (1 / d01 + 1 / d12)**2 * sx[1]**2)
    assert g[COL["vhit_phiphi"]] == pytest.approx(v_phi, rel=1e-12)
    assert g[COL["vhit_thetatheta"]] == pytest.approx(0.0, abs=1e-20)
    # σ_y (along B) enters the longitudinal kink: sin⁴ϑ σ_z²/Δr² terms with ϑ = 90°
    hv2 = np.zeros((1, 3, 3))
    hv2[0, :, 1] = sx**2
    g2 = tf.triplet_geometry(h, B, hit_var=hv2)[0]
    assert g2[COL["vhit_thetatheta"]] == pytest.approx(v_phi, rel=1e-12)
    assert g2[COL["vhit_phiphi"]] == pytest.approx(0.0, abs=1e-20)


# --- exact helices --------------------------------------------------------------------


def _exact_helix_triplets(bvec=B):
    rows = [(p, q, tx, ty)
            for p in (500.0, 1000.0, 2000.0, 5000.0, 10000.0, 50000.0, 100000.0)
            for q in (-1.0, 1.0)
            for tx, ty in ((0.0, 0.0), (0.2, -0.3), (-0.25, 0.15), (0.05, 0.4))]
    rows = np.array(rows)
    n = len(rows)
    d = np.stack([rows[:, 2], rows[:, 3], np.ones(n)], axis=1)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    pos = np.zeros((n, 3))
    pos[:, 0] = np.linspace(-30, 30, n)
    hits, dirs = track_hits(rows[:, 0], rows[:, 1], pos, d, bvec, PLANES[:3])
    return rows[:, 0], rows[:, 1], hits, dirs


@pytest.mark.parametrize("form", (tf.FORM_CURVATURE, tf.FORM_RADIUS))
@pytest.mark.parametrize("with_hit_errors", (False, True))
@pytest.mark.parametrize("bvec", ((0.0, 1.0, 0.0), (0.0, -1.0, 0.0), (0.48, -0.64, 0.6),
                                  (1.2, 0.0, -0.9)))
def test_exact_helix_gives_its_radius_and_zero_chi2(form, with_hit_errors, bvec):
    """Either polarity and oblique fields: the fit frame follows B̂ at the middle hit."""
    p, q, hits, dirs = _exact_helix_triplets(bvec)
    fit = tf.fit_triplets(hits, bvec, X_OVER_X0, HIT_VAR if with_hit_errors else None,
                          form=form)
    bmag = float(np.linalg.norm(bvec))
    r_helix = p / (C_LIGHT * bmag)  # R3D = p/(κ_c B), e.g. 3335.64 mm at 1 GeV in 1 T
    assert np.all(fit.status == 0)
    assert np.all(np.abs(fit.r3d / r_helix - 1.0) < 1e-6)
    assert np.all(np.sign(fit.kappa) == q)  # κ has the sign of the charge
    assert np.all(np.abs(fit.qop * p * q - 1.0) < 1e-6)
    assert np.all(fit.chi2 <= 1e-12)
    assert np.all(fit.ndf == 1)
    if bmag == 1.0:
        assert np.all(np.abs(fit.r3d[p == 1000.0] - 3335.64) < 0.01)
    # direction at the middle hit
    assert np.allclose(fit.tx, dirs[:, 1, 0] / dirs[:, 1, 2], atol=1e-9)
    assert np.allclose(fit.ty, dirs[:, 1, 1] / dirs[:, 1, 2], atol=1e-9)
    assert np.allclose(fit.kink_phi, 0.0, atol=1e-12)
    assert np.allclose(fit.kink_theta, 0.0, atol=1e-12)


def test_exact_helix_ms_only_paper_eq1():
    p, _, hits, _ = _exact_helix_triplets()
    geo = tf.triplet_geometry(hits, B)
    r3d, sigma_r3d, chi2, sigma_ms, ok = tf.triplet_fit_ms(geo, X_OVER_X0)
    assert ok.all()
    assert np.all(np.abs(r3d * C_LIGHT / p - 1.0) < 1e-6)
    assert np.all(chi2 <= 1e-12)
    # σ_MS is Highland at the fitted momentum (pion), path along the track
    assert np.all(sigma_ms > 0) and np.all(sigma_r3d > 0)
    # MS-dominated: relative resolution is momentum independent (a few per cent here)
    rel = sigma_r3d / r3d
    assert np.all((rel > 0.01) & (rel < 0.2))
    # the Belle II bias correction is 1 at χ² = 0 (δ = 0)
    r_bc = tf.triplet_fit_ms(geo, X_OVER_X0, bias_correction=True)[0]
    assert np.allclose(r_bc, r3d, rtol=1e-9)


def test_no_material_and_no_hit_errors():
    """Nothing to weight the kinks with: κ is still the exact helix curvature (it does not
    depend on σ_MS), but χ² is undefined and the fit is flagged invalid, not NaN."""
    p, q, hits, _ = _exact_helix_triplets()
    for form in (tf.FORM_CURVATURE, tf.FORM_RADIUS):
        fit = tf.fit_triplets(hits, B, 0.0, form=form)
        assert np.all(fit.status & tf.STATUS_NO_VARIANCE)
        assert not np.any(fit.valid)
        assert np.allclose(fit.kappa, q * C_LIGHT / p, rtol=1e-6)
        assert not np.any(np.isnan(fit.chi2)) and not np.any(np.isnan(fit.var_kappa))


def test_moving_one_hit_by_a_micron_gives_positive_chi2():
    p, q, hits, _ = _exact_helix_triplets()
    base = tf.fit_triplets(hits, B, X_OVER_X0)
    assert np.all(base.chi2 <= 1e-12)
    for k in range(3):
        moved = hits.copy()
        moved[:, k, 1] += 1e-3  # 1 µm along B: a longitudinal kink the curvature cannot absorb
        fit = tf.fit_triplets(moved, B, X_OVER_X0)
        assert np.all(fit.chi2 > 1e3 * 1e-12), k
        assert np.all(fit.chi2 > 1e3 * base.chi2 + 1e-9)
    # 1 µm in the bending plane changes the radius (the transverse kink goes into κ)
    moved = hits.copy()
    moved[:, 1, 0] += 1e-3
    fit = tf.fit_triplets(moved, B, X_OVER_X0)
    assert np.all(np.abs(fit.kappa - base.kappa) > 1e-4 * np.abs(base.kappa))


# --- App. C cubic ---------------------------------------------------------------------


def test_cardano_roots_match_numpy():
    rng = np.random.default_rng(4)
    for _ in range(300):
        roots = rng.normal(size=3) * 10 ** rng.uniform(-3, 3)
        if rng.random() < 0.3:  # one real root and a complex pair
            re, im = rng.normal(size=2)
            coef = np.poly([roots[0], complex(re, im), complex(re, -im)]).real
        else:
            coef = np.poly(roots)
        coef *= 10 ** rng.uniform(-5, 5)
        expected = np.sort(np.roots(coef)[np.abs(np.roots(coef).imag) < 1e-9].real)
        n, r0, r1, r2 = tf.solve_cubic(*coef, float(np.max(np.abs(expected))))
        got = np.sort(np.array((r0, r1, r2))[:n])
        assert n == len(expected)
        assert np.allclose(got, expected, rtol=1e-8, atol=1e-10 * np.max(np.abs(expected)))
    # degenerate leading coefficients: quadratic and linear
    n, r0, r1, _ = tf.solve_cubic(0.0, 1.0, -3.0, 2.0, 1.0)
    assert n == 2 and sorted((r0, r1)) == pytest.approx([1.0, 2.0])
    n, r0, _, _ = tf.solve_cubic(0.0, 0.0, 2.0, -3.0, 1.0)
    assert n == 1 and r0 == pytest.approx(1.5)


def test_cubic_coefficients_are_those_of_appendix_c():
    eta, beta, phit, thet, s2, vp, vt, b = 2e-7, 3e-9, -1e-3, 2e-4, 0.8, 4e-8, 3e-8, 5.0
    a = tf._radius_cubic_coefficients(eta, beta, phit, thet, s2, vp, 0.0, vt, b)
    paper = (eta**2 * vt + beta**2 * vp, eta * phit * vt + beta * thet * vp,
             b**2 * (eta**2 + beta**2 / s2), b**2 * (eta * phit + beta * thet / s2))
    assert np.allclose(a, paper, rtol=1e-14, atol=0)


# (field, σx, σy): isotropic errors ⟂ the track give uncorrelated Φ/Θ hit errors; σx ≠ σy
# with the field at 45° in x–y gives ~90% correlation.
ERROR_SETUPS = {
    "isotropic": (B, SIGMA, SIGMA),
    "correlated": (np.array([1.0, 1.0, 0.0]) / math.sqrt(2.0), 0.01, 0.05),
}


def _triplets_with_hit_errors(n, seed, setup, p_range=(500.0, 20000.0)):
    bvec, sx, sy = ERROR_SETUPS[setup]
    rng = np.random.default_rng(seed)
    p, q, pos, d = random_tracks(rng, n, p_range=p_range)
    hits, _ = track_hits(p, q, pos, d, bvec, PLANES[:3], rng=rng, scatter_at=(1,))
    hits[:, :, 0] += rng.normal(size=(n, 3)) * sx
    hits[:, :, 1] += rng.normal(size=(n, 3)) * sy
    return hits, bvec, (sx * sx, sy * sy, 0.0)


@pytest.mark.parametrize("setup", sorted(ERROR_SETUPS))
def test_cubic_root_is_the_numerical_minimum_radius_form(setup):
    """App. C root = argmin of the effective χ²(R3D) with σ_MS = b/R3D held at the
    solution, found by scipy; and the self-consistent iteration of that numerical
    minimisation converges to the same R3D."""
    hits, bvec, hit_var = _triplets_with_hit_errors(60, 5, setup)
    geo = tf.triplet_geometry(hits, bvec, hit_var=hit_var)
    r3d, _, chi2, b, sigma_ms, status = tf.triplet_fit_hit_errors(geo, X_OVER_X0)
    assert np.all(status == 0)
    assert np.allclose(sigma_ms, b / r3d)
    for i, g in enumerate(geo):
        s2 = math.sin(g[COL["vartheta"]]) ** 2
        psi = g[[COL["phi_tilde"], COL["theta_tilde"]]]
        rho = g[[COL["eta"], COL["beta"]]]
        # Φ̃ + ηR counts turning along the bending direction: covariance × turn
        cov = g[COL["turn"]] * g[COL["vhit_phitheta"]]
        vhit = np.array([[g[COL["vhit_phiphi"]], cov], [cov, g[COL["vhit_thetatheta"]]]])

        def weight(r, i=i, s2=s2, vhit=vhit):
            sms = b[i] / r
            return np.linalg.inv(np.diag([sms**2 / s2, sms**2]) + vhit)

        def chi2_of(r, k, psi=psi, rho=rho):
            res = psi + rho * r
            return res @ k @ res

        k_star = weight(r3d[i])
        best = optimize.minimize_scalar(lambda x: chi2_of(x * r3d[i], k_star),
                                        bracket=(0.5, 1.0, 2.0), tol=1e-12).x * r3d[i]
        assert best == pytest.approx(r3d[i], rel=1e-6)
        assert chi2_of(r3d[i], k_star) == pytest.approx(chi2[i], rel=1e-9, abs=1e-12)
        r = 1.5 * r3d[i]
        for _ in range(200):
            k = weight(r)
            new = optimize.minimize_scalar(lambda x, r=r, k=k: chi2_of(x * r, k),
                                           bracket=(0.9, 1.1), tol=1e-12).x * r
            if abs(new - r) < 1e-11 * r:
                break
            r = new
        assert r == pytest.approx(r3d[i], rel=1e-6)


@pytest.mark.parametrize("setup", sorted(ERROR_SETUPS))
def test_cubic_root_is_the_numerical_minimum_curvature_form(setup):
    hits, bvec, hit_var = _triplets_with_hit_errors(60, 6, setup, p_range=(500.0, 100000.0))
    fit = tf.fit_triplets(hits, bvec, X_OVER_X0, hit_var, form=tf.FORM_CURVATURE)
    assert np.all(fit.status == 0)
    geo = fit.geometry
    for i, g in enumerate(geo):
        s2 = math.sin(g[COL["vartheta"]]) ** 2
        psi = g[[COL["psi_phi"], COL["psi_theta"]]]
        rho = g[[COL["rho_phi"], COL["rho_theta"]]]
        vhit = np.array([[g[COL["vhit_phiphi"]], g[COL["vhit_phitheta"]]],
                         [g[COL["vhit_phitheta"]], g[COL["vhit_thetatheta"]]]])
        sms = fit.sigma_ms[i]
        k = np.linalg.inv(np.diag([sms**2 / s2, sms**2]) + vhit)
        scale = abs(fit.kappa[i])

        def chi2_of(x, k=k, psi=psi, rho=rho, scale=scale):
            res = psi + rho * x * scale
            return res @ k @ res

        best = optimize.minimize_scalar(chi2_of, bracket=(-1.0, 1.0), tol=1e-12).x * scale
        assert best == pytest.approx(fit.kappa[i], rel=1e-6)
        assert chi2_of(fit.kappa[i] / scale) == pytest.approx(fit.chi2[i], rel=1e-9, abs=1e-12)
        assert fit.var_kappa[i] == pytest.approx(1.0 / (rho @ k @ rho), rel=1e-9)


# --- zero and weak field --------------------------------------------------------------


@pytest.mark.parametrize("bvec", ((0.0, 0.0, 0.0), (0.0, 1e-9, 0.0), (0.0, -0.004, 0.0),
                                  (0.01, 0.0, 0.02)))
def test_collinear_hits_in_weak_or_zero_field_are_finite(bvec):
    h = np.array([
        [[0.0, 0.0, 100.0], [1.0, 2.0, 200.0], [2.0, 4.0, 300.0]],  # exactly collinear
        [[5.0, -3.0, 100.0], [5.0, -3.0, 200.0], [5.0, -3.0, 400.0]],  # along z
        # a 7 mrad kink in a diagonal plane: with κ free only its projection onto the
        # bending plane (which the axis choice defines when B ≈ 0) is absorbed
        [[0.0, 0.0, 100.0], [0.0, 0.0, 200.0], [0.5, 0.5, 300.0]],
    ])
    for straight in (False, True):
        for hv in (None, HIT_VAR):
            fit = tf.fit_triplets(h, bvec, X_OVER_X0, hv, straight_below_threshold=straight)
            for name in ("kappa", "var_kappa", "qop", "var_qop", "chi2", "tx", "ty",
                         "kink_phi", "kink_theta", "var_kink_phi", "var_kink_theta"):
                assert np.all(np.isfinite(getattr(fit, name))), name
            assert np.all(fit.status & tf.STATUS_WEAK_FIELD)
            assert np.all(fit.valid)
            assert fit.chi2[0] == pytest.approx(0.0, abs=1e-20)
            assert fit.chi2[1] == pytest.approx(0.0, abs=1e-20)
            assert fit.kappa[0] == 0.0 and fit.kappa[1] == 0.0
            assert fit.chi2[2] > 10.0
            assert np.all(fit.qop == 0.0)
            assert np.all(fit.ndf == (2 if straight else 1))
            assert fit.tx[0] == pytest.approx(0.01) and fit.ty[0] == pytest.approx(0.02)


def test_collinear_hits_in_a_strong_field_are_finite():
    """Infinite momentum in 1 T: R3D undefined, the curvature form gives κ = 0."""
    h = np.array([[[0.0, 0.0, 100.0], [1.0, 2.0, 200.0], [2.0, 4.0, 300.0]]])
    for form in (tf.FORM_CURVATURE, tf.FORM_RADIUS):
        for hv in (None, HIT_VAR):
            fit = tf.fit_triplets(h, B, X_OVER_X0, hv, form=form)
            assert fit.valid[0]
            assert fit.kappa[0] == pytest.approx(0.0, abs=1e-15)
            assert fit.chi2[0] == pytest.approx(0.0, abs=1e-12)
            assert np.isfinite(fit.var_kappa[0]) and fit.var_kappa[0] > 0
    fit = tf.fit_triplets(h, B, X_OVER_X0, form=tf.FORM_RADIUS)
    assert fit.status[0] & tf.STATUS_CURVATURE_FALLBACK
    geo = tf.triplet_geometry(h, B)
    assert not tf.triplet_fit_ms(geo, X_OVER_X0)[4][0]


def test_degenerate_triplets_are_flagged():
    h = np.array([
        [[0.0, 0.0, 100.0], [0.0, 0.0, 100.0], [1.0, 0.0, 300.0]],  # coincident hits
        [[0.0, 0.0, 100.0], [0.0, 100.0, 100.0], [0.0, 200.0, 100.0]],  # along B
    ])
    fit = tf.fit_triplets(h, B, X_OVER_X0)
    assert np.all(fit.status & tf.STATUS_DEGENERATE)
    assert not np.any(fit.valid)
    assert np.all(fit.chi2 == np.inf)
    assert not np.any(np.isnan(fit.chi2))


def test_weak_field_uses_p_min_and_field_threshold():
    """Below the threshold σ_MS is Highland at p_min; above it, at the fitted momentum."""
    rng = np.random.default_rng(7)
    p, q, pos, d = random_tracks(rng, 50, p_range=(2000.0, 2000.0))
    hits, _ = track_hits(p, q, pos, d, np.zeros(3), PLANES[:3])
    weak = tf.fit_triplets(hits, (0.0, 0.03, 0.0), X_OVER_X0, p_min=1500.0)
    assert np.all(weak.status & tf.STATUS_WEAK_FIELD)
    n_path = np.sqrt(1 + weak.geometry[:, COL["tx_c"]] ** 2 + weak.geometry[:, COL["ty_c"]] ** 2)
    expected = [tf.highland_sigma(1500.0, tf.MASS_PION, X_OVER_X0 * n) for n in n_path]
    assert np.allclose(weak.sigma_ms, expected, rtol=1e-12)
    strong = tf.fit_triplets(hits, (0.0, 0.03, 0.0), X_OVER_X0, b_threshold=0.02)
    assert not np.any(strong.status & tf.STATUS_WEAK_FIELD)
    assert np.all(strong.var_qop < np.inf)


def test_argument_checking():
    with pytest.raises(ValueError, match="hits"):
        tf.fit_triplets(np.zeros((4, 3)), B, X_OVER_X0)
    with pytest.raises(ValueError, match="bfield"):
        tf.fit_triplets(np.zeros((4, 3, 3)), np.zeros((3, 3)), X_OVER_X0)
    with pytest.raises(ValueError, match="form"):
        tf.fit_triplets(np.zeros((1, 3, 3)), B, X_OVER_X0, form=7)
    with pytest.raises(ValueError, match="offsets"):
        tf.combine_triplet_chain([0, 3], [1.0, 2.0], [1.0, 1.0], [0.0, 0.0])
    empty = tf.fit_triplets(np.zeros((0, 3, 3)), B, X_OVER_X0)
    assert empty.kappa.shape == (0,)
