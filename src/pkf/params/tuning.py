"""Tuning of the parametrized extrapolations on simulation (paper §4, docs/parameters.md#how-the-coefficients-are-tuned).

Data set D: consecutive true states of each MC particle (mc_hits, with q/p replaced by
the production q/p that the parametrized state carries) plus the reference
extrapolation of the first state: RK4 through the field map with the particle's local
momentum, no material. Each pair that makes exactly one paper step feeds that step's
parameter slot (VELO pairs feed the one shared VELO set).

Step 1 (eq. 12): the extrapolation parameters, f_tx before f_x and f_ty before f_y,
maximising Π[G(f_s(x1) − x2_ref,s; σ) + c] per variable — here a Gaussian core of free
width σ plus a flat outlier density c = ε/range (ε = 1%). Every extrapolation formula
is linear in its parameters once the earlier ones are fixed: `robust_linear_fit` works
in an orthonormal basis of the design (the extended eq. 14 has up to 27 strongly
correlated monomials), reaches the maximum by EM iterations from the least-squares
start, and iminuit (analytic gradient) confirms it and gives the fit status.

Step 2 (eq. 13): the noise parameters (p̃0…p̃3 and the floor p̃4, eq. 11) maximising
Π[G2(f_d − x2_d, f_td − x2_td; Q) + c] over d ∈ {x, y} against the *true* second state.

The UT→SciFi step is tabulated from RK4 through the field map (`pkf.params.ut_to_scifi`);
only its noise is tuned here.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numba as nb
import numpy as np
from iminuit import Minuit

from pkf.params.formulas import (
    LAYER_TX_MONOMIALS,
    LAYER_TX_OFFSET,
    LAYER_TY_MONOMIALS,
    LAYER_TY_OFFSET,
    N_EXTRAPOLATION_PARAMS,
    N_NOISE_PARAMS,
    layer_step,
    velo_step,
    velo_to_ut_step,
)
from pkf.params.gauss import gaussian_core
from pkf.params.parameter_set import SlotStructure
from pkf.params.transport import (
    STEP_NONE,
    STEP_SCIFI,
    STEP_UT,
    STEP_UT_TO_SCIFI,
    STEP_VELO,
    STEP_VELO_TO_UT,
)
from pkf.params.ut_to_scifi import ut_to_scifi_extrapolate, ut_to_scifi_extrapolate_many
from pkf.physics.transport import rk4_propagate_scalar

OUTLIER_FRACTION = 0.01
MAX_PAIRS_PER_FIT = 200_000
REFERENCE_MAX_STEP = 50.0
#: mm: position residuals below this (nm-scale parametrization errors, irrelevant next to
#: 10 µm hits) must not drive the noise fit — without it the noise floor p̃4 grew to fit them
POSITION_RESOLUTION_FLOOR = 1e-3
#: 1/MeV: added to |q/p| in the per-pair scale of the extrapolation fits (1/(100 GeV))
SCALE_FLOOR_QOP = 1e-5
#: EM iterations before Minuit in `robust_linear_fit`, and their stopping rule (relative
#: change of −ln L): with 20–30 parameters, Minuit started from the plain least squares
#: (pulled by the outliers) needed ~2000 calls per fit
EM_MAX_ITERATIONS = 50
EM_TOLERANCE = 1e-9
#: lower limit of the noise fit's p̃1 (position noise = p̃1·Δz·σ_slope)
NOISE_MIN_POSITION_RATIO = 1e-4
#: a fit needs at least this many pairs per free parameter (extrapolation fits) …
MIN_PAIRS_PER_PARAMETER = 10
#: … and the noise fit (5 parameters, the 2-D likelihood of eq. 13) this many pairs
MIN_NOISE_PAIRS = 50
#: free parameters of the largest extrapolation fit of each step type (`fit_extrapolation`,
#: `fit_table_energy_loss`): the design columns of its f_tx (UT, SciFi) or f_x (VELO→UT) fit
EXTRAPOLATION_FIT_PARAMETERS = {
    STEP_VELO: 2,
    STEP_UT: 8 + len(LAYER_TX_MONOMIALS),
    STEP_SCIFI: 8 + len(LAYER_TX_MONOMIALS),
    STEP_VELO_TO_UT: 4,
    STEP_UT_TO_SCIFI: 1,
}


@dataclass
class StatePairs:
    """Consecutive true states of particles: layers (la, lb), states x1, x2 (n, 5) with
    production q/p, and x2_ref (n, 5): RK4 of x1 with its local q/p, no material."""

    layer_a: np.ndarray
    layer_b: np.ndarray
    x1: np.ndarray
    x2: np.ndarray
    x2_ref: np.ndarray


@nb.njit(cache=True)
def _reference_extrapolations(x1_local, z1, z2, max_step, kind, params, grid, out):
    for i in range(z1.size):
        x, y, tx, ty = rk4_propagate_scalar(x1_local[i, 0], x1_local[i, 1], x1_local[i, 2], x1_local[i, 3],
                                            x1_local[i, 4], z1[i], z2[i], max_step, kind, params, grid)
        out[i, 0] = x
        out[i, 1] = y
        out[i, 2] = tx
        out[i, 3] = ty
        out[i, 4] = x1_local[i, 4]


def build_pairs(event: np.ndarray, particle: np.ndarray, layer: np.ndarray, local_state: np.ndarray,
                production_qop: np.ndarray, layer_z: np.ndarray, field_map) -> StatePairs:
    """Pairs of consecutive hits of each particle (per hit arrays; particle > 0 only)."""
    order = np.lexsort((layer, particle, event))
    event, particle, layer = event[order], particle[order], layer[order]
    local_state, production_qop = local_state[order], production_qop[order]
    same = (event[1:] == event[:-1]) & (particle[1:] == particle[:-1]) & (layer[1:] > layer[:-1])
    a = np.flatnonzero(same)
    b = a + 1
    ok = np.all(np.isfinite(local_state[a]), axis=1) & np.all(np.isfinite(local_state[b]), axis=1)
    a, b = a[ok], b[ok]
    x1 = local_state[a].copy()
    x2 = local_state[b].copy()
    x2_ref = np.empty_like(x1)
    _reference_extrapolations(np.ascontiguousarray(local_state[a]), layer_z[layer[a]], layer_z[layer[b]],
                              REFERENCE_MAX_STEP, *field_map.args, x2_ref)
    x1[:, 4] = production_qop[a]
    x2[:, 4] = production_qop[b]
    x2_ref[:, 4] = production_qop[a]
    return StatePairs(layer[a], layer[b], x1, x2, x2_ref)


def pair_slot(slots: SlotStructure, layer_a: np.ndarray, layer_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each pair, the (kind, slot) of the single paper step it makes, or (STEP_NONE, −1)."""
    sub_a = slots.layer_sub[layer_a]
    sub_b = slots.layer_sub[layer_b]
    kind = np.full(layer_a.size, STEP_NONE, dtype=np.int64)
    slot = np.full(layer_a.size, -1, dtype=np.int64)
    within = slots.within_type[sub_a]
    same = sub_a == sub_b
    velo_like = same & (within == STEP_VELO)
    kind[velo_like], slot[velo_like] = STEP_VELO, layer_a[velo_like]
    per_layer = same & np.isin(within, (STEP_UT, STEP_SCIFI)) & (layer_b == layer_a + 1)
    kind[per_layer], slot[per_layer] = within[per_layer], layer_a[per_layer]
    leave = slots.between_type[sub_a]
    last = slots.sub_last[sub_a]
    crossing = ~same & (layer_b == last + 1)
    v2u = crossing & (leave == STEP_VELO_TO_UT)
    kind[v2u], slot[v2u] = STEP_VELO_TO_UT, last[v2u]
    u2s = crossing & (leave == STEP_UT_TO_SCIFI) & (layer_a == last)
    kind[u2s], slot[u2s] = STEP_UT_TO_SCIFI, last[u2s]
    gap = crossing & np.isin(leave, (STEP_UT, STEP_SCIFI)) & (layer_a == last)
    kind[gap], slot[gap] = leave[gap], last[gap]
    return kind, slot


