"""UT→SciFi parametrization (pkf.params.ut_to_scifi): paper eqs. 21–23 against RK4 through the field map."""

import base64
import json
import logging
import math
import sys
import time

from pathlib import Path

import numba as nb
import numpy as np
import pytest

from pkf.geometry import load_geometry
from pkf.geometry.field import uniform_field
from pkf.params.ut_to_scifi import (
    DEFAULT_DEGREES,
    MAX_EXTRAPOLATION_CELLS,
    META_SIZE,
    STATUS_BELOW_P_MIN,
    STATUS_INVALID_TABLE,
    UTSciFiTable,
    bend_integral,
    chebyshev_qop_nodes,
    interpolate_grid,
    tabulate_ut_to_scifi,
    ut_to_scifi_extrapolate,
    ut_to_scifi_extrapolate_many,
)
from pkf.physics.transport import C_LIGHT, rk4_propagate, rk4_propagate_many

sys.path.insert(0, str(Path(__file__).resolve().parent))
from ut_to_scifi_helpers import finite_difference_jacobian, near_cell_boundary  # noqa: E402

log = logging.getLogger(__name__)

Z_UT = 2642.5  # last UT layer
Z_T = 7826.0  # first SciFi layer
TRUTH_STEP = 5.0  # mm; RK4 through the map converges to < 0.5 µm at this step
P_BINS = ((3e3, 5e3), (5e3, 10e3), (10e3, 30e3), (30e3, 100e3))

# Upper limits on the RMS of (parametrized − RK4) per momentum bin, ≈ 1.4× the values
# measured with the default 50×50 table (see the module log); units µm, µm, µrad, µrad.
RMS_LIMITS = {
    "x": (140.0, 65.0, 30.0, 10.0),
    "y": (40.0, 17.0, 7.0, 2.0),
    "tx": (70.0, 30.0, 12.0, 4.0),
    "ty": (40.0, 12.0, 6.0, 1.5),
}
UNITS = {"x": 1e3, "y": 1e3, "tx": 1e6, "ty": 1e6}


@pytest.fixture(scope="module")
def field_map():
    return load_geometry("lhcb-like").reconstruction_field()


@pytest.fixture(scope="module")
def table(field_map):
    """The full-size default table (50×50 grid, 20 q/p nodes, paper degrees)."""
    start = time.perf_counter()
    tab = tabulate_ut_to_scifi(field_map)
    log.info("full UT→SciFi tabulation (incl. JIT on a cold cache): %.1f s; max fit residuals %s",
             time.perf_counter() - start, tab.tabulation["max_fit_residual"])
    return tab


@pytest.fixture(scope="module")
def arrays(table):
    return table.as_arrays()


def extrapolate(meta, cells, states):
    out = np.empty_like(states)
    jac = np.empty((states.shape[0], 5, 5))
    status = np.empty(states.shape[0], dtype=np.int64)
    ut_to_scifi_extrapolate_many(meta, cells, states, out, jac, status)
    return out, jac, status


def luminous_region_tracks(field, n, seed):
    """States at the last UT layer of noiseless tracks from the luminous region.

    Vertex x, y ~ N(0, 40 µm), z ~ N(0, 50 mm); 2 < η < 5, uniform φ; p log-uniform in
    3–100 GeV; both charges. Straight line from the vertex to z = 0 (the VELO field is a
    few mT), RK4 through the map to the UT. Keeps |x/z|, |y/z| < 0.25 at the UT.
    """
    rng = np.random.default_rng(seed)
    eta = rng.uniform(2.0, 5.0, n)
    phi = rng.uniform(-math.pi, math.pi, n)
    p = np.exp(rng.uniform(math.log(3e3), math.log(100e3), n))
    q = rng.choice([-1.0, 1.0], n)
    tan_theta = np.tan(2.0 * np.arctan(np.exp(-eta)))
    tx, ty = tan_theta * np.cos(phi), tan_theta * np.sin(phi)
    zv = rng.normal(0.0, 50.0, n)
    start = np.column_stack([
        rng.normal(0.0, 0.04, n) - tx * zv, rng.normal(0.0, 0.04, n) - ty * zv, tx, ty, q / p,
    ])
    ut = rk4_propagate_many(start, 0.0, Z_UT, TRUTH_STEP, *field.args)
    keep = (np.abs(ut[:, 0] / Z_UT) < 0.25) & (np.abs(ut[:, 1] / Z_UT) < 0.25)
    return ut[keep], p[keep], rng


