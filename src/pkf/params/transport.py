"""The parametrized transport (paper §4, docs/parameters.md): steps, their chain and the extrapolator record.

The one home of the parametrized extrapolation; no field or material map at fit time.
The Kalman fitters use it through `pkf.fit.extrapolator` (which registers
`parametrized_step` for `ParametrizedExtrapolator`), the forward search of the pattern
recognition through `pkf.seeding.forward_steps`, the tuning through the step codes.

A step between two nodes is cut into the paper's steps, chosen by the geometry's
``[[steps]]`` table (the type of each subdetector-to-subdetector segment):

- inside a subdetector of type ``velo``: one step of any length (eq. 10);
- inside a subdetector of type ``ut``/``scifi``: the per-layer steps (eq. 14), chained
  through layers without a hit (paper §3: no update where there is no measurement);
- leaving a subdetector by ``velo_to_ut``: one step from the last state inside it to
  the first layer of the next (eqs. 15–20);
- leaving by ``ut_to_scifi``: per-layer steps to the subdetector's last layer, then the
  tabulated step to the next subdetector's first layer (eqs. 21–23, `pkf.params.ut_to_scifi`).

Each step has its own parameter slot: slot i holds the parameters of the step that
leaves layer i (the ``velo`` set is shared by all VELO slots). q/p is the momentum at
production. Only downstream steps exist: the Kalman core's backward filter reuses the
forward steps (see `pkf.fit.kalman`), so no upstream parameter sets are needed.

Status codes (TRANSPORT_*) are the values of the track status codes of
`pkf.fit.extrapolator` (STATUS_OK, STATUS_EXTRAPOLATION_FAILED, STATUS_BELOW_P_MIN).
Units: mm, 1/MeV.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import numba as nb
import numpy as np

from pkf.geometry.acceptance import in_active_area
from pkf.geometry.detector import Geometry
from pkf.jit import NO_REFCOUNT, fma
from pkf.params.formulas import layer_step, parametrized_noise, velo_step, velo_to_ut_step
from pkf.params.ut_to_scifi import ut_to_scifi_extrapolate
from pkf.physics.linalg import copy5, copy55, matmul55, search_sorted, set_identity, transport_cov
from pkf.physics.transport import rk4_transport_jacobian

TRANSPORT_OK = 0
TRANSPORT_FAILED = 2  # an unphysical step (|tx/N| ≥ 1 after the VELO→UT kink, NaN), a bad table
TRANSPORT_BELOW_P_MIN = 4  # the UT→SciFi table evaluated beyond its p_min (|w| > 1), without fallback

#: RK4 step [mm] of the UT→SciFi fallback below the table's p_min (the reference fitter's step).
FALLBACK_MAX_STEP = 100.0

STEP_NONE = -1
STEP_VELO = 0
STEP_VELO_TO_UT = 1
STEP_UT = 2
STEP_UT_TO_SCIFI = 3
STEP_SCIFI = 4
STEP_CODES = {"velo": STEP_VELO, "velo_to_ut": STEP_VELO_TO_UT, "ut": STEP_UT,
              "ut_to_scifi": STEP_UT_TO_SCIFI, "scifi": STEP_SCIFI}


class ParametrizedExtrapolator(NamedTuple):
    """Context of the parametrized extrapolator.

    layer_z (L) [mm]; layer_sub (L) subdetector index; sub_first/sub_last (S) first and
    last layer of each subdetector (−1 if absent); within_type/between_type (S) the step
    type inside the subdetector and for leaving it (STEP_*); extrapolation (L, 9) and
    noise (L, 6) parameters per slot; layer_area (L, 7) each layer's material area
    (`area_record`: half_x, half_y, hole_radius, hole_half_x, hole_half_y [mm], side,
    side_overlap [mm]) for the VELO layers a step crosses without a hit
    (`add_crossed_velo_layers`); uts_meta/uts_cells the UT→SciFi table arrays (`UTSciFiTable.as_arrays`);
    field_kind/field_params/field_grid the field map of the UT→SciFi fallback below the
    table's p_min (`_apply`; field_kind < 0: no fallback, such steps return
    TRANSPORT_BELOW_P_MIN).
    """

    layer_z: np.ndarray
    layer_sub: np.ndarray
    sub_first: np.ndarray
    sub_last: np.ndarray
    within_type: np.ndarray
    between_type: np.ndarray
    extrapolation: np.ndarray
    noise: np.ndarray
    layer_area: np.ndarray
    uts_meta: np.ndarray
    uts_cells: np.ndarray
    field_kind: int = -1
    field_params: np.ndarray = np.zeros(1)
    field_grid: np.ndarray = np.zeros((1, 1, 1, 3))


@nb.njit(cache=True, inline="always")
def _layer_of(layer_z, z):
    i = search_sorted(layer_z, z, False)
    if i < layer_z.size and abs(layer_z[i] - z) < 1e-6:
        return i
    return -1


@nb.njit(cache=True, inline="always")
def _layer_after(layer_z, a, z):
    """`_layer_of(layer_z, z)` knowing layer a (−1: none): for a z downstream of it, a
    linear scan from a + 1 (the next node is mostly one to three layers on) instead of a
    second bisection, with the same result."""
    if a < 0 or not layer_z[a] < z:
        return _layer_of(layer_z, z)
    i = a + 1
    while i < layer_z.size and layer_z[i] < z:
        i += 1
    if i < layer_z.size and abs(layer_z[i] - z) < 1e-6:
        return i
    return -1


@nb.njit(cache=True)
def _rk4_fallback(field_kind, field_params, field_grid, seg_state, z0, z1, seg_jac, stages):
    """The UT→SciFi step by RK4 (with its Jacobian) through the field map, for states below
    the table's p_min: seg_state transported in place from z0 to z1 [mm] (stages: the RK
    stages' scratch, `rk4_transport_jacobian`). TRANSPORT_FAILED if the track leaves the
    envelope (|tx|, |ty| > 10 or not finite: it curls in the magnet)."""
    rk4_transport_jacobian(seg_state, z0, z1, FALLBACK_MAX_STEP, field_kind, field_params, field_grid, seg_jac,
                           stages)
    for i in range(5):
        if not math.isfinite(seg_state[i]):
            return TRANSPORT_FAILED
    if abs(seg_state[2]) > 10.0 or abs(seg_state[3]) > 10.0:
        return TRANSPORT_FAILED
    return TRANSPORT_OK


@nb.njit(cache=True, inline="always")
def _apply(kind, p, uts_meta, uts_cells, cur_state, z0, z1, seg_state, seg_jac, field_kind, field_params,
           field_grid, stages):
    """One paper step of `kind` with parameters `p`; returns a status. Below the UT→SciFi
    table's p_min the step is RK4 through the field map (`_rk4_fallback`, stages its
    scratch) when the context has one (field_kind ≥ 0): the table's polynomials are not
    valid there."""
    if kind == STEP_VELO:
        velo_step(p, cur_state, z0, z1, seg_state, seg_jac)
    elif kind == STEP_VELO_TO_UT:
        if not velo_to_ut_step(p, cur_state, z0, z1, seg_state, seg_jac):
            return TRANSPORT_FAILED
    elif kind == STEP_UT_TO_SCIFI:
        # The table was made by RK4 with the local momentum; the state carries the one at
        # production: evaluate it at q/p' = q/p / (1 − ΔE·|q/p|), ΔE = p[0] [MeV] the tuned
        # mean energy lost upstream of the magnet.
        qop = cur_state[4]
        shrink = 1.0 - p[0] * abs(qop)
        copy5(cur_state, seg_state)
        seg_state[4] = qop / shrink
        status = ut_to_scifi_extrapolate(uts_meta, uts_cells, seg_state, seg_state, seg_jac)
        if status == TRANSPORT_BELOW_P_MIN and field_kind >= 0:
            copy5(cur_state, seg_state)
            seg_state[4] = qop / shrink
            status = _rk4_fallback(field_kind, field_params, field_grid, seg_state, z0, z1, seg_jac, stages)
        if status != TRANSPORT_OK:
            return status  # TRANSPORT_BELOW_P_MIN, or TRANSPORT_FAILED for a bad table
        dqop = 1.0 / (shrink * shrink)
        for i in range(4):
            seg_jac[i, 4] *= dqop
        seg_state[4] = qop
    elif kind == STEP_UT or kind == STEP_SCIFI:
        layer_step(p, cur_state, z0, z1, seg_state, seg_jac)
    else:
        return TRANSPORT_FAILED
    return TRANSPORT_OK


@nb.njit(cache=True, inline="always")
def step_noise(pn, state, dz, jac, noise):
    """Process noise of one paper step of length dz [mm] from `state` (5): paper eq. 11
    with the slot's noise parameters pn, plus the energy-loss straggling before the step,
    a q/p variance (pn[5]·(q/p)²)² [1/MeV²] carried through the step's Jacobian `jac`.
    The q/p of `state` sets the size of both (a search evaluates it at a hypothesis)."""
    parametrized_noise(pn, state, dz, noise)
    if pn[5] > 0.0:  # energy-loss straggling before the step: q/p noise through J
        var_qop = (pn[5] * state[4] * state[4]) ** 2
        for i in range(5):
            for j in range(5):
                noise[i, j] = fma(var_qop * jac[i, 4], jac[j, 4], noise[i, j])


def area_record(geometry: Geometry) -> np.ndarray:
    """(L, 7) float64: per active layer, the material area of its plane (half_x, half_y,
    hole_radius, hole_half_x, hole_half_y [mm], side code, side_overlap [mm]), the
    arguments of `pkf.geometry.acceptance.in_active_area`."""
    planes = geometry.planes
    index = geometry.layer_plane
    return np.ascontiguousarray(np.stack([
        planes.half_x[index], planes.half_y[index], planes.hole_radius[index], planes.hole_half_x[index],
        planes.hole_half_y[index], planes.side[index].astype(np.float64), planes.side_overlap[index],
    ], axis=1), dtype=np.float64)


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def add_crossed_velo_layers(layer_z, layer_area, pn, state, cur, nxt, jac, noise, q_start, tmp, out):
    """Add to the step's noise (5×5, at z_to) the scattering of the VELO layers strictly
    between layers `cur` and `nxt` that the track crosses without a hit.

    The paper's VELO step (eq. 10–11) carries one plane's scattering, the plane at z_to
    (the tuned lever p̃1 ≈ 0); the tuning sees consecutive crossings only. A step across a
    layer whose hit is missing (inefficiency, or the pattern left it out) crosses its
    material too: without it the first-hit tx/ty pull cores of 1–4 GeV pions whose second
    VELO hit is missing were 1.51/1.55 (0.96/0.97 with it, the reference fit 0.99/0.99;
    tests/params/test_crossed_velo_layers.py), and on minimum bias VELO-only candidates the
    written first-hit tx variance was down to 10⁻³–10⁻⁴ of the reference fit's. Each crossed layer l
    (the straight line from `state` at layer cur lies on its area) adds the VELO slot's
    plane scattering θ² (eq. 11 at Δz = 0: (p̃0·q/p)²·N³·(1 + t²) + p̃4²) at z_l; written as
    the equivalent kick at z_cur (δt = θ, δx = −(z_l − z_cur)·θ) and carried by the step's
    Jacobian: noise += J·Q_cur·Jᵀ — exact for the straight VELO track between z_cur and z_l.
    q_start, tmp, out: 5×5 scratch. Inlined and without reference counts: it runs on the 57 %
    of minimum-bias VELO steps that skip a layer (mostly one of the other half), where as a
    call its 11 arrays went by value and each crossed layer's area view was counted.
    Measured on benchmarks/fit_core.py's minimum-bias tracks (the parametrized forward
    filter: step, covariance transport, update; CPU, old and new code alternating in one
    process, each compilation order divided by an A/B of identical code): ×0.966 and ×0.991
    inlined, the same numbers."""
    z0 = layer_z[cur]
    x0 = state[0]
    y0 = state[1]
    tx = state[2]
    ty = state[3]
    crossed = False
    for layer in range(cur + 1, nxt):
        lever = layer_z[layer] - z0
        a = layer_area[layer]
        if not in_active_area(x0 + tx * lever, y0 + ty * lever, a[0], a[1], a[2], a[3], a[4], int(a[5]), a[6]):
            continue
        if not crossed:
            parametrized_noise(pn, state, 0.0, tmp)  # θ² of one plane in tmp[2, 2], tmp[3, 3]
            for i in range(5):
                for j in range(5):
                    q_start[i, j] = 0.0
            crossed = True
        q_tx = tmp[2, 2]
        q_ty = tmp[3, 3]
        q_start[2, 2] += q_tx
        q_start[3, 3] += q_ty
        q_start[0, 0] = fma(lever * lever, q_tx, q_start[0, 0])
        q_start[1, 1] = fma(lever * lever, q_ty, q_start[1, 1])
        q_start[0, 2] = fma(-lever, q_tx, q_start[0, 2])
        q_start[1, 3] = fma(-lever, q_ty, q_start[1, 3])
    if not crossed:
        return
    q_start[2, 0] = q_start[0, 2]
    q_start[3, 1] = q_start[1, 3]
    transport_cov(jac, q_start, tmp, out)
    for i in range(5):
        for j in range(5):
            noise[i, j] += out[i, j]


@nb.njit(cache=True, inline="always")
def next_step(layer_sub, sub_last, within_type, between_type, cur, target):
    """(kind, slot, next layer) of the paper step from layer `cur` towards layer `target`."""
    s = layer_sub[cur]
    if layer_sub[target] == s:
        kind = within_type[s]
        if kind == STEP_VELO:
            return kind, cur, target
        return kind, cur, cur + 1
    last = sub_last[s]
    leave = between_type[s]
    if leave == STEP_VELO_TO_UT:
        return leave, last, last + 1
    if cur < last:
        kind = within_type[s]
        if kind == STEP_VELO:
            return kind, cur, last
        return kind, cur, cur + 1
    return leave, last, last + 1


@nb.njit(cache=True, inline="always")
def parametrized_step(ext, state_in, z_from, z_to, state_out, jac_out, noise_out, work):
    """Downstream transport between two layers through the chain of paper steps."""
    copy5(state_in, state_out)
    if z_to == z_from:
        set_identity(jac_out)
        for i in range(5):
            for j in range(5):
                noise_out[i, j] = 0.0
        return TRANSPORT_OK
    # small helpers get plain arrays: passing the whole context costs ~20 reference counts
    layer_z = ext.layer_z
    a = _layer_of(layer_z, z_from)
    b = _layer_after(layer_z, a, z_to)
    if a < 0 or b < 0 or b < a:
        return TRANSPORT_FAILED
    seg_jac = work[0]
    seg_noise = work[1]
    tmp = work[2]
    tmp2 = work[3]
    seg_state = work[5, 0]
    cur = a
    first = True
    while cur < b:
        kind, slot, nxt = next_step(ext.layer_sub, ext.sub_last, ext.within_type, ext.between_type, cur, b)
        # the first paper step writes F = J, Q = Q_seg in place (most node-to-node steps
        # are a single one); later ones go to scratch and are chained
        step_jac = jac_out if first else seg_jac
        step_noise_out = noise_out if first else seg_noise
        status = _apply(kind, ext.extrapolation[slot], ext.uts_meta, ext.uts_cells, state_out,
                        layer_z[cur], layer_z[nxt], seg_state, step_jac, ext.field_kind, ext.field_params,
                        ext.field_grid, work[1:5])  # work[1:5] is free until step_noise
        if status != TRANSPORT_OK:
            return status
        step_noise(ext.noise[slot], state_out, layer_z[nxt] - layer_z[cur], step_jac, step_noise_out)
        if (kind == STEP_VELO or kind == STEP_VELO_TO_UT) and nxt > cur + 1:
            add_crossed_velo_layers(layer_z, ext.layer_area, ext.noise[cur], state_out, cur, nxt, step_jac,
                                    step_noise_out, work[4], tmp, tmp2)  # work[2:5] free until chaining
        copy5(seg_state, state_out)
        if first:
            first = False
        else:  # F ← J·F, Q ← J·Q·Jᵀ + Q_seg
            matmul55(seg_jac, jac_out, tmp)
            copy55(tmp, jac_out)
            transport_cov(seg_jac, noise_out, tmp, tmp2)
            for i in range(5):
                for j in range(5):
                    noise_out[i, j] = tmp2[i, j] + seg_noise[i, j]
        cur = nxt
    return TRANSPORT_OK