# ----------------------------------------------------------------------------- robust fits


@dataclass
class FitReport:
    """Outcome of one minimisation (iminuit): validity, function calls, points used."""

    valid: bool
    calls: int
    points: int
    sigma: float | None = None

    def as_dict(self) -> dict:
        return {"valid": self.valid, "calls": self.calls, "points": self.points, "sigma": self.sigma}


@nb.njit(cache=True)
def _orthonormalize(a, q, r):
    """Thin QR of a (n, k) by classical Gram–Schmidt with re-orthogonalisation (CGS2):
    q (n, k, Fortran order) with columns of RMS 1 (qᵀq = n·I), r (k, k) upper triangular,
    a = q·r. A column dependent on the earlier ones (relative norm < 1e-12 after the
    projections) gets q = 0 and r[j, j] = 0. Plain loops, no BLAS: OpenBLAS threads on a
    loaded 2-core machine made each matrix–vector product ~70× slower."""
    n, k = a.shape
    for j in range(k):
        norm0 = 0.0
        for i in range(n):
            q[i, j] = a[i, j]
            norm0 += a[i, j] * a[i, j]
        for i in range(k):
            r[i, j] = 0.0
        for _ in range(2):
            for m in range(j):
                c = 0.0
                for i in range(n):
                    c += q[i, m] * q[i, j]
                c /= n
                r[m, j] += c
                for i in range(n):
                    q[i, j] -= c * q[i, m]
        norm = 0.0
        for i in range(n):
            norm += q[i, j] * q[i, j]
        if norm <= 1e-24 * norm0 or norm == 0.0:
            for i in range(n):
                q[i, j] = 0.0
            continue
        rms = math.sqrt(norm / n)
        r[j, j] = rms
        for i in range(n):
            q[i, j] /= rms


