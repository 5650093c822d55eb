"""Parametrized transport for the forward extension: reference trajectories and q/p scans.

docs/physics.md#pattern-recognition, docs/physics.md#the-parametrized-fitter. The forward extension (`pkf.seeding.forward`) needs, for one VELO
track, many transports of the same start state with different q/p hypotheses. This
module provides them with the paper's parametrized steps of `pkf.params.transport` (the
shipped or tuned parameter set), without a field map:

- `reference_trajectory`: the transport of a VELO state through every UT and SciFi layer
  (one paper step per layer pair, as `pkf.params.transport.parametrized_step` chains
  them), with the Jacobian and the process noise of each step evaluated at a chosen |q/p|
  (the noise of the paper's eq. 11 is ∝ (q/p)²: a search needs it at the hypothesis, not
  at the linearisation point);
- `scan_states`: x, y and d/dq on the SciFi layers for a list of q/p hypotheses.

Both take the UT→SciFi step (paper eqs. 21–23) with coefficients localised once per track
(`pkf.params.ut_to_scifi.localize_ut_to_scifi`, `ut_to_scifi_extrapolate_localized`): a q/p
scan costs one interpolation instead of one per hypothesis. Below the table's p_min the
search continues the polynomials quadratically (``quadratic=True``, see
`pkf.params.ut_to_scifi`); such states carry status `TRANSPORT_BELOW_P_MIN` (4): the hits
found are usable, the q/p estimate is flagged (the Kalman fit decides what to do with a
status-4 parametrization).

Units: mm, 1/MeV (q/p at production, docs/physics.md#the-parametrized-fitter).
"""

from __future__ import annotations

import numba as nb
import numpy as np

from pkf.jit import NO_REFCOUNT
from pkf.params import formulas
from pkf.params.transport import TRANSPORT_BELOW_P_MIN, TRANSPORT_FAILED, TRANSPORT_OK, step_noise
from pkf.params.ut_to_scifi import ut_to_scifi_extrapolate_localized

# The per-layer formula (pkf.params.formulas), compiled again for inlining: the search calls
# it ~10⁵ times per event. The rare, large steps (VELO→UT, the table) stay ordinary calls:
# inlining them into the step dispatch makes every step ~5× slower.
_INLINE = dict(cache=True, inline="always", **NO_REFCOUNT)
layer_step = nb.njit(**_INLINE)(getattr(formulas.layer_step, "py_func", formulas.layer_step))
velo_to_ut_step = formulas.velo_to_ut_step

__all__ = [
    "TRANSPORT_BELOW_P_MIN", "TRANSPORT_FAILED", "TRANSPORT_OK",
    "new_table_buffers", "reference_trajectory", "scan_states",
]


@nb.njit(cache=True, inline="always", **NO_REFCOUNT)
def _noise_at(noise_par, slot, s, q_noise, dz, s_tmp, jac, out):
    """The noise of the step leaving `slot` (`pkf.params.transport.step_noise`) at the
    slopes of s and |q/p| = q_noise."""
    for i in range(4):
        s_tmp[i] = s[i]
    s_tmp[4] = q_noise
    step_noise(noise_par[slot], s_tmp, dz, jac, out)