def accuracy_table(diff, p):
    """{output: [(rms, p99) per P_BINS bin] + [(rms, p99) overall]} in µm / µrad."""
    table = {}
    for k, name in enumerate(("x", "y", "tx", "ty")):
        rows = []
        for lo, hi in P_BINS + ((3e3, 100e3),):
            m = (p >= lo) & (p < hi)
            d = np.abs(diff[m, k]) * UNITS[name]
            rows.append((float(np.sqrt(np.mean(d * d))), float(np.percentile(d, 99))))
        table[name] = rows
    return table


def log_accuracy(label, table, counts):
    log.info("UT→SciFi accuracy vs RK4 (%s), RMS / 99%% [µm, µm, µrad, µrad]:", label)
    for b, (lo, hi) in enumerate(P_BINS + ((3e3, 100e3),)):
        log.info("  %3.0f–%3.0f GeV (n=%5d): %s", lo / 1e3, hi / 1e3, counts[b],
                 "  ".join(f"{n} {table[n][b][0]:7.2f}/{table[n][b][1]:7.2f}" for n in table))


def check_accuracy(field_map, arrays, ut, p, label):
    meta, cells = arrays
    truth = rk4_propagate_many(ut, Z_UT, Z_T, TRUTH_STEP, *field_map.args)
    out, jac, status = extrapolate(meta, cells, ut)
    assert np.all(status == 0)
    assert np.all(np.isfinite(out)) and np.all(np.isfinite(jac))
    assert np.array_equal(out[:, 4], ut[:, 4])  # f_qop = identity
    table = accuracy_table(out - truth, p)
    counts = [int(np.sum((p >= lo) & (p < hi))) for lo, hi in P_BINS + ((3e3, 100e3),)]
    log_accuracy(label, table, counts)
    assert min(counts[:4]) > 500
    assert table["x"][-1][0] <= 50.0, f"overall x RMS {table['x'][-1][0]:.1f} µm > 50 µm"
    for name, limits in RMS_LIMITS.items():
        for b, limit in enumerate(limits):
            assert table[name][b][0] <= limit, (name, P_BINS[b], table[name][b], limit)


def test_accuracy_for_tracks_from_the_luminous_region(field_map, arrays):
    ut, p, _ = luminous_region_tracks(field_map, 16000, seed=11)
    check_accuracy(field_map, arrays, ut, p, "tracks from the luminous region")


def test_accuracy_for_scattered_tracks(field_map, arrays):
    """Slopes off the ideal direction by Highland scattering in x/X0 = 0.37 (VELO, RICH1, UT):
    θ0 ≈ 2.6 mrad at 3 GeV."""
    ut, p, rng = luminous_region_tracks(field_map, 16000, seed=12)
    theta0 = 13.6 / p * math.sqrt(0.37) * (1.0 + 0.038 * math.log(0.37))
    ut[:, 2] += rng.normal(size=p.size) * theta0
    ut[:, 3] += rng.normal(size=p.size) * theta0
    check_accuracy(field_map, arrays, ut, p, "scattered tracks, Highland x/X0 = 0.37")


def test_grid_points_on_the_ideal_direction_between_q_over_p_nodes(field_map, table, arrays):
    """At grid points only the q/p polynomial fit and the RK4 step of the tabulation err."""
    meta, cells = arrays
    rng = np.random.default_rng(5)
    n = 400
    sx = table.slopes_x()[rng.integers(5, 45, n)]
    sy = table.slopes_y()[rng.integers(5, 45, n)]
    qop = rng.choice([-1.0, 1.0], n) * rng.uniform(0.05, 1.0, n) / table.p_min
    beta_x, beta_y = table.bend_at(sx, sy)
    states = np.column_stack([sx * Z_UT, sy * Z_UT, sx + beta_x * qop, sy + beta_y * qop, qop])
    truth = rk4_propagate_many(states, Z_UT, Z_T, TRUTH_STEP, *field_map.args)
    out, _, status = extrapolate(meta, cells, states)
    assert np.all(status == 0)
    diff = out - truth
    assert np.sqrt(np.mean(diff[:, 0] ** 2)) < 0.010  # mm
    assert np.max(np.abs(diff[:, 0])) < 0.040
    assert np.max(np.abs(diff[:, 1])) < 0.020
    assert np.max(np.abs(diff[:, 2])) < 2e-5
    assert np.max(np.abs(diff[:, 3])) < 1e-5