@nb.njit(cache=True)
def _mixture_terms(q, y, gamma, log_sigma, norm, background, r, g):
    """r = (y − q·γ)/σ and g = norm·exp(−r²/2)/σ per point; returns Σ −ln(g + background)."""
    n, k = q.shape
    s = math.exp(log_sigma)
    for i in range(n):
        r[i] = y[i]
    for j in range(k):
        c = gamma[j]
        if c != 0.0:
            for i in range(n):
                r[i] -= c * q[i, j]
    total = 0.0
    for i in range(n):
        r[i] /= s
        g[i] = norm * math.exp(-0.5 * r[i] * r[i]) / s
        total -= math.log(g[i] + background)
    return total


@nb.njit(cache=True)
def _mixture_gradient(q, r, g, log_sigma, background, out):
    """∂(−ln L)/∂γ_j = −Σ w·r·q_j/σ and ∂/∂ln σ = −Σ w·(r² − 1), w = g/(g + background)."""
    n, k = q.shape
    s = math.exp(log_sigma)
    wr = np.empty(n)
    d_log_sigma = 0.0
    for i in range(n):
        w = g[i] / (g[i] + background)
        wr[i] = w * r[i]
        d_log_sigma -= w * (r[i] * r[i] - 1.0)
    for j in range(k):
        c = 0.0
        for i in range(n):
            c += q[i, j] * wr[i]
        out[j] = -c / s
    out[k] = d_log_sigma


@nb.njit(cache=True)
def _residual(q, y, gamma, out):
    """out = y − q·γ (plain loops: see `_orthonormalize`)."""
    n, k = q.shape
    for i in range(n):
        out[i] = y[i]
    for j in range(k):
        c = gamma[j]
        if c != 0.0:
            for i in range(n):
                out[i] -= c * q[i, j]


@nb.njit(cache=True)
def _weighted_normal_equations(q, y, w, gram, rhs):
    """gram = qᵀ·W·q and rhs = qᵀ·W·y (W = diag w)."""
    n, k = q.shape
    for j in range(k):
        c = 0.0
        for i in range(n):
            c += w[i] * q[i, j] * y[i]
        rhs[j] = c
        for m in range(j + 1):
            c = 0.0
            for i in range(n):
                c += w[i] * q[i, j] * q[i, m]
            gram[j, m] = c
            gram[m, j] = c


