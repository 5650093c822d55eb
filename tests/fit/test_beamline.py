"""The beamline state: point of closest approach to the z axis, material noise added."""

import numpy as np
import pytest

from pkf.fit.beamline import beamline_states, straight_line_extrapolator
from pkf.geometry import load_geometry


def test_point_of_closest_approach_and_material_noise():
    geometry = load_geometry("lhcb-like")
    ext = straight_line_extrapolator(geometry)
    # a straight track through (1, -2, 30) with slopes (0.1, 0.05), state given at z = 275
    z0, tx, ty = 275.0, 0.1, 0.05
    x0, y0 = 1.0 + tx * (z0 - 30.0), -2.0 + ty * (z0 - 30.0)
    state = np.array([[x0, y0, tx, ty, 1 / 5000.0]])
    cov = np.diag([1e-4, 1e-4, 1e-8, 1e-8, 1e-12])[None]
    out_z, out_s, out_c = np.empty(1), np.empty((1, 5)), np.empty((1, 5, 5))
    beamline_states(ext, np.array([z0]), state, cov, out_z, out_s, out_c)
    # closest approach of the line to the z axis
    expected_z = z0 - (x0 * tx + y0 * ty) / (tx * tx + ty * ty)
    assert out_z[0] == pytest.approx(expected_z, abs=1e-9)
    assert out_s[0, 0] * tx + out_s[0, 1] * ty == pytest.approx(0.0, abs=1e-9)
    assert np.allclose(out_s[0, 2:], state[0, 2:])  # straight line, no energy loss
    # covariance: straight-line transport plus scattering in the VELO modules crossed
    dz = expected_z - z0
    f = np.eye(5)
    f[0, 2] = f[1, 3] = dz
    transported = f @ cov[0] @ f.T
    assert np.all(np.diag(out_c[0])[:4] >= np.diag(transported)[:4] - 1e-15)
    crossed = (geometry.planes.z > expected_z) & (geometry.planes.z <= z0)
    assert crossed.any()
    assert out_c[0, 2, 2] > transported[2, 2] * 1.01  # material between z_pca and the first hit


def test_straight_line_step_is_the_reference_step_in_zero_field():
    """The beamline's straight-line transport is the RK4 reference step in zero field to the
    bit: state, Jacobian and material noise, up- and downstream through the VELO planes
    (in and out of their active areas), including multi-step segments."""
    from pkf.fit.beamline import straight_line_step
    from pkf.fit.reference import reference_step

    geometry = load_geometry("lhcb-like")
    rng = np.random.default_rng(7)
    scattered = 0
    for max_step in (1e6, 37.0):
        ext = straight_line_extrapolator(geometry)._replace(max_step=max_step)
        for _ in range(200):
            state = np.array([rng.normal(0, 15), rng.normal(0, 15), rng.normal(0, 0.2), rng.normal(0, 0.2),
                              rng.choice([-1, 1]) / rng.uniform(1500, 1e5)])
            z_from, z_to = rng.uniform(-300, 800, size=2)
            out = [(np.empty(5), np.empty((5, 5)), np.empty((5, 5))) for _ in range(2)]
            status = [step(ext, state, z_from, z_to, *o, np.empty((6, 5, 5)))
                      for step, o in zip((reference_step, straight_line_step), out)]
            assert status[0] == status[1]
            for a, b in zip(*out):
                assert np.array_equal(a, b), (state, z_from, z_to)
            scattered += out[0][2][2, 2] > 0.0
    assert scattered > 100  # most cases cross material in an active area