def test_bend_is_the_slope_offset_of_a_track_from_the_origin(field_map, table):
    # Uniform 1 T along y: bend = ∫_0^z −κ·z'/z dz' = −κ·z/2.
    assert bend_integral(uniform_field(0.0, 1.0, 0.0), Z_UT) == pytest.approx(-C_LIGHT * Z_UT / 2, rel=1e-12)
    # the fitted quadratic ideal direction (LHCb's): on the axis ≈ the field integral ...
    assert table.bend == pytest.approx(bend_integral(field_map, Z_UT), rel=1e-2)
    assert 30.0 < table.bend < 45.0  # MeV for the lhcb-like map
    # ... and off axis the slope offset of particles from the origin to ≤ 0.7 MeV, where a
    # constant bend is up to 27 MeV off (12 MeV at |y/z| = 0.25: the fringe field)
    rng = np.random.default_rng(21)
    worst_model, worst_constant = 0.0, 0.0
    for _ in range(40):
        sx, sy = rng.uniform(-0.25, 0.25, 2)
        qop = rng.choice([-1.0, 1.0]) / rng.uniform(1500.0, 20000.0)
        t0 = np.array([0.0, 0.0, sx, sy, qop])
        for _ in range(6):  # aim at (sx, sy) on the UT layer
            ut = rk4_propagate(t0, 0.0, Z_UT, 5.0, *field_map.args)
            t0[2] += sx - ut[0] / Z_UT
            t0[3] += sy - ut[1] / Z_UT
        ut = rk4_propagate(t0, 0.0, Z_UT, 5.0, *field_map.args)
        beta_x, beta_y = table.bend_at(sx, sy)
        worst_model = max(worst_model, abs((ut[2] - ut[0] / Z_UT) / qop - beta_x), abs((ut[3] - ut[1] / Z_UT) / qop - beta_y))
        worst_constant = max(worst_constant, abs((ut[2] - ut[0] / Z_UT) / qop - table.bend))
    assert worst_model < 1.0, worst_model
    assert worst_constant > 10.0


def test_straight_line_at_zero_q_over_p(arrays):
    meta, cells = arrays
    state = np.array([300.0, -200.0, 0.12, -0.07, 0.0])
    out, jac = np.empty(5), np.empty((5, 5))
    assert ut_to_scifi_extrapolate(meta, cells, state, out, jac) == 0
    dz = Z_T - Z_UT
    np.testing.assert_array_equal(out, [300.0 + 0.12 * dz, -200.0 - 0.07 * dz, 0.12, -0.07, 0.0])
    np.testing.assert_array_equal(jac[:4, :4], [[1, 0, dz, 0], [0, 1, 0, dz], [0, 0, 1, 0], [0, 0, 0, 1]])
    assert jac[0, 4] != 0.0  # the deflection's q/p derivative stays