def robust_linear_fit(design: np.ndarray, target: np.ndarray, scale: np.ndarray | None = None
                      ) -> tuple[np.ndarray, FitReport]:
    """β maximising Σ log[(1−ε)·G(target − design·β; σ·scale) + ε/range] (eq. 12).

    σ is free; `scale` gives each pair's expected spread up to that factor — in eq. 12 the
    width is √Q_ss ∝ |q/p|, so the steps pass |q/p| (+ 1/100 GeV): without it the many
    high-momentum pairs with tiny residuals set σ and the low-momentum ones, whose
    residuals are larger, end up in the outlier term and do not shape the fit.

    Numerics: the extended eq. 14 designs mix monomials from qop to qop·y⁴ [mm⁴] that are
    strongly correlated (condition number up to ~1e8 after scaling the columns). The fit
    therefore works in the coordinates γ of an orthonormal basis Q of the design
    (design·diag(1/c) = Q·R, β = diag(1/c)·R⁻¹·γ), where the likelihood is nearly
    isotropic: a few EM iterations (weighted least squares with the inlier posteriors,
    each raising the likelihood) bring γ to the maximum, and iminuit (analytic gradient)
    confirms it and reports its status. Parameters whose column depends linearly on the
    earlier ones are set to 0.
    """
    if scale is not None:
        design = design / scale[:, None]
        target = target / scale
    good = np.all(np.isfinite(design), axis=1) & np.isfinite(target)
    design, target = design[good], target[good]
    n, k = design.shape
    if n < MIN_PAIRS_PER_PARAMETER * k:
        return np.zeros(k), FitReport(False, 0, n)
    scale_cols = np.maximum(np.sqrt(np.mean(design**2, axis=0)), 1e-300)
    q = np.empty((n, k), order="F")
    r_mat = np.zeros((k, k))
    _orthonormalize(np.asfortranarray(design / scale_cols), q, r_mat)
    independent = np.diag(r_mat) > 0.0
    gram = np.empty((k, k))
    gamma0 = np.empty(k)
    _weighted_normal_equations(q, np.ascontiguousarray(target), np.ones(n), gram, gamma0)
    gamma0 /= n  # least squares (qᵀq = n·I)
    resid = np.empty(n)
    _residual(q, np.ascontiguousarray(target), gamma0, resid)
    sigma0 = max(1.4826 * np.median(np.abs(resid - np.median(resid))), 1e-12 * (np.std(target) + 1e-30))
    span = max(np.ptp(target), 1e-300)
    # work in units of σ0 for numerical conditioning
    ys = np.ascontiguousarray(target / sigma0)
    background = OUTLIER_FRACTION * sigma0 / span
    norm = (1 - OUTLIER_FRACTION) / math.sqrt(2 * math.pi)
    r_buf = np.empty(n)
    g_buf = np.empty(n)

    def nll(par):
        par = np.asarray(par, dtype=np.float64)
        return _mixture_terms(q, ys, par[:k], par[k], norm, background, r_buf, g_buf)

    def grad(par):
        par = np.asarray(par, dtype=np.float64)
        _mixture_terms(q, ys, par[:k], par[k], norm, background, r_buf, g_buf)
        out = np.empty(k + 1)
        _mixture_gradient(q, r_buf, g_buf, par[k], background, out)
        return out

    # EM for this mixture (ε fixed): each iteration raises the likelihood
    par = np.concatenate([gamma0 / sigma0, [0.0]])
    last = nll(par)
    rhs = np.empty(k)
    for _ in range(EM_MAX_ITERATIONS):
        nll(par)  # fills r_buf, g_buf at par
        w = g_buf / (g_buf + background)
        _weighted_normal_equations(q, ys, w, gram, rhs)
        gram[~independent, :] = 0.0
        gram[:, ~independent] = 0.0
        gram[~independent, ~independent] = 1.0
        gamma = np.linalg.solve(gram, np.where(independent, rhs, 0.0))
        _residual(q, ys, gamma, resid)
        sigma = math.sqrt(max(np.sum(w * resid**2) / max(np.sum(w), 1e-300), 1e-300))
        trial = np.concatenate([gamma, [min(max(math.log(sigma), -7.0), 7.0)]])
        value = nll(trial)
        if not value <= last:  # no progress (or NaN): keep the best point
            break
        par, improvement, last = trial, last - value, value
        if improvement < EM_TOLERANCE * max(abs(last), 1.0):
            break
    m = Minuit(nll, par, grad=grad)
    m.errordef = Minuit.LIKELIHOOD
    m.limits = [(None, None)] * k + [(-7.0, 7.0)]  # σ within e^±7 of the robust start
    # in these coordinates the Hessian is ≈ n·I: steps of the expected errors, and no final
    # numerical Hessian (strategy 0), which alone cost k² ≈ 800 calls
    m.errors = [1.0 / math.sqrt(n)] * k + [1.0 / math.sqrt(2.0 * n)]
    m.strategy = 0
    for j in np.flatnonzero(~independent):
        m.fixed[j] = True
    m.migrad()
    gamma = np.asarray(m.values)[:k] * sigma0
    beta_scaled = np.zeros(k)
    idx = np.flatnonzero(independent)
    if idx.size:
        beta_scaled[idx] = np.linalg.solve(r_mat[np.ix_(idx, idx)], gamma[idx])
    beta = beta_scaled / scale_cols
    return beta, FitReport(bool(m.valid), int(m.nfcn), n, float(math.exp(m.values[k]) * sigma0))