@nb.njit(cache=True, **NO_REFCOUNT)
def reference_trajectory(ext, poly, ref, quadratic, a, f_layer, n_ut, j_end, s_start, q_noise,
                         ref_s, ref_F, ref_Q, s_tmp):
    """Transport s_start (5, at VELO layer a) to the forward layers f_layer[0 … j_end−1]
    (the UT layers, then the SciFi layers, consecutive in the geometry): ref_s[j] (5),
    the Jacobian ref_F[j] of the step from the previous layer (from layer a for j = 0)
    and its noise ref_Q[j] at |q/p| = q_noise. One paper step per layer pair: VELO→UT
    (eqs. 15–20), UT/SciFi layer steps (eq. 14), UT→SciFi table (eqs. 21–23).
    Returns the worst TRANSPORT_* status.

    The two large steps are ordinary calls outside the per-layer loops: an un-taken
    call inside the loop makes every inlined layer step ~5× slower (numba keeps the
    array arguments reference counted).
    """
    layer_z = ext.layer_z
    extrap = ext.extrapolation
    noise_par = ext.noise
    status = TRANSPORT_OK
    z1 = layer_z[f_layer[0]]
    slot = ext.sub_last[ext.layer_sub[a]]
    if not velo_to_ut_step(extrap[slot], s_start, layer_z[a], z1, ref_s[0], ref_F[0]):
        return TRANSPORT_FAILED
    _noise_at(noise_par, slot, s_start, q_noise, z1 - layer_z[a], s_tmp, ref_F[0], ref_Q[0])
    for j in range(1, min(n_ut, j_end)):
        l0 = f_layer[j - 1]
        dz = layer_z[l0 + 1] - layer_z[l0]
        layer_step(extrap[l0], ref_s[j - 1], layer_z[l0], layer_z[l0 + 1], ref_s[j], ref_F[j])
        _noise_at(noise_par, l0, ref_s[j - 1], q_noise, dz, s_tmp, ref_F[j], ref_Q[j])
    if j_end > n_ut:
        l0 = f_layer[n_ut - 1]
        status = ut_to_scifi_extrapolate_localized(ext.uts_meta, poly, ref, extrap[l0, 0], ref_s[n_ut - 1], ref_s[n_ut],
                            ref_F[n_ut], quadratic)
        _noise_at(noise_par, l0, ref_s[n_ut - 1], q_noise, layer_z[l0 + 1] - layer_z[l0], s_tmp,
                  ref_F[n_ut], ref_Q[n_ut])
        for j in range(n_ut + 1, j_end):
            l0 = f_layer[j - 1]
            dz = layer_z[l0 + 1] - layer_z[l0]
            layer_step(extrap[l0], ref_s[j - 1], layer_z[l0], layer_z[l0 + 1], ref_s[j], ref_F[j])
            _noise_at(noise_par, l0, ref_s[j - 1], q_noise, dz, s_tmp, ref_F[j], ref_Q[j])
    for i in range(5):
        if not np.isfinite(ref_s[j_end - 1, i]):
            return TRANSPORT_FAILED
    return status


@nb.njit(cache=True, **NO_REFCOUNT)
def scan_states(ext, poly, ref, quadratic, l_from, sf_layers, s0, ds0, q_nodes, xs, dxs, ys, dys,
                work):
    """States on the SciFi layers for each q/p node, from the last UT layer l_from.

    sf_layers: the SciFi layers (consecutive, the first is l_from + 1). The start state
    for the hypothesis q is s0[:4] + ds0[:4]·(q − s0[4]) (a conditional mean given q,
    e.g. of a fitted UT state); outputs x, y and their total derivatives d/dq on each
    SciFi layer: xs, dxs, ys, dys (n_nodes, n_layers). work: (4, 5, 5) scratch.
    Returns the worst TRANSPORT_* status; TRANSPORT_FAILED where a node's state or its
    derivative is not finite at the last layer (a non-finite value, once there, stays:
    the steps are products and sums). The derivative counts too: a steep VELO track
    (at the last UT layer x = −0.59 m, y = 0.57 m, slopes −0.23, 0.22; minimum bias at
    ν = 2) kept a finite state at the lowest q/p node whose derivative overflowed, and
    the scan's implied q/p of a hit became NaN (`pkf.seeding.forward.hough`).
    """
    layer_z = ext.layer_z
    extrap = ext.extrapolation
    s = work[0, 0]
    s_next = work[0, 1]
    d = work[0, 2]
    d_next = work[0, 3]
    jac = work[1]
    status = TRANSPORT_OK
    n_layers = sf_layers.shape[0]
    eloss = extrap[l_from, 0]
    for k in range(q_nodes.shape[0]):
        q = q_nodes[k]
        for i in range(4):
            s[i] = s0[i] + ds0[i] * (q - s0[4])
            d[i] = ds0[i]
        s[4] = q
        d[4] = 1.0
        st = ut_to_scifi_extrapolate_localized(ext.uts_meta, poly, ref, eloss, s, s_next, jac, quadratic)
        status = max(status, st)
        for li in range(n_layers):
            if li > 0:
                l0 = sf_layers[li - 1]
                layer_step(extrap[l0], s, layer_z[l0], layer_z[l0 + 1], s_next, jac)
            for i in range(5):
                acc = 0.0
                for m in range(5):
                    acc += jac[i, m] * d[m]
                d_next[i] = acc
            for i in range(5):
                s[i] = s_next[i]
                d[i] = d_next[i]
            xs[k, li] = s[0]
            ys[k, li] = s[1]
            dxs[k, li] = d[0]
            dys[k, li] = d[1]
        for i in range(5):
            if not (np.isfinite(s[i]) and np.isfinite(d[i])):
                return TRANSPORT_FAILED
    return status


def new_table_buffers(ext) -> tuple[np.ndarray, np.ndarray]:
    """Scratch (poly, ref) for `localize_ut_to_scifi` sized for the extrapolator's table."""
    return np.zeros((3, 4, max(ext.uts_cells.shape[3], 1))), np.zeros(2)