@pytest.mark.parametrize("region", ["inside", "edge-and-outside", "below-p-min"])
def test_jacobian_matches_finite_differences(table, arrays, region):
    meta, cells = arrays
    rng = np.random.default_rng({"inside": 1, "edge-and-outside": 2, "below-p-min": 3}[region])
    n = 200
    if region == "inside":
        s = rng.uniform(-0.24, 0.24, (n, 2))
        p = rng.uniform(3000.0, 100000.0, n)
    elif region == "edge-and-outside":
        s = rng.uniform(0.23, 0.33, (n, 2)) * rng.choice([-1.0, 1.0], (n, 2))
        p = rng.uniform(3000.0, 100000.0, n)
    else:
        s = rng.uniform(-0.24, 0.24, (n, 2))
        p = rng.uniform(500.0, 2990.0, n)
    qop = rng.choice([-1.0, 1.0], n) / p
    states = np.column_stack([
        s[:, 0] * Z_UT, s[:, 1] * Z_UT,
        s[:, 0] + table.bend_at(s[:, 0], s[:, 1])[0] * qop + rng.normal(0, 3e-3, n),
        s[:, 1] + table.bend_at(s[:, 0], s[:, 1])[1] * qop + rng.normal(0, 3e-3, n), qop,
    ])
    states = states[~near_cell_boundary(states, meta)]
    # positions step 3e-4 mm: at 1e-4 mm the round-off of x_out (~1 m) in the central difference
    # is ~2e-5 of the small ∂x/∂y (−4.5e-5) on some CPUs (1.8e-5 measured; 2.7e-6 at 3e-4 mm)
    steps = np.array([3e-4, 3e-4, 1e-7, 1e-7, 1e-10])
    worst = 0.0
    for state in states:
        out, jac = np.empty(5), np.empty((5, 5))
        status = ut_to_scifi_extrapolate(meta, cells, state, out, jac)
        assert status == (STATUS_BELOW_P_MIN if region == "below-p-min" else 0)
        fd = finite_difference_jacobian(meta, cells, state, steps)
        scale = np.abs(jac) + 1e-6 * np.abs(jac).max(axis=0)  # column scale for the ~0 elements
        worst = max(worst, float(np.max(np.abs(fd - jac) / scale)))
        np.testing.assert_array_equal(jac[4], [0, 0, 0, 0, 1])
    assert states.shape[0] > 150
    assert worst < 1e-5, worst


def test_below_p_min_returns_status_4_with_finite_output(table, arrays):
    meta, cells = arrays
    base = np.array([400.0, 250.0, 400.0 / Z_UT, 250.0 / Z_UT, 0.0])
    out, jac = np.empty(5), np.empty((5, 5))
    for qop in (1 / 2999.0, -1 / 2999.0, 1 / 1000.0, -1 / 300.0, 1e-2, -1.0, 1e3):
        state = base.copy()
        state[4] = qop
        out[:] = np.nan
        jac[:] = np.nan
        assert ut_to_scifi_extrapolate(meta, cells, state, out, jac) == STATUS_BELOW_P_MIN
        assert np.all(np.isfinite(out)) and np.all(np.isfinite(jac))
        assert out[4] == qop
    for qop in (1 / 3000.0, -1 / 3000.0, 1 / 3001.0):
        state = base.copy()
        state[4] = qop
        assert ut_to_scifi_extrapolate(meta, cells, state, out, jac) == 0
    # continuous at |w| = 1, and the linear continuation bends a softer track further
    at, beyond, further = np.empty(5), np.empty(5), np.empty(5)
    for sign in (1.0, -1.0):
        for q, o in ((1 / 3000.0, at), (1 / 2999.999, beyond), (1 / 2000.0, further)):
            state = base.copy()
            state[4] = sign * q
            ut_to_scifi_extrapolate(meta, cells, state, o, jac)
        assert np.allclose(beyond[:4], at[:4], rtol=0, atol=1e-3)
        assert abs(further[0] - base[0] - base[2] * (Z_T - Z_UT)) > abs(at[0] - base[0] - base[2] * (Z_T - Z_UT))


def test_nan_input_does_not_crash(arrays):
    meta, cells = arrays
    out, jac = np.empty(5), np.empty((5, 5))
    for k in range(5):
        state = np.array([100.0, 100.0, 0.04, 0.04, 1e-4])
        state[k] = np.nan
        ut_to_scifi_extrapolate(meta, cells, state, out, jac)
        assert np.isnan(out[:4]).any()


def synthetic_table(values_fn, nx=9, ny=7, degrees=((1, 0), (1, 0), (1, 0), (1, 0))):
    """A table whose coefficient A_1 of every output is values_fn(x/z, y/z) (others 0)."""
    sx = np.linspace(-0.25, 0.25, nx)
    sy = np.linspace(-0.2, 0.2, ny)
    gx, gy = np.meshgrid(sx, sy, indexing="ij")
    coef = np.zeros((4, nx, ny, max(k1 + 2 * k2 for k1, k2 in degrees)))
    for u in range(4):
        coef[u, :, :, 0] = values_fn(gx, gy) * (u + 1)
    return UTSciFiTable(
        z_from=Z_UT, z_to=Z_T, p_min=3000.0, bend=0.0, slope_x0=sx[0], slope_dx=sx[1] - sx[0],
        slope_y0=sy[0], slope_dy=sy[1] - sy[0], degrees=degrees, coef=coef,
    )