def _fix_parameters_at_limits(m: Minuit) -> bool:
    """Fix each free parameter of `m` that Migrad left within one error of a limit at that
    limit; True if any was. A parameter whose likelihood peaks on its boundary (e.g. the
    noise floor p̃4 of a step with no high-p_T tail: best value 0) keeps Migrad at its call
    limit with an INVALID minimum and an EDM above the goal, although the other parameters
    have converged: one SciFi step of a 200-event π gun (seed 11) gave p̃4 = 1.3e-6 ± 3.3e-6,
    EDM 1.3e-3 after 1,385 calls, and `pkf tune` refused the whole set. With p̃4 fixed at 0
    the same minimum is valid (EDM 4e-7; p̃0…p̃3 equal to 1e-5 relative)."""
    fixed = False
    for j, (lower, upper) in enumerate(m.limits):
        if m.fixed[j]:
            continue
        value, error = m.values[j], m.errors[j]
        for limit in (lower, upper):
            if limit is not None and math.isfinite(limit) and abs(value - limit) <= error:
                m.values[j] = limit
                m.fixed[j] = True
                fixed = True
                break
    return fixed


def fit_noise(dx: np.ndarray, dtx: np.ndarray, dy: np.ndarray, dty: np.ndarray, state: np.ndarray,
              dz: np.ndarray) -> tuple[np.ndarray, FitReport]:
    """Noise parameters p̃0…p̃4 (`parametrized_noise`) maximising the 2-D likelihood of
    eq. 13; `state` (n, 5) are the start states of the steps."""
    good = np.isfinite(dx) & np.isfinite(dtx) & np.isfinite(dy) & np.isfinite(dty)
    dx, dtx, dy, dty, state, dz = dx[good], dtx[good], dy[good], dty[good], state[good], dz[good]
    qop, tx, ty = state[:, 4], state[:, 2], state[:, 3]
    n2 = 1 + tx * tx + ty * ty
    path_x = n2 * np.sqrt(n2) * (1 + tx * tx)
    path_y = n2 * np.sqrt(n2) * (1 + ty * ty)
    n = dx.size
    if n < MIN_NOISE_PAIRS:
        return np.zeros(N_NOISE_PARAMS), FitReport(False, 0, n)
    q2 = qop * qop
    slope_spread = np.sqrt(np.mean(np.concatenate([dtx, dty]) ** 2))
    # start: slope noise ∝ |q/p|, floor small
    p0 = math.sqrt(max(np.median(np.concatenate([dtx, dty]) ** 2 / np.concatenate([q2, q2])), 1e-12))
    pos_ratio = np.sqrt(np.median(dx**2) / max(np.median(dtx**2), 1e-30)) / max(np.median(np.abs(dz)), 1e-9)
    span = max(np.ptp(np.concatenate([dx, dy])) * np.ptp(np.concatenate([dtx, dty])), 1e-300)

    def nll(par):
        a0, a1, r_x, r_y, floor = par
        total = 0.0
        for d, t, rho, path in ((dx, dtx, r_x, path_x), (dy, dty, r_y, path_y)):
            st2 = (a0 * a0) * q2 * path + floor * floor
            sx2 = (a1 * dz) ** 2 * st2 + POSITION_RESOLUTION_FLOOR**2
            det = sx2 * st2 * (1 - rho * rho)
            chi2 = (d * d * st2 - 2 * rho * np.sqrt(sx2 * st2) * d * t + t * t * sx2) / det
            dens = (1 - OUTLIER_FRACTION) * np.exp(-0.5 * chi2) / (2 * math.pi * np.sqrt(det)) + OUTLIER_FRACTION / span
            total -= np.sum(np.log(dens))
        return total

    m = Minuit(nll, (p0, max(pos_ratio, 1e-3), 0.0, 0.0, 1e-3 * slope_spread + 1e-9))
    m.errordef = Minuit.LIKELIHOOD
    m.limits = [(0, None), (NOISE_MIN_POSITION_RATIO, 10.0), (-0.99, 0.99), (-0.99, 0.99), (0, None)]
    m.migrad()
    if m.values[1] < 2 * NOISE_MIN_POSITION_RATIO:
        # No position noise above the 1 µm floor (steps between thin layers with nothing in
        # between: the true state after layer a drifts straight to layer b): p̃1 sits at
        # its lower limit and the correlations ρ, which then scale a covariance of ~0,
        # are not measured. Here the likelihood sees the slope variance as p̃0²(1 − ρ²)
        # (the position residuals are at the floor), so p̃0 and ρ slide along one valley:
        # Migrad either wanders to its call limit (INVALID) or stops anywhere on it — on
        # the VELO of a 200-event gun at ρ = 0.67, p̃0 = 1.52 where the slope residuals say
        # 1.11–1.21 — and the filter, which uses p̃0 alone, got slope pulls of 0.84.
        # Fix p̃1 at the limit and ρ at 0, fit the rest.
        m.values[1], m.values[2], m.values[3] = NOISE_MIN_POSITION_RATIO, 0.0, 0.0
        for j in (1, 2, 3):
            m.fixed[j] = True
        m.migrad()
    if not m.valid and _fix_parameters_at_limits(m):
        m.migrad()
    params = np.zeros(N_NOISE_PARAMS)
    params[:5] = np.abs(np.asarray(m.values))  # p̃5 (straggling) is set per step type
    return params, FitReport(bool(m.valid), int(m.nfcn), n)


