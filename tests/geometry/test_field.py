"""The analytic dipole (DESIGN §3.1) and its field map."""

import numpy as np
import pytest

from pkf.geometry import build_field_map, dipole_field, load_geometry, uniform_field


@pytest.fixture(scope="module")
def dipole():
    return dipole_field()


def test_on_axis_integral_is_4_1_tesla_metre(dipole):
    z = np.linspace(-3000.0, 14000.0, 170001)
    by = dipole.evaluate(0 * z, 0 * z, z)[:, 1]
    integral = np.trapezoid(by, z) / 1000.0  # T·m
    assert integral == pytest.approx(-4.12, abs=0.05)


def test_field_values_match_the_design_numbers(dipole):
    b = dipole.evaluate([0, 0, 0], [0, 0, 0], [0.0, 2500.0, 7826.0])
    assert abs(b[0, 1]) < 5e-3  # a few mT in the VELO
    assert 0.15 < abs(b[1, 1]) < 0.35  # about 0.24 T in the UT
    assert abs(b[2, 1]) == pytest.approx(0.13, abs=0.01)  # first SciFi layer
    assert np.all(b[:, [0, 2]] == 0.0)  # on axis the field is along y


def test_field_is_curl_free(dipole):
    rng = np.random.default_rng(1)
    pts = rng.uniform([-2000, -1500, 1000], [2000, 1500, 9000], size=(200, 3))
    h = 0.5

    def grad(axis):
        d = np.zeros(3)
        d[axis] = h
        plus = dipole.evaluate(*(pts + d).T)
        minus = dipole.evaluate(*(pts - d).T)
        return (plus - minus) / (2 * h)  # rows: point, columns: dB_i/d(axis)

    gx, gy, gz = grad(0), grad(1), grad(2)
    curl = np.stack([gy[:, 2] - gz[:, 1], gz[:, 0] - gx[:, 2], gx[:, 1] - gy[:, 0]], axis=1)
    scale = np.max(np.abs(np.stack([gx, gy, gz])))  # typical gradient, T/mm
    assert np.max(np.abs(curl)) < 1e-6 * max(scale, 1e-6) + 1e-9
    # and it is a real 3-D field: the gradients are far from zero
    assert scale > 1e-4


def test_off_axis_behaviour(dipole):
    # |B_y| grows towards the yoke (large |y|) and falls with |x| (DESIGN §3.1)
    b = dipole.evaluate([0, 0, 1500], [0, 1000, 0], [5000, 5000, 5000])
    assert abs(b[1, 1]) > abs(b[0, 1]) > abs(b[2, 1])


def test_field_map_agrees_with_analytic_field(dipole, tmp_path):
    fmap = build_field_map(dipole, cache_dir=tmp_path)
    rng = np.random.default_rng(2)
    pts = rng.uniform([-1500, -1000, -300], [1500, 1000, 9500], size=(5000, 3))
    diff = fmap.evaluate(*pts.T) - dipole.evaluate(*pts.T)
    assert np.max(np.abs(diff)) < 0.01  # T, trilinear with 100 mm spacing
    assert np.sqrt(np.mean(diff**2)) < 1e-3
    # exact on the grid points
    grid_pts = np.array([[0.0, 0.0, 5000.0], [100.0, -200.0, 3000.0]])
    assert np.allclose(fmap.evaluate(*grid_pts.T), dipole.evaluate(*grid_pts.T), atol=1e-12)


def test_field_map_is_cached_on_disk(dipole, tmp_path):
    first = build_field_map(dipole, spacing=200.0, cache_dir=tmp_path)
    files = list(tmp_path.glob("fieldmap-*.npy"))
    assert len(files) == 1
    second = build_field_map(dipole, spacing=200.0, cache_dir=tmp_path)
    assert np.array_equal(first.grid, second.grid)
    other = build_field_map(dipole_field(b0=1.03), spacing=200.0, cache_dir=tmp_path)
    assert len(list(tmp_path.glob("fieldmap-*.npy"))) == 2
    assert np.allclose(other.grid, -first.grid)