def test_interpolation_reproduces_quadratics_exactly():
    rng = np.random.default_rng(7)
    for _ in range(5):
        a = rng.normal(size=6)

        def quad(x, y, a=a):
            return a[0] + a[1] * x + a[2] * y + a[3] * x * x + a[4] * x * y + a[5] * y * y

        tab = synthetic_table(quad)
        meta, cells = tab.as_arrays()
        # inside the grid, at the edges and extrapolated up to the clamp
        for sx, sy in rng.uniform([-0.3, -0.25], [0.3, 0.25], (200, 2)):
            f, fx, fy = interpolate_grid(cells[:, :, 0, 0], tab.slope_x0, tab.slope_dx, tab.slope_y0, tab.slope_dy, sx, sy)
            assert f == pytest.approx(quad(sx, sy), abs=1e-12)
            assert fx == pytest.approx(a[1] + 2 * a[3] * sx + a[4] * sy, abs=1e-10)
            assert fy == pytest.approx(a[2] + a[4] * sx + 2 * a[5] * sy, abs=1e-10)
            # through the extrapolator: w = 1, ideal direction, so out − straight line = A_1
            state = np.array([sx * Z_UT, sy * Z_UT, sx, sy, 1.0 / 3000.0])
            out, jac = np.empty(5), np.empty((5, 5))
            assert ut_to_scifi_extrapolate(meta, cells, state, out, jac) == 0
            dz = Z_T - Z_UT
            straight = np.array([state[0] + sx * dz, state[1] + sy * dz, sx, sy])
            np.testing.assert_allclose(out[:4] - straight, quad(sx, sy) * np.arange(1, 5), atol=1e-9)
            np.testing.assert_allclose(jac[0, 0], 1.0 + (a[1] + 2 * a[3] * sx + a[4] * sy) / Z_UT, rtol=1e-9)


def test_interpolation_reproduces_grid_values_and_is_not_bilinear():
    rng = np.random.default_rng(8)
    values = rng.normal(size=(9, 7))
    tab = synthetic_table(lambda x, y: 0.0 * x)
    tab.coef[0, :, :, 0] = values
    for i in range(9):
        for j in range(7):
            sx, sy = tab.slope_x0 + i * tab.slope_dx, tab.slope_y0 + j * tab.slope_dy
            f, _, _ = interpolate_grid(tab.coef[0, :, :, 0], tab.slope_x0, tab.slope_dx, tab.slope_y0, tab.slope_dy, sx, sy)
            assert f == pytest.approx(values[i, j], abs=1e-12)
    # x² is reproduced between grid points, where a bilinear interpolation would be convex-biased
    tab = synthetic_table(lambda x, y: x * x)
    mid = tab.slope_x0 + 3.5 * tab.slope_dx
    f, _, _ = interpolate_grid(tab.coef[0, :, :, 0], tab.slope_x0, tab.slope_dx, tab.slope_y0, tab.slope_dy, mid, 0.0)
    assert f == pytest.approx(mid * mid, abs=1e-14)


def test_outside_the_grid_coefficients_freeze_beyond_the_clamp():
    tab = synthetic_table(lambda x, y: x * x + y)
    meta, cells = tab.as_arrays()
    edge = 0.25 + MAX_EXTRAPOLATION_CELLS * tab.slope_dx
    f_edge, fx_edge, _ = interpolate_grid(cells[:, :, 0, 0], tab.slope_x0, tab.slope_dx, tab.slope_y0, tab.slope_dy, edge, 0.0)
    assert f_edge == pytest.approx(edge * edge, abs=1e-12) and fx_edge != 0.0
    for far in (edge + 0.01, 1.0, 50.0):
        f, fx, _ = interpolate_grid(cells[:, :, 0, 0], tab.slope_x0, tab.slope_dx, tab.slope_y0, tab.slope_dy, far, 0.0)
        assert f == pytest.approx(f_edge, abs=1e-12) and fx == 0.0


def test_many_equals_single(arrays):
    meta, cells = arrays
    rng = np.random.default_rng(9)
    states = np.column_stack([rng.uniform(-600, 600, 50), rng.uniform(-600, 600, 50), rng.uniform(-0.3, 0.3, 50),
                              rng.uniform(-0.3, 0.3, 50), rng.uniform(-1 / 2000, 1 / 2000, 50)])
    out, jac, status = extrapolate(meta, cells, states)
    for k in range(50):
        o, j = np.empty(5), np.empty((5, 5))
        assert ut_to_scifi_extrapolate(meta, cells, states[k], o, j) == status[k]
        np.testing.assert_array_equal(o, out[k])
        np.testing.assert_array_equal(j, jac[k])