# ----------------------------------------------------------------------------- per step type


def _sign(v):
    return np.where(v >= 0, 1.0, -1.0)


def _monomial(x, tx, y, ty, exponents):
    """x^a·tx^b·y^c·ty^d for exponents (a, b, c, d) (`pkf.params.formulas.LAYER_TX_MONOMIALS`)."""
    a, b, c, d = (int(e) for e in exponents)
    return x**a * tx**b * y**c * ty**d


def fit_extrapolation(kind: int, x1: np.ndarray, x2_ref: np.ndarray, z1: np.ndarray, z2: np.ndarray):
    """Extrapolation parameters (9,) of one slot from its pairs (step 1, eq. 12)."""
    p = np.zeros(N_EXTRAPOLATION_PARAMS)
    reports = {}
    x, y, tx, ty, qop = x1.T
    dz = z2 - z1
    scale = np.abs(qop) + SCALE_FLOOR_QOP

    def robust_linear_fit_scaled(design, target):
        return robust_linear_fit(design, target, scale)

    if kind == STEP_VELO:
        beta, reports["tx"] = robust_linear_fit_scaled(np.column_stack([qop * z1, qop]), (x2_ref[:, 2] - tx) / dz)
        p[0] = beta[0]
        p[1] = beta[1] / beta[0] if beta[0] != 0 else 0.0
    elif kind in (STEP_UT, STEP_SCIFI):
        extra_tx = [qop * _monomial(x, tx, y, ty, e) for e in LAYER_TX_MONOMIALS]
        design = np.column_stack([qop, qop**3, y * y * qop, qop * tx * tx, qop * ty * ty, qop * x * x,
                                  qop * ty * y, qop * ty * y**3] + extra_tx)
        beta, reports["tx"] = robust_linear_fit_scaled(design, (x2_ref[:, 2] - tx) / dz)
        p[0:3] = beta[0:3]
        p[6:8] = beta[3:5]
        p[9] = beta[5]
        p[11] = beta[6]
        p[13] = beta[7]
        p[LAYER_TX_OFFSET: LAYER_TX_OFFSET + len(extra_tx)] = beta[8:]
        f_tx = tx + (design @ beta) * dz
        beta, reports["x"] = robust_linear_fit_scaled(((tx - f_tx) * dz)[:, None], x2_ref[:, 0] - x - f_tx * dz)
        p[3] = beta[0]
        extra_ty = [qop * _monomial(x, tx, y, ty, e) for e in LAYER_TY_MONOMIALS]
        design = np.column_stack([qop * tx * _sign(y), qop * tx * ty, qop * x * y, qop * tx * y, qop * tx * y**3]
                                 + extra_ty)
        beta, reports["ty"] = robust_linear_fit_scaled(design, x2_ref[:, 3] - ty)
        p[4], p[8], p[10], p[12], p[14] = beta[:5]
        p[LAYER_TY_OFFSET: LAYER_TY_OFFSET + len(extra_ty)] = beta[5:]
        f_ty = ty + design @ beta
        beta, reports["y"] = robust_linear_fit_scaled(((ty - f_ty) * dz)[:, None], x2_ref[:, 1] - y - f_ty * dz)
        p[5] = beta[0]
    elif kind == STEP_VELO_TO_UT:
        beta, reports["ty"] = robust_linear_fit_scaled((qop * tx * _sign(y))[:, None], x2_ref[:, 3] - ty)
        p[0] = beta[0]
        n1 = np.sqrt(1 + tx**2 + ty**2)
        n2 = np.sqrt(1 + x2_ref[:, 2] ** 2 + x2_ref[:, 3] ** 2)
        beta, reports["tx"] = robust_linear_fit_scaled(np.column_stack([qop, qop * z1, qop * ty**2]),
                                                x2_ref[:, 2] / n2 - tx / n1)
        p[1:4] = beta
        ty_ut = ty + p[0] * qop * tx * _sign(y)
        a = tx / n1 + qop * (p[1] + p[2] * z1 + p[3] * ty**2)
        tx_ut = a * np.sqrt(1 + ty_ut**2) / np.sqrt(np.maximum(1 - a * a, 1e-12))
        kink = tx - tx_ut
        beta, reports["x"] = robust_linear_fit_scaled(np.column_stack([kink, kink * z1, kink * z1**2, kink * ty**2]),
                                               x2_ref[:, 0] - x + z1 * tx - z2 * tx_ut)
        p[4:8] = beta
        beta, reports["y"] = robust_linear_fit_scaled(((ty - ty_ut) * dz)[:, None], x2_ref[:, 1] - y - ty_ut * dz)
        p[8] = beta[0]
    return p, {k: v.as_dict() for k, v in reports.items()}


