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