def test_as_arrays_layout(table, arrays):
    meta, cells = arrays
    assert meta.shape == (META_SIZE,) and meta.dtype == np.float64
    assert list(meta[:10]) == [Z_UT, Z_T, 3000.0, -0.25, table.slope_dx, 50, -0.25, table.slope_dy, 50, table.bend]
    assert list(meta[10:18]) == [k for pair in DEFAULT_DEGREES for k in pair]
    assert list(meta[18:21]) == [table.bend_x2, table.bend_y2, table.bend_xy]
    assert meta[21] == 1.0 and meta[22] == 23 and not meta[23:].any()  # no soft range
    assert table.slope_dx == pytest.approx(0.5 / 49)
    # cell-major: cells[i, j, u] are output u's columns at grid point (i, j), the table's coef[u, i, j]
    assert cells.shape == (50, 50, 4, 23) and cells.flags.c_contiguous and cells.dtype == np.float64
    np.testing.assert_array_equal(cells, table.coef.transpose(1, 2, 0, 3))
    # y, ty use 7 + 2·5 = 17 columns; the padding is zero
    assert np.all(cells[:, :, 1, 17:] == 0.0) and np.all(cells[:, :, 3, 17:] == 0.0)
    assert np.all(np.isfinite(cells))
    assert table.tabulation["n_qop"] == 20 and table.tabulation["qop_nodes"] == "chebyshev-first-kind"