@nb.njit(cache=True)
def _apply_many(kind, p, x1, z1, z2, uts_meta, uts_cells, out):
    jac = np.empty((5, 5))
    for i in range(z1.size):
        if kind == STEP_VELO:
            velo_step(p, x1[i], z1[i], z2[i], out[i], jac)
        elif kind == STEP_VELO_TO_UT:
            if not velo_to_ut_step(p, x1[i], z1[i], z2[i], out[i], jac):
                out[i, :] = np.nan
        elif kind == STEP_UT_TO_SCIFI:
            shifted = x1[i].copy()
            shifted[4] = x1[i, 4] / (1.0 - p[0] * abs(x1[i, 4]))
            if ut_to_scifi_extrapolate(uts_meta, uts_cells, shifted, out[i], jac) != 0:
                out[i, :] = np.nan
            out[i, 4] = x1[i, 4]
        else:
            layer_step(p, x1[i], z1[i], z2[i], out[i], jac)


def fit_table_energy_loss(x1: np.ndarray, x2_ref: np.ndarray, uts_arrays):
    """ΔE (p[0], MeV) of the UT→SciFi table step: the mean energy lost upstream of the
    magnet, so that the table (made with the local momentum) is evaluated at
    q/p' = q/p/(1 − ΔE·|q/p|). Linear in ΔE to first order: Δtx ≈ ∂tx/∂qop·ΔE·qop·|qop|."""
    p = np.zeros(N_EXTRAPOLATION_PARAMS)
    predicted = np.empty_like(x1)
    jacobians = np.empty((x1.shape[0], 5, 5))
    status = np.empty(x1.shape[0], dtype=np.int64)
    reports = {}
    for iteration in range(2):
        shrink = 1.0 - p[0] * np.abs(x1[:, 4])
        shifted = x1.copy()
        shifted[:, 4] = x1[:, 4] / shrink
        ut_to_scifi_extrapolate_many(*uts_arrays, np.ascontiguousarray(shifted), predicted, jacobians, status)
        ok = status == 0
        design = (jacobians[:, 2, 4] * shifted[:, 4] * np.abs(shifted[:, 4]))[ok][:, None]
        beta, report = robust_linear_fit(design, (x2_ref[:, 2] - predicted[:, 2])[ok],
                                         np.abs(shifted[ok, 4]) + SCALE_FLOOR_QOP)
        p[0] += beta[0]
        reports[f"energy_loss_pass{iteration}"] = report.as_dict()
    reports["delta_e_mev"] = float(p[0])
    # straggling: the spread of the energy lost before the step, from the same residuals
    # (δE_i = Δtx_i / (∂tx/∂qop·qop·|qop|)), its Gaussian core width [MeV]
    implied = (x2_ref[:, 2] - predicted[:, 2])[ok] / design[:, 0]
    reports["straggling_mev"] = float(gaussian_core(implied).sigma)
    return p, reports