def test_uniform_field_and_polarity():
    f = uniform_field(0.0, 1.0, 0.0)
    assert np.allclose(f.evaluate([5, -100], [3, 40], [0, 900]), [[0, 1, 0], [0, 1, 0]])
    assert dipole_field(b0=1.03).content_hash() != dipole_field().content_hash()


def test_geometry_reconstruction_field_is_the_map():
    g = load_geometry("lhcb-like")
    assert g.reconstruction_field().kind == 2
    assert load_geometry("telescope").reconstruction_field().kind == 0


def test_map_gradient_is_the_exact_derivative_of_the_interpolation():
    """`map_field_and_gradient`: the field bitwise `field_at`'s; the x and y derivatives those
    of the trilinear interpolation: exact on a map linear in x and y (0 across the grid's
    edges, where the edge value is held), and on lhcb-like's map equal to 1 µm central
    differences away from cell boundaries."""
    import numba as nb

    from pkf.fit.reference import reference_extrapolator
    from pkf.geometry.field import FIELD_MAP, field_at, map_field_and_gradient

    @nb.njit
    def evaluate(params, grid, x, y, z):
        out = np.empty((x.size, 2, 9))
        s = 1e-3
        for i in range(x.size):
            r = map_field_and_gradient(params, grid, x[i], y[i], z[i])
            b = field_at(FIELD_MAP, params, grid, x[i], y[i], z[i])
            px = field_at(FIELD_MAP, params, grid, x[i] + s, y[i], z[i])
            mx = field_at(FIELD_MAP, params, grid, x[i] - s, y[i], z[i])
            py = field_at(FIELD_MAP, params, grid, x[i], y[i] + s, z[i])
            my = field_at(FIELD_MAP, params, grid, x[i], y[i] - s, z[i])
            for c in range(3):
                out[i, 1, c] = b[c]
                out[i, 1, 3 + c] = (px[c] - mx[c]) / (2 * s)
                out[i, 1, 6 + c] = (py[c] - my[c]) / (2 * s)
            for j in range(9):
                out[i, 0, j] = r[j]
        return out

    # a map linear in x and y: B = (0.1 + 0.002·x − 0.003·y, −0.5 + 0.001·y, 0.2·z/1000), 5×4×3 cells
    params = np.array([-100.0, -50.0, 0.0, 50.0, 40.0, 500.0, 5, 4, 3])
    gx, gy, gz = np.meshgrid(-100.0 + 50.0 * np.arange(5), -50.0 + 40.0 * np.arange(4), 500.0 * np.arange(3),
                             indexing="ij")
    grid = np.stack([0.1 + 0.002 * gx - 0.003 * gy, -0.5 + 0.001 * gy, 0.2 * gz / 1000.0], axis=-1)
    rng = np.random.default_rng(4)
    x, y, z = rng.uniform(-100, 100, 500), rng.uniform(-50, 70, 500), rng.uniform(0, 1000, 500)
    out = evaluate(params, grid, x, y, z)
    np.testing.assert_allclose(out[:, 0, 3:], np.tile([0.002, 0.0, 0.0, -0.003, 0.001, 0.0], (500, 1)), atol=1e-15)
    outside = evaluate(params, grid, np.array([150.0, 0.0]), np.array([0.0, -80.0]), np.array([100.0, 100.0]))
    assert outside[0, 0, 3:6].tolist() == [0.0] * 3 and outside[1, 0, 6:9].tolist() == [0.0] * 3

    ext = reference_extrapolator(load_geometry("lhcb-like"))
    p, g = ext.field_params, ext.field_grid
    n = 20000
    x, y, z = rng.uniform(-3000, 3000, n), rng.uniform(-2500, 2500, n), rng.uniform(0, 9500, n)
    out = evaluate(p, g, x, y, z)
    assert np.array_equal(out[:, 0, :3], out[:, 1, :3])
    fx, fy = (x - p[0]) / p[3], (y - p[1]) / p[4]
    away = (np.abs(fx - np.round(fx)) * p[3] > 2e-3) & (np.abs(fy - np.round(fy)) * p[4] > 2e-3)
    scale = np.abs(out[:, 1, 3:]).max()
    assert away.mean() > 0.99 and scale > 1e-4
    assert np.max(np.abs(out[away, 0, 3:] - out[away, 1, 3:])) < 1e-8 * scale