def test_json_round_trip_is_exact_and_compact(table):
    text = json.dumps(table.to_json_dict())
    data = json.loads(text)
    stored = sum(len(base64.b64decode(v)) // 8 for v in data["coefficients"].values())
    assert stored == 50 * 50 * 80  # LHCb: 80 numbers per cell
    back = UTSciFiTable.from_json_dict(data)
    np.testing.assert_array_equal(back.coef, table.coef)
    for a, b in zip(back.as_arrays()[0], table.as_arrays()[0]):
        assert a == b
    assert back.degrees == table.degrees and back.tabulation == json.loads(json.dumps(table.tabulation))
    bad = json.loads(text)
    bad["coefficients"]["y"] = base64.b64encode(base64.b64decode(bad["coefficients"]["y"])[:-8]).decode()
    with pytest.raises(ValueError):
        UTSciFiTable.from_json_dict(bad)
    bad = json.loads(text)
    bad["format"] = "something else"
    with pytest.raises(ValueError):
        UTSciFiTable.from_json_dict(bad)
    bad = json.loads(text)
    del bad["grid"]
    with pytest.raises(KeyError):
        UTSciFiTable.from_json_dict(bad)


def test_invalid_table_is_reported_not_crashed():
    out, jac = np.empty(5), np.empty((5, 5))
    state = np.array([1.0, 2.0, 0.1, 0.2, 1e-4])
    assert ut_to_scifi_extrapolate(np.zeros(16), np.zeros((4, 1, 1, 1)), state, out, jac) == STATUS_INVALID_TABLE
    np.testing.assert_array_equal(out, state)
    np.testing.assert_array_equal(jac, np.eye(5))


def test_chebyshev_nodes_avoid_zero_and_fill_the_range():
    q = chebyshev_qop_nodes(20, 3000.0)
    assert q.size == 20 and np.all(np.diff(q) > 0)
    assert np.all(np.abs(q) * 3000.0 < 1.0) and np.min(np.abs(q)) > 0
    np.testing.assert_allclose(q, -q[::-1], atol=1e-18)


def test_small_table_in_a_uniform_field_matches_rk4():
    """A coarse 11×11 table in a uniform 0.3 T field, where the coefficients are smooth in
    (x/z, y/z): only the q/p fit, the interpolation and the δt linearization err, and
    they are at the µm level (in the field map the map's own trilinear ripple dominates)."""
    field = uniform_field(0.0, 0.3, 0.0)
    tab = tabulate_ut_to_scifi(field, nx=11, ny=11, n_qop=20, max_step=50.0)
    meta, cells = tab.as_arrays()
    # the fitted ideal direction: −κ·B·z/2 on the axis, to the path-length factors off it
    assert tab.bend == pytest.approx(-C_LIGHT * 0.3 * Z_UT / 2, rel=2e-3)
    # off the axis, to first order in the deflection, a particle from the origin with slopes
    # (a, b) has tx − x/z = bend·N·(1 + a²) and ty − y/z = bend·N·a·b (N = √(1 + a² + b²)):
    # βx ≈ bend·(1 + 1.5·a² + 0.5·b²), βy ≈ bend·a·b (fitted: 1.53, 0.499, 1.04 × bend)
    assert tab.bend_x2 == pytest.approx(1.5 * tab.bend, rel=0.05)
    assert tab.bend_y2 == pytest.approx(0.5 * tab.bend, rel=0.05)
    assert tab.bend_xy == pytest.approx(tab.bend, rel=0.06)
    rng = np.random.default_rng(4)
    n = 300
    s = rng.uniform(-0.2, 0.2, (n, 2))
    qop = rng.choice([-1.0, 1.0], n) / rng.uniform(3000.0, 100000.0, n)
    beta_x, beta_y = tab.bend_at(s[:, 0], s[:, 1])
    states = np.column_stack([s[:, 0] * Z_UT, s[:, 1] * Z_UT, s[:, 0] + beta_x * qop + rng.normal(0, 2e-3, n),
                              s[:, 1] + beta_y * qop + rng.normal(0, 2e-3, n), qop])
    truth = rk4_propagate_many(states, Z_UT, Z_T, 10.0, *field.args)
    out, _, status = extrapolate(meta, cells, states)
    assert np.all(status == 0)
    diff = out - truth
    assert np.sqrt(np.mean(diff[:, 0] ** 2)) < 0.003  # mm
    # worst of 300 (x, y [mm], tx, ty): 0.022, 0.011, 1.1e-5, 5.3e-6 with the quadratic ideal
    # direction, 0.016, 0.009, 8.8e-6, 4.4e-6 with the constant bend (RMS x 1.7 against 1.3 µm);
    # in the field map the quadratic one is the better: 3–5 GeV 41 → 37 µm RMS
    assert np.max(np.abs(diff[:, 0])) < 0.025
    assert np.max(np.abs(diff[:, 1])) < 0.013
    assert np.max(np.abs(diff[:, 2])) < 1.3e-5
    assert np.max(np.abs(diff[:, 3])) < 6e-6


def test_six_columns_gives_the_numbers_of_six_per_column():
    """The SIMD interpolation of a cell's columns (`_six_columns`, the evaluation's and the
    localisation's) is per column the same products and sums as `_six`: equal bit for bit."""
    from pkf.params.ut_to_scifi import _six, _six_columns, interpolation_weights

    @nb.njit
    def both(cells, u, i, j, xi, psi, n):
        ex, ey, w, w_xi, w_psi = interpolation_weights(xi, psi)
        fast = np.zeros((3, n))
        _six_columns(cells, u, i, j, ex, ey, n, w, w_xi, w_psi, fast[0], fast[1], fast[2])
        slow = np.zeros((3, n))
        for c in range(n):
            slow[0, c] = _six(cells, u, i, j, ex, ey, c, w)
            slow[1, c] = _six(cells, u, i, j, ex, ey, c, w_xi)
            slow[2, c] = _six(cells, u, i, j, ex, ey, c, w_psi)
        return fast, slow

    rng = np.random.default_rng(11)
    cells = np.ascontiguousarray(rng.normal(size=(6, 5, 4, 29)) * 10.0 ** rng.integers(-8, 3, size=(6, 5, 4, 29)))
    for _ in range(50):
        u, i, j = rng.integers(0, 4), rng.integers(1, 5), rng.integers(1, 4)
        xi, psi = rng.uniform(-1.5, 1.5, 2)
        fast, slow = both(cells, u, i, j, xi, psi, rng.integers(1, 30))
        np.testing.assert_array_equal(fast, slow)


def test_degrees_beyond_the_evaluation_buffer_are_refused():
    with pytest.raises(ValueError, match="at most"):
        synthetic_table(lambda x, y: x, degrees=((41, 12), (1, 0), (1, 0), (1, 0)))  # 65 columns