def required_pairs(kind: int) -> int:
    """State pairs a step of type `kind` needs at least: every one of its fits has
    MIN_PAIRS_PER_PARAMETER pairs per free parameter, the noise fit MIN_NOISE_PAIRS."""
    return max(MIN_PAIRS_PER_PARAMETER * EXTRAPOLATION_FIT_PARAMETERS[kind], MIN_NOISE_PAIRS)


@dataclass(frozen=True)
class StepGroup:
    """The pairs that tune one parameter set: `name` ("velo" or "slot N"), step type,
    the slots that receive the set and the indices of its pairs in the StatePairs."""

    name: str
    kind: int
    slots: np.ndarray
    pairs: np.ndarray


def step_groups(slots: SlotStructure, pairs: StatePairs, n_layers: int) -> list[StepGroup]:
    """The parameter sets to tune, one per slot; the VELO set is shared by all VELO slots —
    every slot whose step is of the VELO type gets it, also the upstream modules that
    tracks from the luminous region never leave from. Includes the slots without pairs
    (an empty `pairs`), so that a caller sees every set the geometry needs."""
    kind, slot = pair_slot(slots, pairs.layer_a, pairs.layer_b)
    velo = kind == STEP_VELO
    velo_slots = np.array([i for i in range(n_layers - 1) if slots.slot_kind(i) == STEP_VELO], dtype=np.int64)
    groups = []
    if velo_slots.size or velo.any():
        groups.append(StepGroup("velo", STEP_VELO, velo_slots, np.flatnonzero(velo)))
    for s in range(n_layers - 1):
        k = slots.slot_kind(s)
        if k in (STEP_NONE, STEP_VELO):
            continue
        groups.append(StepGroup(f"slot {s}", k, np.array([s]), np.flatnonzero((slot == s) & ~velo)))
    return groups


def short_steps(groups: list[StepGroup]) -> list[tuple[StepGroup, int]]:
    """The groups with fewer pairs than their fits need (`required_pairs`), with that need."""
    return [(g, required_pairs(g.kind)) for g in groups if g.pairs.size < required_pairs(g.kind)]


@dataclass
class TuningResult:
    """Parameters per slot and the report of every fit."""

    extrapolation: np.ndarray
    noise: np.ndarray
    reports: dict = field(default_factory=dict)


def tune_slots(slots: SlotStructure, pairs: StatePairs, layer_z: np.ndarray, uts_arrays, progress=None) -> TuningResult:
    """Both tuning steps for every slot that has pairs."""
    n_layers = layer_z.size
    extrapolation = np.zeros((n_layers, N_EXTRAPOLATION_PARAMS))
    noise = np.zeros((n_layers, N_NOISE_PARAMS))
    z1 = layer_z[pairs.layer_a]
    z2 = layer_z[pairs.layer_b]
    reports = {}
    rng = np.random.default_rng(12345)
    for group in step_groups(slots, pairs, n_layers):
        name, k, members, sel = group.name, group.kind, group.slots, group.pairs
        if sel.size == 0:
            continue
        if sel.size > MAX_PAIRS_PER_FIT:
            sel = np.sort(rng.choice(sel, MAX_PAIRS_PER_FIT, replace=False))
        x1, x2, x2r = pairs.x1[sel], pairs.x2[sel], pairs.x2_ref[sel]
        if k == STEP_UT_TO_SCIFI:
            p, rep = fit_table_energy_loss(x1, x2r, uts_arrays)
        else:
            p, rep = fit_extrapolation(k, x1, x2r, z1[sel], z2[sel])
        predicted = np.empty_like(x1)
        _apply_many(k, p, np.ascontiguousarray(x1), z1[sel], z2[sel], *uts_arrays, predicted)
        d = predicted - x2
        pn, noise_report = fit_noise(d[:, 0], d[:, 2], d[:, 1], d[:, 3], x1, z2[sel] - z1[sel])
        if k == STEP_UT_TO_SCIFI:
            pn[5] = rep["straggling_mev"]
        extrapolation[members] = p
        noise[members] = pn
        reports[name] = {"kind": int(k), "slots": [int(m) for m in members], "pairs": int(sel.size),
                         "extrapolation": rep, "noise": noise_report.as_dict()}
        if progress is not None:
            progress(name, reports[name])
    return TuningResult(extrapolation, noise, reports)
