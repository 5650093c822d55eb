"""Below the momentum the UT→SciFi table covers the parametrized step is RK4 through the field map (issue 15).

Before: the step returned status 4 ("momentum below the parametrization's p_min") and the
parametrized fitter refused the track (1,236 of 12,765 real long tracks of 60 minimum-bias
events at ν = 7.6, 1,091 of them at 1.5–3 GeV, when the table covered p ≥ 3 GeV). The
shipped table covers p ≥ 1.5 GeV (its soft range, `pkf.params.ut_to_scifi`); below that the
step is RK4.
"""

import numpy as np
import pytest

from pkf.geometry import load_geometry
from pkf.params.parameter_set import shipped_parameters
from pkf.params.transport import (
    FALLBACK_MAX_STEP,
    TRANSPORT_BELOW_P_MIN,
    TRANSPORT_OK,
    parametrized_step,
)
from pkf.params.ut_to_scifi import ut_to_scifi_extrapolate
from pkf.physics.transport import rk4_propagate


@pytest.fixture(scope="module")
def setup():
    geometry = load_geometry("lhcb-like")
    params = shipped_parameters(geometry)
    ext = params.extrapolator(geometry)
    z_ut = float(geometry.layer_z[geometry.subdetector_layers("ut")[-1]])
    z_t = float(geometry.layer_z[geometry.subdetector_layers("scifi")[0]])
    slot = int(geometry.subdetector_layers("ut")[-1])
    return geometry, params, ext, z_ut, z_t, slot


def _state_at_ut(geometry, p, tx=0.06, ty=0.03, charge=1.0):
    field = geometry.reconstruction_field()
    start = np.array([0.0, 0.0, tx, ty, charge / p])
    return rk4_propagate(start, 0.0, 2642.5, 10.0, *field.args)


def _step(ext, state, z_from, z_to):
    out = np.empty(5)
    jac = np.empty((5, 5))
    noise = np.empty((5, 5))
    work = np.empty((6, 5, 5))
    status = parametrized_step(ext, state, z_from, z_to, out, jac, noise, work)
    return status, out, jac, noise


@pytest.mark.parametrize("p", [1150.0, 1300.0, 1450.0])
@pytest.mark.parametrize("charge", [1.0, -1.0])
def test_below_p_min_the_step_is_rk4_through_the_map(setup, p, charge):
    geometry, params, ext, z_ut, z_t, slot = setup
    assert p < params.ut_to_scifi.covered_p_min == 1500.0
    state = _state_at_ut(geometry, p, charge=charge)
    status, out, jac, noise = _step(ext, state, z_ut, z_t)
    assert status == TRANSPORT_OK
    # the table is evaluated at q/p' = q/p/(1 − ΔE|q/p|) (the tuned loss before the magnet)
    shrink = 1.0 - ext.extrapolation[slot][0] * abs(state[4])
    moved = state.copy()
    moved[4] /= shrink
    truth = rk4_propagate(moved, z_ut, z_t, FALLBACK_MAX_STEP, *geometry.reconstruction_field().args)
    np.testing.assert_allclose(out[:4], truth[:4], rtol=0, atol=1e-9)
    assert out[4] == state[4]  # production q/p, f_qop = identity
    assert np.all(np.isfinite(noise)) and np.all(np.linalg.eigvalsh(noise[2:4, 2:4]) >= 0)
    # Jacobian against finite differences (q/p column through the ΔE rescaling)
    for j, h in ((0, 1e-3), (2, 1e-6), (4, 1e-10)):
        plus, minus = state.copy(), state.copy()
        plus[j] += h
        minus[j] -= h
        numeric = (_step(ext, plus, z_ut, z_t)[1] - _step(ext, minus, z_ut, z_t)[1]) / (2 * h)
        np.testing.assert_allclose(jac[:4, j], numeric[:4], rtol=2e-3, atol=1e-6 * np.max(np.abs(numeric[:4])))


@pytest.mark.parametrize("p", [1600.0, 2500.0, 8000.0])  # the soft range and above p_min
def test_above_p_min_the_table_is_used(setup, p):
    geometry, params, ext, z_ut, z_t, slot = setup
    state = _state_at_ut(geometry, p)
    status, out, _, _ = _step(ext, state, z_ut, z_t)
    assert status == TRANSPORT_OK
    shrink = 1.0 - ext.extrapolation[slot][0] * abs(state[4])
    moved = state.copy()
    moved[4] /= shrink
    meta, cells = params.ut_to_scifi.as_arrays()
    table = np.empty(5)
    assert ut_to_scifi_extrapolate(meta, cells, moved, table, np.empty((5, 5))) == TRANSPORT_OK
    np.testing.assert_array_equal(out[:4], table[:4])


def test_without_a_field_map_below_p_min_is_still_refused(setup):
    geometry, params, ext, z_ut, z_t, slot = setup
    bare = ext._replace(field_kind=-1)
    status = _step(bare, _state_at_ut(geometry, 1300.0), z_ut, z_t)[0]
    assert status == TRANSPORT_BELOW_P_MIN
