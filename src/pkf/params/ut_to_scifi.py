"""UT→SciFi parametrized extrapolation: the tabulated q/p expansion of paper §4, eqs. 21–23.

Format and tuning: docs/parameters.md#the-utscifi-table. Units: mm, MeV, T.

The model (paper eq. 21). A state (x, y, tx, ty, qop) at the last UT layer z_from is
carried to z_to (the first SciFi layer) by

    f_x  = x  + tx·Δz + Σ_{k=1..K1} A^x_k(x,y)·w^k  + Σ_{k=1..K2} (B^x_k·δtx + C^x_k·δty)·w^k
    f_y  = y  + ty·Δz + (same with the y coefficients)
    f_tx = tx         + (same with the tx coefficients)
    f_ty = ty         + (same with the ty coefficients)
    f_qop = qop       (qop is the momentum at production, docs/physics.md#the-parametrized-fitter)

with Δz = z_to − z_from, w = qop·p_min (the paper's (q/p)^k up to the factor p_min^k,
which keeps every coefficient O(deflection)), and the deviations from the *ideal
direction* of a particle from the origin that hits the UT point (x, y, z_from):

    δtx = tx − t0x,  t0x = x/z_from + βx·qop,     δty = ty − t0y,  t0y = y/z_from + βy·qop.

The bend. A particle from the origin with initial slope tx(0) gets, to first order in the
deflection, tx(z) = tx(0) + qop·∫_0^z g dz' and x(z) = tx(0)·z + qop·∫_0^z (z − z')·g dz'
with g(z') = −κ·B_y(0, 0, z') (the equations of motion for small slopes). Eliminating tx(0),

    tx(z_UT) − x(z_UT)/z_UT = qop·∫_0^{z_UT} g(z')·z'/z_UT dz'  ⇒  bend = ∫_0^{z_UT} g·z'/z_UT dz'

[MeV] on the z axis (`bend_integral`: 38.215 MeV for the lhcb-like map). The paper takes
this constant (βx = bend, βy = 0). Off axis the slope offset of a particle from the origin
varies a lot: 40 MeV at x/z = 0.25, 12 MeV at |y/z| = 0.25 (the field falls towards the
yoke's fringe), and βy reaches ±15 MeV at the corners; with a constant bend a 1.5 GeV
particle from the origin has δtx up to 18 mrad, δty 10 mrad, and the first-order δt terms
of eq. 21 then err by millimetres. The table therefore uses LHCb's quadratic ideal
direction (their BENDX, BENDX_X2, BENDX_Y2, BENDY_XY),

    βx = bend + bend_x2·(x/z)² + bend_y2·(y/z)²,     βy = bend_xy·(x/z)·(y/z)     [MeV],

fitted by `fit_bend_model` to RK4 particles from the origin on a 21×21 grid of (x/z, y/z)
(lhcb-like: 38.38, 28.0, −432.7, 240.1 MeV; largest residual 0.7 MeV, i.e. 0.45 mrad at
1.5 GeV; the offset's non-linearity in q/p is ≤ 0.4 MeV at 1.5 GeV). Tables of older files
have bend_x2 = bend_y2 = bend_xy = 0: the paper's constant.

Tabulation (`tabulate_ut_to_scifi`). For every grid point (X/z, Y/z) of a regular
nx × ny grid on |x/z|, |y/z| ≤ slope_range at z_from and every q/p node, the ideal
state (X, Y, t0x, t0y, qop) is propagated with RK4 through the given field (the
reconstruction field map) *with its transport Jacobian*. The A part is the deviation of
the propagated state from the straight line along t0; the B and C parts are the exact
derivatives ∂/∂tx and ∂/∂ty of the same propagation minus the straight-line part
(the B_k, C_k multiply δtx, δty: they are the q/p-dependent part of ∂f/∂tx, ∂f/∂ty at
δt = 0). The q/p nodes are the n_qop Chebyshev nodes of the first kind on (−1, 1)·1/p_min,
w_i = cos((2i+1)π/(2·n_qop)): they avoid w = 0 for even n_qop (where every deviation is
zero), crowd towards ±1 where the deflection is most non-linear, and make the monomial
least-squares fit well conditioned (condition number of the degree-9 Vandermonde
matrix ≈ 1e3). Each set of deviations is fitted by least squares with a polynomial in w
without a constant term (at qop = 0 the straight line is exact). RK4 step: max_step
(default 20 mm: for 3–5 GeV the extrapolations of a 20 mm and a 10 mm table differ by
≈ 4 µm RMS in x; 100 mm steps would put single trajectories ≈ 20 µm off).

The soft range p_low ≤ p < p_min (1.5–3 GeV in the shipped table; LHCb's implementation
covers 1.5 GeV). One polynomial in w over ±1/1.5 GeV does not work: at 1.5 GeV the
trajectories from the grid's outer part bend out of the SciFi acceptance (55 % of the grid
points at |w| = 1 for |x|, |y| at z_to beyond 3200, 2400 mm), out of the map (41 % beyond
4000 mm) or curl in the fringe field (NaN for |y/z| ≳ 0.15), tx reaches 1–3, and the
deviations there are no polynomial: a degree-9 fit on all nodes is NaN, on the nodes inside
the map only it errs by 56 µm RMS at 30–100 GeV (2.8 µm today) and 160 µm at 3–100 GeV,
because the least squares spreads the outer nodes' misfit over small |w| (measured on a
50×100 grid, 30 nodes). So the eq. 21 polynomials keep their range |w| ≤ 1 — identical in
form and nodes to the paper's table — and beyond it, for 1 < |w| ≤ w_max = p_min/p_low,
each of them (A, B and C of each output) continues linearly from the edge plus a correction
per charge sign:

    P(w) = P(s) + P′(s)·e + Σ_{k=2..L} D^s_k(x, y)·e^k,     s = sign w, e = w − s,

which is continuous with its first derivative at |w| = 1 (3 GeV). The D^s_k are tabulated
on the same grid (interpolated with eqs. 22–23) by a weighted least-squares fit to the RK4
deviations at n_soft = 12 Chebyshev nodes of e in (0, w_max − 1) per sign: full weight for
the nodes whose trajectory ends inside |x| < 4000, |y| < 3200 mm at z_to (the map, and
≥ 800 mm beyond the SciFi acceptance, so that the six-point stencil of a track inside the
acceptance is fitted where that track is), weight 0.01 for the other finite ones (they
keep the polynomial a physical, monotonic continuation where the trajectories leave:
those need no accuracy, only harmlessness), 0 for curling ones. L = 8 for the A blocks and
6 for B, C (x RMS at 1.5–3 GeV, luminous-region tracks, with the curling nodes weighted
0.01: L = 6/4 164 µm, 8/6 77 µm, 10/8 128 µm). Weighting the curling nodes towards the
linear continuation (weights 1e-4–1e-2) tames the polynomials where no particle goes but makes
1.5–3 GeV states anywhere on the grid 6–10× worse (0.3 → 1.8–3.0 mm RMS, near the yoke,
|y/z| > 0.2), so it is not done: there the polynomials are finite but can be far off (> 20 m at z_to for 1.6 % of
uniformly spread 1.5–3 GeV states, all of them particles that curl in the magnet). The
soft coefficients are stored as float32 (< 1 µm at z_to). The full 50×100 tabulation with
20 + 2×12 nodes takes ≈ 150–240 s on one loaded core (220 000 RK4+Jacobian propagations).

Interpolation (paper eqs. 22–23). Every coefficient is interpolated at (x/z, y/z) from
six grid values: with (X, Y) the closest grid point, ξ = (x/z − X)/ΔX, ψ = (y/z − Y)/ΔY,
εx = sign ξ, εy = sign ψ (+1 at 0),

    F = F00 + Fd·ξψ + [(F+0 − F−0)ξ + (F0+ − F0−)ψ + (F+0 + F−0 − 2F00)ξ² + (F0+ + F0− − 2F00)ψ²]/2,
    Fd = εxεy(F00 + Fεxεy − Fεx0 − F0εy).

It reproduces any quadratic in (x/z, y/z) exactly and the grid values at grid points; it
is continuous across ξ = 0, ψ = 0 but not exactly across cell boundaries (jumps of
O(ΔX³·F‴), the price of the paper's six-point rule).

Edges and outside. The stencil centre is clamped to the points 1 … n−2, so near the edge
and outside the grid the edge cell's quadratic is used (|ξ| up to 1.5 inside the grid).
Beyond the grid the lookup point is clamped to at most MAX_EXTRAPOLATION_CELLS = 5 cells
outside (|x/z| ≤ 0.301 for the default grid, which covers the UT acceptance |x| ≤ 770 mm,
|x/z| ≤ 0.29); further out the coefficients are frozen (their x, y derivatives are
zero) and the error grows. Such states still return status 0.

Below the table's range. For |w| > w_max (p < p_low; w_max = 1 without a soft range)
`ut_to_scifi_extrapolate` returns STATUS_BELOW_P_MIN (4) and continues every polynomial
*linearly* from the edge, P(w) = P(w_c) + P′(w_c)·(w − w_c) with |w_c| = w_max: the result
is finite for any finite qop, continuous and differentiable in qop at the edge (the
Jacobian stays the exact derivative of what is returned), and the deflection, which is
dominated by its linear term, is still roughly right — unlike evaluating at the clamped
qop, which would give the deflection of a p_low track to any softer one. It is not
accurate: the caller must treat status 4 as a failure of the parametrization (the
parametrized fit then takes RK4 through the field map, `pkf.params.transport`).

Localised evaluation (the forward search, `pkf.seeding.forward_steps`). A q/p scan of one
track transports the same start point many times: `localize_ut_to_scifi` interpolates the
coefficients (eq. 21 and soft range) once at (x/z, y/z) of that point, with their x and y
derivatives, and `ut_to_scifi_extrapolate_localized` evaluates eq. 21 with them corrected
to first order in (x, y) — one interpolation per track instead of one per hypothesis (the
Jacobian columns x, y use the derivatives at the localisation point). Inside the covered
range it equals `ut_to_scifi_extrapolate` at the localisation point; beyond it each
polynomial is continued linearly (as above) or, for the search, quadratically with the
edge's second derivative (of the soft correction; of the polynomial for a table without
soft range — with the 3 GeV table this gave the 2.0–2.5 GeV x error at the first SciFi
layer ≈ 15 mm instead of ≈ 30 mm, measured by `tests/seeding/test_forward.py`).

Accuracy (tests/params/test_ut_to_scifi_soft.py, the shipped lhcb-like 50×100 table).
Against RK4 through the same map at the first SciFi layer, tracks from the luminous region
that cross the first and last SciFi layers inside the acceptance (x RMS, unscattered /
Highland-scattered in x/X0 = 0.37): 1.5–3 GeV 69/179 µm, 3–5 GeV 36/41 µm, 5–10 GeV
19/22 µm, 10–30 GeV 7.7/8.1 µm, 30–100 GeV 2.8/2.7 µm, 3–100 GeV 16.5/18.9 µm (the
3 GeV table with the constant bend on the same tracks: 41/48, 19.5/23, 7.8/8.2, 2.8/2.7,
18.2/21.4 µm; 1.5–3 GeV not covered). 1.5–3 GeV anywhere on the grid (random δt of 3 mrad),
inside the acceptance: 0.1–0.3 mm RMS, dominated by |y/z| > 0.2 near the yoke. At 3–5 GeV
the error is mostly the interpolation in y/z of a quantity that is *not smooth* in the
map, because the 100 mm trilinear map samples the field's y-curvature in 100 mm cells, so
the map trajectory ripples with y/z on about the grid step (the map itself differs from the
analytic field by ≈ 120 µm RMS in x at 3–5 GeV); a 50×100 grid has half the y/z step of the
paper's 50×50 (tests/params/test_ut_to_scifi.py checks the 50×50 table: x RMS ≈ 39 µm at
3–100 GeV, ≈ 86 µm at 3–5 GeV for all tracks with |x/z|, |y/z| < 0.25); in a smooth field an
11×11 grid is already accurate to a few µm above 3 GeV and to ≈ 27 µm at 1.5–3 GeV.
"""

from __future__ import annotations

import base64

import math
import time
from dataclasses import dataclass, field

import numba as nb
import numpy as np

from pkf.jit import NO_REFCOUNT, stack_array
from pkf.physics.transport import C_LIGHT, rk4_propagate, rk4_propagate_jacobian

#: Output order of the coefficient array: x, y, tx, ty.
OUTPUTS = ("x", "y", "tx", "ty")
#: Paper polynomial degrees (K1, K2) for x, y, tx, ty (§4: K1 = 9, K2 = 7 for x, tx; 7, 5 for y, ty).
DEFAULT_DEGREES = ((9, 7), (7, 5), (9, 7), (7, 5))
#: Default RK4 step limit [mm] of the tabulation.
DEFAULT_MAX_STEP = 20.0
#: Largest K1 + 2·K2 of an output (eq. 21 columns per cell): the evaluation interpolates a
#: cell's columns into a stack buffer of this size (paper: 9 + 2·7 = 23).
MAX_EQ21_COLUMNS = 64
#: How far outside the grid (in cells) the edge cell's quadratic is extrapolated.
MAX_EXTRAPOLATION_CELLS = 5.0
#: Soft range (p_low ≤ p < p_min): highest power L of e in the correction Σ_{k=2..L} D_k·e^k
#: of the A block and of the B, C blocks, for x, y, tx, ty.
DEFAULT_SOFT_DEGREES = ((8, 6), (8, 6), (8, 6), (8, 6))
#: Soft q/p nodes per charge sign (Chebyshev nodes of the first kind in e).
DEFAULT_N_SOFT = 12
#: A soft node is fitted with full weight if its trajectory reaches z_to with |x| < 4000 mm
#: and |y| < 3200 mm: inside the lhcb-like field map (|x|, |y| ≤ 4000 mm) and 800 mm beyond
#: the SciFi acceptance (3200 × 2400 mm), so that every grid point of the six-point stencil of
#: a track inside the acceptance is fitted where that track is.
DEFAULT_SOFT_WINDOW = (4000.0, 3200.0)
#: Relative weight of the soft nodes outside that window (finite trajectories that leave the
#: map or the acceptance): they keep the polynomial a physical, monotonic continuation
#: there (harmless for the pattern's q/p scans) without costing accuracy inside.
DEFAULT_SOFT_OUTSIDE_WEIGHT = 0.01

# Layout of the `meta` array of `UTSciFiTable.as_arrays()`.
META_Z_FROM = 0  # mm
META_Z_TO = 1  # mm
META_P_MIN = 2  # MeV
META_SLOPE_X0 = 3  # first grid value of x/z
META_SLOPE_DX = 4  # grid step in x/z
META_NX = 5
META_SLOPE_Y0 = 6
META_SLOPE_DY = 7
META_NY = 8
META_BEND = 9  # MeV: t0x = x/z + bend·qop
META_DEGREES = 10  # 8 entries: K1, K2 for x, y, tx, ty
META_BEND_X2 = 18  # MeV: t0x = x/z + (bend + bend_x2·(x/z)² + bend_y2·(y/z)²)·qop
META_BEND_Y2 = 19  # MeV
META_BEND_XY = 20  # MeV: t0y = y/z + bend_xy·(x/z)·(y/z)·qop
META_W_MAX = 21  # the table covers |w| ≤ w_max = p_min/p_low (1: no soft range)
META_SOFT_OFFSET = 22  # first coefficient column of the soft range
META_SOFT_DEGREES = 23  # 8 entries: L1, L2 for x, y, tx, ty (highest power of e; < 2: no correction)
META_SIZE = 31

STATUS_OK = 0
STATUS_INVALID_TABLE = 2  # same code as pkf.fit.extrapolator.STATUS_EXTRAPOLATION_FAILED
STATUS_BELOW_P_MIN = 4  # same code as pkf.fit.extrapolator.STATUS_BELOW_P_MIN

JSON_FORMAT = "pkf-ut-scifi-table/1"
#: Storage of the soft-range coefficients: float32 (the tabulation rounds them to it; the
#: rounding moves the first-SciFi-layer prediction by < 1 µm and halves their size in the
#: parameter file); the eq. 21 coefficients stay float64.
SOFT_DTYPE = "<f4"


# ----------------------------------------------------------------------------------------
# The table
# ----------------------------------------------------------------------------------------

def soft_columns(soft_degrees) -> list[int]:
    """Soft-range coefficient columns per output for one charge sign: (L1 − 1) + 2·(L2 − 1)
    (none for L < 2)."""
    return [max(l1 - 1, 0) + 2 * max(l2 - 1, 0) for l1, l2 in soft_degrees]


@dataclass(eq=False)
class UTSciFiTable:
    """Tabulated coefficients of paper eq. 21 on a regular (x/z, y/z) grid at z_from.

    z_from, z_to [mm]; p_min [MeV] (the polynomials are in w = qop·p_min, valid for |w| ≤ 1);
    bend, bend_x2, bend_y2, bend_xy [MeV]: the ideal direction
    t0x = x/z + (bend + bend_x2·(x/z)² + bend_y2·(y/z)²)·qop, t0y = y/z + bend_xy·(x/z)(y/z)·qop;
    grid: x/z = slope_x0 + i·slope_dx (i < nx), y/z = slope_y0 + j·slope_dy (j < ny);
    degrees: (K1, K2) for x, y, tx, ty;
    coef: float64 (4, nx, ny, n_coef), per output u the columns A_1..A_K1, B_1..B_K2,
    C_1..C_K2 (coefficients of w^k, units mm for x, y and 1 for tx, ty), zero-padded to
    n_coef = max(K1 + 2·K2);
    p_low [MeV] (≤ p_min; = p_min: no soft range): the soft range p_low ≤ p < p_min, where each
    polynomial is continued linearly from w = ±1 plus a correction Σ_{k=2..L} D±_k·e^k,
    e = w ∓ 1 (module docstring); soft_degrees: (L1, L2) for x, y, tx, ty; soft: float64
    (4, nx, ny, n_soft), per output the columns D+ (A: e²..e^L1, B, C: e²..e^L2), then D−
    likewise, zero-padded (`soft_columns`); None without a soft range;
    tabulation: provenance (q/p nodes, RK4 step, field hash, fit residuals, time).
    """

    z_from: float
    z_to: float
    p_min: float
    bend: float
    slope_x0: float
    slope_dx: float
    slope_y0: float
    slope_dy: float
    degrees: tuple
    coef: np.ndarray
    tabulation: dict = field(default_factory=dict)
    bend_x2: float = 0.0
    bend_y2: float = 0.0
    bend_xy: float = 0.0
    p_low: float | None = None
    soft_degrees: tuple = ((0, 0), (0, 0), (0, 0), (0, 0))
    soft: np.ndarray | None = None

    def __post_init__(self):
        self.degrees = tuple((int(k1), int(k2)) for k1, k2 in self.degrees)
        self.soft_degrees = tuple((int(l1), int(l2)) for l1, l2 in self.soft_degrees)
        self.coef = np.ascontiguousarray(self.coef, dtype=np.float64)
        if self.p_low is None:
            self.p_low = self.p_min
        self.p_low = float(self.p_low)
        if len(self.degrees) != 4 or any(k1 < 1 or k2 < 0 for k1, k2 in self.degrees):
            raise ValueError(f"degrees must be four (K1 >= 1, K2 >= 0) pairs, got {self.degrees}")
        ncoef = max(k1 + 2 * k2 for k1, k2 in self.degrees)
        if ncoef > MAX_EQ21_COLUMNS:
            raise ValueError(f"K1 + 2·K2 must be at most {MAX_EQ21_COLUMNS} per output, got {self.degrees}")
        if self.coef.ndim != 4 or self.coef.shape[0] != 4 or self.coef.shape[3] < ncoef:
            raise ValueError(f"coef must have shape (4, nx, ny, >= {ncoef}), got {self.coef.shape}")
        if self.coef.shape[1] < 3 or self.coef.shape[2] < 3:
            raise ValueError(f"the grid needs at least 3×3 points, got {self.coef.shape[1:3]}")
        if len(self.soft_degrees) != 4 or any(min(d) < 0 for d in self.soft_degrees):
            raise ValueError(f"soft_degrees must be four (L1, L2 >= 0) pairs, got {self.soft_degrees}")
        if not 0.0 < self.p_low <= self.p_min:
            raise ValueError(f"p_low must be in (0, p_min = {self.p_min}], got {self.p_low}")
        n_soft = 2 * max(soft_columns(self.soft_degrees))
        if self.p_low < self.p_min and n_soft > 0:
            if self.soft is None:
                raise ValueError("a table with p_low < p_min and soft degrees needs its soft coefficients")
            self.soft = np.ascontiguousarray(self.soft, dtype=np.float64)
            if self.soft.shape[:3] != self.coef.shape[:3] or self.soft.ndim != 4 or self.soft.shape[3] < n_soft:
                raise ValueError(f"soft must have shape (4, nx, ny, >= {n_soft}), got {self.soft.shape}")
            if not np.all(np.isfinite(self.soft)):
                raise ValueError("UT→SciFi table has non-finite values")
        else:
            self.soft = None
        scalars = (self.z_from, self.z_to, self.p_min, self.bend, self.slope_x0, self.slope_dx,
                   self.slope_y0, self.slope_dy, self.bend_x2, self.bend_y2, self.bend_xy)
        if not all(math.isfinite(v) for v in scalars) or not np.all(np.isfinite(self.coef)):
            raise ValueError("UT→SciFi table has non-finite values")
        if self.p_min <= 0.0 or self.slope_dx <= 0.0 or self.slope_dy <= 0.0 or self.z_from == 0.0:
            raise ValueError("UT→SciFi table needs p_min > 0, grid steps > 0 and z_from != 0")

    @property
    def nx(self) -> int:
        return self.coef.shape[1]

    @property
    def ny(self) -> int:
        return self.coef.shape[2]

    @property
    def covered_p_min(self) -> float:
        """[MeV] the lowest momentum the table covers: p_low with a soft range, else p_min."""
        return self.p_low if self.soft is not None else self.p_min

    def slopes_x(self) -> np.ndarray:
        """Grid values of x/z."""
        return self.slope_x0 + self.slope_dx * np.arange(self.nx)

    def slopes_y(self) -> np.ndarray:
        """Grid values of y/z."""
        return self.slope_y0 + self.slope_dy * np.arange(self.ny)

    def bend_at(self, sx, sy):
        """(βx, βy) [MeV] of the ideal direction at (x/z, y/z): t0 = (x/z + βx·qop, y/z + βy·qop)."""
        return (self.bend + self.bend_x2 * sx * sx + self.bend_y2 * sy * sy, self.bend_xy * sx * sy)

    def as_arrays(self) -> tuple[np.ndarray, np.ndarray]:
        """(meta float64[META_SIZE], cells float64[nx, ny, 4, n_columns]) for `ut_to_scifi_extrapolate`.

        meta = (z_from, z_to, p_min, slope_x0, slope_dx, nx, slope_y0, slope_dy, ny, bend,
        K1x, K2x, K1y, K2y, K1tx, K2tx, K1ty, K2ty, bend_x2, bend_y2, bend_xy, w_max,
        soft_offset, L1x, L2x, L1y, L2y, L1tx, L2tx, L1ty, L2ty); cells[i, j, u] = the eq. 21
        coefficients of output u at grid point (i, j), then from column soft_offset the
        soft-range ones (w_max = 1, soft degrees 0 without a soft range): C-contiguous and
        cell-major, so that the six grid points of one evaluation are six runs of 4 ×
        n_columns numbers and a point's columns one SIMD row (`_six_columns`).
        """
        meta = np.zeros(META_SIZE)
        meta[META_Z_FROM] = self.z_from
        meta[META_Z_TO] = self.z_to
        meta[META_P_MIN] = self.p_min
        meta[META_SLOPE_X0] = self.slope_x0
        meta[META_SLOPE_DX] = self.slope_dx
        meta[META_NX] = self.nx
        meta[META_SLOPE_Y0] = self.slope_y0
        meta[META_SLOPE_DY] = self.slope_dy
        meta[META_NY] = self.ny
        meta[META_BEND] = self.bend
        for u, (k1, k2) in enumerate(self.degrees):
            meta[META_DEGREES + 2 * u] = k1
            meta[META_DEGREES + 2 * u + 1] = k2
        meta[META_BEND_X2] = self.bend_x2
        meta[META_BEND_Y2] = self.bend_y2
        meta[META_BEND_XY] = self.bend_xy
        meta[META_SOFT_OFFSET] = self.coef.shape[3]
        if self.soft is None:
            meta[META_W_MAX] = 1.0
            return meta, np.ascontiguousarray(self.coef.transpose(1, 2, 0, 3))
        meta[META_W_MAX] = self.p_min / self.p_low
        for u, (l1, l2) in enumerate(self.soft_degrees):
            meta[META_SOFT_DEGREES + 2 * u] = l1
            meta[META_SOFT_DEGREES + 2 * u + 1] = l2
        return meta, np.ascontiguousarray(np.concatenate([self.coef, self.soft], axis=3).transpose(1, 2, 0, 3))

    def to_json_dict(self) -> dict:
        """Plain-JSON form: scalars, and per output the coefficients (C order over
        (i_x, i_y, k), only the K1 + 2·K2 used columns) as base64 of little-endian float64
        — exact, and 2.3× smaller than decimal lists; the soft range likewise under `soft`."""
        coefficients = {}
        for u, name in enumerate(OUTPUTS):
            k1, k2 = self.degrees[u]
            values = np.ascontiguousarray(self.coef[u, :, :, : k1 + 2 * k2], dtype="<f8")
            coefficients[name] = base64.b64encode(values.tobytes()).decode("ascii")
        out = {
            "format": JSON_FORMAT,
            "z_from": float(self.z_from),
            "z_to": float(self.z_to),
            "p_min": float(self.p_min),
            "bend": float(self.bend),
            "bend_terms": {"x2": float(self.bend_x2), "y2": float(self.bend_y2), "xy": float(self.bend_xy)},
            "grid": {
                "slope_x0": float(self.slope_x0), "slope_dx": float(self.slope_dx), "nx": self.nx,
                "slope_y0": float(self.slope_y0), "slope_dy": float(self.slope_dy), "ny": self.ny,
            },
            "degrees": {name: list(self.degrees[u]) for u, name in enumerate(OUTPUTS)},
            "layout": ("coefficients[u]: C order over (i_x, i_y, k); k = A_1..A_K1, B_1..B_K2, "
                       "C_1..C_K2 of w^k, w = qop*p_min (paper eq. 21)"),
            "coefficients": coefficients,
            "tabulation": _jsonable(self.tabulation),
        }
        if self.soft is not None:
            cols = soft_columns(self.soft_degrees)
            soft = {}
            for u, name in enumerate(OUTPUTS):
                values = np.ascontiguousarray(self.soft[u, :, :, : 2 * cols[u]], dtype=SOFT_DTYPE)
                soft[name] = base64.b64encode(values.tobytes()).decode("ascii")
            out["soft"] = {
                "p_low": float(self.p_low),
                "degrees": {name: list(self.soft_degrees[u]) for u, name in enumerate(OUTPUTS)},
                "dtype": SOFT_DTYPE,
                "layout": ("coefficients[u]: C order over (i_x, i_y, k); k = for e > 0 then e < 0: "
                           "D_2..D_L1 (A), D_2..D_L2 (B), D_2..D_L2 (C) of e^k, e = w -+ 1, for 1 < |w| <= p_min/p_low"),
                "coefficients": soft,
            }
        return out

    @classmethod
    def from_json_dict(cls, data: dict) -> UTSciFiTable:
        """Inverse of `to_json_dict`; raises ValueError/KeyError/TypeError on malformed input.
        Tables without `bend_terms` or `soft` (older files) load with zero bend terms and
        no soft range."""
        if data.get("format") != JSON_FORMAT:
            raise ValueError(f"UT→SciFi table format {data.get('format')!r}, expected {JSON_FORMAT!r}")
        grid = data["grid"]
        nx, ny = int(grid["nx"]), int(grid["ny"])
        degrees = tuple(tuple(int(k) for k in data["degrees"][name]) for name in OUTPUTS)
        if any(len(d) != 2 for d in degrees):
            raise ValueError("UT→SciFi table degrees must be (K1, K2) pairs")
        ncoef = max(k1 + 2 * k2 for k1, k2 in degrees)
        coef = np.zeros((4, nx, ny, ncoef))
        for u, name in enumerate(OUTPUTS):
            k1, k2 = degrees[u]
            coef[u, :, :, : k1 + 2 * k2] = _decode(data["coefficients"][name], nx, ny, k1 + 2 * k2, name)
        terms = data.get("bend_terms") or {}
        soft_data = data.get("soft")
        p_low, soft_degrees, soft = None, ((0, 0),) * 4, None
        if soft_data:
            p_low = float(soft_data["p_low"])
            soft_degrees = tuple(tuple(int(k) for k in soft_data["degrees"][name]) for name in OUTPUTS)
            if any(len(d) != 2 for d in soft_degrees):
                raise ValueError("UT→SciFi soft degrees must be (L1, L2) pairs")
            cols = soft_columns(soft_degrees)
            soft = np.zeros((4, nx, ny, 2 * max(cols)))
            for u, name in enumerate(OUTPUTS):
                soft[u, :, :, : 2 * cols[u]] = _decode(soft_data["coefficients"][name], nx, ny, 2 * cols[u],
                                                       f"soft {name}", soft_data.get("dtype", "<f8"))
        return cls(
            z_from=float(data["z_from"]), z_to=float(data["z_to"]), p_min=float(data["p_min"]),
            bend=float(data["bend"]),
            slope_x0=float(grid["slope_x0"]), slope_dx=float(grid["slope_dx"]),
            slope_y0=float(grid["slope_y0"]), slope_dy=float(grid["slope_dy"]),
            degrees=degrees, coef=coef, tabulation=dict(data.get("tabulation", {})),
            bend_x2=float(terms.get("x2", 0.0)), bend_y2=float(terms.get("y2", 0.0)),
            bend_xy=float(terms.get("xy", 0.0)), p_low=p_low, soft_degrees=soft_degrees, soft=soft,
        )


def _decode(stored, nx: int, ny: int, ncol: int, name: str, dtype: str = "<f8") -> np.ndarray:
    """(nx, ny, ncol) float64 from base64 of little-endian `dtype` ("<f8" or "<f4"; or a plain list)."""
    if dtype not in ("<f8", "<f4"):
        raise ValueError(f"UT→SciFi coefficients[{name!r}]: dtype {dtype!r}, expected '<f8' or '<f4'")
    if isinstance(stored, str):
        values = np.frombuffer(base64.b64decode(stored, validate=True), dtype=dtype).astype(np.float64)
    else:
        values = np.asarray(stored, dtype=np.float64)
    if values.shape != (nx * ny * ncol,):
        raise ValueError(f"UT→SciFi coefficients[{name!r}] has {values.size} values, expected {nx * ny * ncol}")
    return values.reshape(nx, ny, ncol)


def _jsonable(value):
    if isinstance(value, dict):
        return {str(k): _jsonable(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_jsonable(v) for v in value]
    if isinstance(value, np.ndarray):
        return _jsonable(value.tolist())
    if isinstance(value, (np.floating, float)):
        return float(value)
    if isinstance(value, (np.integer, int)) and not isinstance(value, bool):
        return int(value)
    return value


# ----------------------------------------------------------------------------------------
# Tabulation
# ----------------------------------------------------------------------------------------

def chebyshev_qop_nodes(n_qop: int, p_min: float) -> np.ndarray:
    """The n_qop Chebyshev nodes of the first kind on (−1, 1)/p_min [1/MeV], ascending."""
    i = np.arange(n_qop)
    return np.sort(np.cos((2 * i + 1) * np.pi / (2 * n_qop))) / p_min


def bend_integral(field, z_ut: float, n_steps: int = 20000) -> float:
    """bend [MeV] = ∫_0^{z_ut} −κ·B_y(0, 0, z')·z'/z_ut dz' (trapezoid rule, n_steps intervals).

    The slope offset tx − x/z_ut ≈ bend·qop of a particle from the origin (module docstring).
    """
    z = np.linspace(0.0, z_ut, n_steps + 1)
    by = field.evaluate(np.zeros_like(z), np.zeros_like(z), z)[:, 1]
    g = -C_LIGHT * by * z / z_ut
    return float(np.sum(0.5 * (g[1:] + g[:-1]) * np.diff(z)))


@nb.njit(cache=True)
def _origin_offsets(slopes_x, slopes_y, qop, z_ut, max_step, field_kind, field_params, field_grid, out):
    """Slope offsets (tx − x/z_ut, ty − y/z_ut) at z_ut of particles from the origin with q/p
    `qop` that hit z_ut at (x/z, y/z) = (slopes_x[k], slopes_y[k]): out (n, 2). The initial
    slopes are found by 6 Newton-like iterations on the hit point (converged to < 1e-9)."""
    state = np.empty(5)
    for k in range(slopes_x.size):
        tx0 = slopes_x[k]
        ty0 = slopes_y[k]
        res = state
        for _ in range(7):
            state[0] = 0.0
            state[1] = 0.0
            state[2] = tx0
            state[3] = ty0
            state[4] = qop
            res = rk4_propagate(state, 0.0, z_ut, max_step, field_kind, field_params, field_grid)
            tx0 += slopes_x[k] - res[0] / z_ut
            ty0 += slopes_y[k] - res[1] / z_ut
        out[k, 0] = res[2] - res[0] / z_ut
        out[k, 1] = res[3] - res[1] / z_ut


def fit_bend_model(field, z_ut: float, slope_range: float = 0.25, p_ref: float = 20000.0, n: int = 21,
                   max_step: float = DEFAULT_MAX_STEP) -> tuple[float, float, float, float]:
    """(bend, bend_x2, bend_y2, bend_xy) [MeV] of the ideal direction (LHCb's form):
    least-squares fit of (tx − x/z)/qop = bend + bend_x2·(x/z)² + bend_y2·(y/z)² and
    (ty − y/z)/qop = bend_xy·(x/z)(y/z) to RK4 particles from the origin with p = p_ref
    [MeV] (both charges, averaged) hitting z_ut [mm] on an n × n grid of |x/z|, |y/z| ≤
    slope_range.

    For the lhcb-like map (bend, x2, y2, xy) ≈ (38.4, 28, −433, 240) MeV: the offset falls
    from 38 MeV on the axis to 12 MeV at |y/z| = 0.25 (the fringe field near the yoke),
    which a constant bend (the paper's t0x = x/z + B·qop) turns into δtx ≈ 18 mrad for a
    1.5 GeV particle from the origin; the fit leaves ≤ 0.7 MeV (≤ 0.5 mrad at 1.5 GeV).
    """
    g = np.linspace(-slope_range, slope_range, n)
    gx, gy = (a.ravel().copy() for a in np.meshgrid(g, g, indexing="ij"))
    kind, params, grid = field.args
    offsets = np.zeros((gx.size, 2))
    for sign in (1.0, -1.0):
        part = np.empty((gx.size, 2))
        _origin_offsets(gx, gy, sign / p_ref, float(z_ut), float(max_step), kind, params, grid, part)
        offsets += part * sign * p_ref / 2.0
    (b0, bx2, by2), *_ = np.linalg.lstsq(np.column_stack([np.ones_like(gx), gx * gx, gy * gy]), offsets[:, 0],
                                         rcond=None)
    xy = gx * gy
    bxy = float(np.dot(xy, offsets[:, 1]) / np.dot(xy, xy))
    return float(b0), float(bx2), float(by2), bxy


@nb.njit(cache=True)
def _tabulate_deviations(z_from, z_to, slopes_x, slopes_y, qops, bend, max_step,
                         field_kind, field_params, field_grid, dev, final):
    """RK4 (+ Jacobian) from every grid point along the ideal direction, every q/p node.

    bend = (bend, bend_x2, bend_y2, bend_xy) [MeV] (`UTSciFiTable`). dev[u, b, ix, iy, iq]
    (u = x, y, tx, ty; b = A, B, C): the propagated state minus the straight line along t0
    (b = A), and ∂out_u/∂tx, ∂out_u/∂ty minus their straight-line values (b = B, C);
    final[0:2, ix, iy, iq]: x, y at z_to [mm] (NaN if the track curled).
    """
    dz = z_to - z_from
    state = np.empty(5)
    jac = np.empty((5, 5))
    for ix in range(slopes_x.size):
        sx = slopes_x[ix]
        for iy in range(slopes_y.size):
            sy = slopes_y[iy]
            beta_x = bend[0] + bend[1] * sx * sx + bend[2] * sy * sy
            beta_y = bend[3] * sx * sy
            for iq in range(qops.size):
                qop = qops[iq]
                x = sx * z_from
                y = sy * z_from
                t0x = sx + beta_x * qop
                t0y = sy + beta_y * qop
                state[0] = x
                state[1] = y
                state[2] = t0x
                state[3] = t0y
                state[4] = qop
                out = rk4_propagate_jacobian(state, z_from, z_to, max_step,
                                             field_kind, field_params, field_grid, jac)
                dev[0, 0, ix, iy, iq] = out[0] - x - t0x * dz
                dev[0, 1, ix, iy, iq] = jac[0, 2] - dz
                dev[0, 2, ix, iy, iq] = jac[0, 3]
                dev[1, 0, ix, iy, iq] = out[1] - y - t0y * dz
                dev[1, 1, ix, iy, iq] = jac[1, 2]
                dev[1, 2, ix, iy, iq] = jac[1, 3] - dz
                dev[2, 0, ix, iy, iq] = out[2] - t0x
                dev[2, 1, ix, iy, iq] = jac[2, 2] - 1.0
                dev[2, 2, ix, iy, iq] = jac[2, 3]
                dev[3, 0, ix, iy, iq] = out[3] - t0y
                dev[3, 1, ix, iy, iq] = jac[3, 2]
                dev[3, 2, ix, iy, iq] = jac[3, 3] - 1.0
                final[0, ix, iy, iq] = out[0]
                final[1, ix, iy, iq] = out[1]


def soft_nodes(n_soft: int, e_max: float) -> np.ndarray:
    """The n_soft Chebyshev nodes of the first kind on (0, e_max), ascending: the soft q/p
    nodes are w = ±(1 + e) (e = w ∓ 1)."""
    i = np.arange(n_soft)
    return np.sort(0.5 * e_max * (1.0 + np.cos((2 * i + 1) * np.pi / (2 * n_soft))))


def _fit_soft(coef, degrees, soft_degrees, dev, final, e, window, outside_weight, curl_weight=0.0):
    """Soft-range coefficients (4, nx, ny, 2·max soft_columns) and max |fit − tabulated| inside the
    window per output and block. dev/final: the soft nodes w = +(1 + e) then −(1 + e)."""
    nx, ny = coef.shape[1:3]
    n = e.size
    cols = soft_columns(soft_degrees)
    soft = np.zeros((4, nx, ny, 2 * max(cols)))
    residual = np.zeros((4, 3))
    finite = np.all(np.isfinite(dev), axis=(0, 1)) & np.isfinite(final[0]) & np.isfinite(final[1])
    inside = finite & (np.abs(final[0]) < window[0]) & (np.abs(final[1]) < window[1])
    # outside the window: weight outside_weight; a curling (non-finite) trajectory: curl_weight
    # towards the edge's linear continuation (correction 0)
    weight = np.where(inside, 1.0, np.where(finite, outside_weight, curl_weight))  # (nx, ny, 2n)
    for side_index, side in enumerate((1.0, -1.0)):
        nodes = slice(side_index * n, (side_index + 1) * n)
        es = side * e  # signed e = w − side
        wgt = weight[:, :, nodes].reshape(nx * ny, n)
        groups, group_of = np.unique(wgt, axis=0, return_inverse=True)
        group_of = group_of.reshape(nx, ny)
        for u in range(4):
            k1, k2 = degrees[u]
            col_in = 0
            col_out = side_index * cols[u]
            for b, (deg, lb) in enumerate(((k1, soft_degrees[u][0]), (k2, soft_degrees[u][1]),
                                           (k2, soft_degrees[u][1]))):
                c = coef[u, :, :, col_in: col_in + deg]
                k = np.arange(1, deg + 1)
                p_edge = (c * side ** k).sum(axis=-1)  # P(±1)
                dp_edge = (c * k * side ** (k - 1)).sum(axis=-1)  # P'(±1)
                target = dev[u, b][:, :, nodes] - p_edge[..., None] - dp_edge[..., None] * es
                target = np.where(finite[:, :, nodes], target, 0.0)
                col_in += deg
                if lb < 2:
                    continue
                vander = es[:, None] ** np.arange(2, lb + 1)[None, :]  # (n, lb − 1)
                for g in range(groups.shape[0]):
                    sel = group_of == g
                    wg = groups[g]
                    if not np.any(wg == 1.0):
                        continue  # no trajectory in the window: the edge's linear continuation
                    d = (target[sel] * wg) @ np.linalg.pinv(vander * wg[:, None]).T
                    soft[u][sel, col_out: col_out + lb - 1] = d
                    fitted = wg == 1.0
                    res = np.abs(d @ vander[fitted].T - target[sel][:, fitted])
                    residual[u, b] = max(residual[u, b], float(res.max()))
                col_out += lb - 1
    return soft, residual, float(np.mean(inside))


def tabulate_ut_to_scifi(
    field,
    z_from: float = 2642.5,
    z_to: float = 7826.0,
    p_min: float = 3000.0,
    n_qop: int = 20,
    nx: int = 50,
    ny: int = 50,
    slope_range: float = 0.25,
    degrees=DEFAULT_DEGREES,
    max_step: float = DEFAULT_MAX_STEP,
    bend: float | None = None,
    progress=None,
    p_low: float | None = None,
    n_soft: int = DEFAULT_N_SOFT,
    soft_degrees=DEFAULT_SOFT_DEGREES,
    soft_window=DEFAULT_SOFT_WINDOW,
    soft_outside_weight: float = DEFAULT_SOFT_OUTSIDE_WEIGHT,
) -> UTSciFiTable:
    """Tabulate the paper eq. 21 coefficients with RK4 through `field` (a FieldModel).

    Grid: nx × ny points on |x/z|, |y/z| ≤ slope_range at z_from [mm]; q/p: n_qop Chebyshev
    nodes in (−1, 1)/p_min [1/MeV]; degrees (K1, K2) for x, y, tx, ty (each fit needs
    n_qop ≥ K1 and ≥ K2); max_step [mm] the RK4 step; bend [MeV]: None fits LHCb's
    quadratic ideal direction (`fit_bend_model`), a number gives the paper's constant one
    (bend_x2 = bend_y2 = bend_xy = 0). p_low [MeV] (None: p_min): with p_low < p_min the
    soft range p_low ≤ p < p_min is tabulated too, on n_soft Chebyshev nodes in e per charge
    sign, fitted with soft_degrees (L1, L2) per output, full weight for nodes whose
    trajectory ends inside soft_window = (|x|, |y|) [mm] at z_to and soft_outside_weight for
    the other finite ones (module docstring). progress, if given, is called with 1 after each
    of the nx rows of the grid. Cost: nx·ny·(n_qop + 2·n_soft) RK4+Jacobian propagations
    (≈ 100 s for 50×100×(20 + 24) at 20 mm steps through the lhcb-like map on one loaded core).
    """
    degrees = tuple((int(k1), int(k2)) for k1, k2 in degrees)
    soft_degrees = tuple((int(l1), int(l2)) for l1, l2 in soft_degrees)
    if nx < 3 or ny < 3:
        raise ValueError("the grid needs at least 3 points per axis")
    if any(max(k1, k2) > n_qop for k1, k2 in degrees):
        raise ValueError(f"n_qop = {n_qop} is fewer than a polynomial degree in {degrees}")
    if p_min <= 0 or slope_range <= 0 or max_step <= 0 or z_from == 0 or z_to == z_from:
        raise ValueError("need p_min > 0, slope_range > 0, max_step > 0, z_from != 0, z_to != z_from")
    if p_low is None:
        p_low = p_min
    if not 0 < p_low <= p_min:
        raise ValueError(f"need 0 < p_low <= p_min, got p_low = {p_low}, p_min = {p_min}")
    has_soft = p_low < p_min and max(soft_columns(soft_degrees)) > 0
    if has_soft and any(max(l1, l2) - 1 > n_soft for l1, l2 in soft_degrees):
        raise ValueError(f"n_soft = {n_soft} is fewer than a soft polynomial's terms in {soft_degrees}")
    t_start = time.perf_counter()
    if bend is None:
        bend_terms = fit_bend_model(field, z_from, slope_range, max_step=max_step)
    else:
        bend_terms = (float(bend), 0.0, 0.0, 0.0)
    slopes_x = np.linspace(-slope_range, slope_range, nx)
    slopes_y = np.linspace(-slope_range, slope_range, ny)
    qops = chebyshev_qop_nodes(n_qop, p_min)
    w = qops * p_min
    e = soft_nodes(n_soft, p_min / p_low - 1.0) if has_soft else np.zeros(0)
    all_qops = np.concatenate([qops, (1.0 + e) / p_min, -(1.0 + e) / p_min])
    kind, params, grid = field.args
    n_all = all_qops.size
    dev = np.empty((4, 3, nx, ny, n_all))
    final = np.empty((2, nx, ny, n_all))
    row = np.empty((4, 3, 1, ny, n_all))
    row_final = np.empty((2, 1, ny, n_all))
    bend_arr = np.array(bend_terms)
    for ix in range(nx):  # one x/z row per call: every grid point is independent
        _tabulate_deviations(float(z_from), float(z_to), slopes_x[ix: ix + 1], slopes_y, all_qops, bend_arr,
                             float(max_step), kind, params, grid, row, row_final)
        dev[:, :, ix: ix + 1] = row
        final[:, ix: ix + 1] = row_final
        if progress is not None:
            progress(1)
    ncoef = max(k1 + 2 * k2 for k1, k2 in degrees)
    coef = np.zeros((4, nx, ny, ncoef))
    residual = {}
    inner = dev[..., :n_qop]
    for u, name in enumerate(OUTPUTS):
        col = 0
        res_u = []
        for b, degree in enumerate((degrees[u][0], degrees[u][1], degrees[u][1])):
            if degree == 0:
                res_u.append(float(np.max(np.abs(inner[u, b]))))
                continue
            vander = w[:, None] ** np.arange(1, degree + 1)[None, :]  # (n_qop, degree)
            fit = np.linalg.pinv(vander)  # (degree, n_qop), least squares
            c = inner[u, b] @ fit.T  # (nx, ny, degree)
            coef[u, :, :, col: col + degree] = c
            res_u.append(float(np.max(np.abs(c @ vander.T - inner[u, b]))))
            col += degree
        residual[name] = res_u
    if not np.all(np.isfinite(coef)):
        raise ValueError(f"UT→SciFi tabulation through {field!r} gave non-finite coefficients for |p| ≥ {p_min} MeV")
    soft = None
    soft_info = {}
    if has_soft:
        soft, soft_residual, inside = _fit_soft(coef, degrees, soft_degrees, dev[..., n_qop:], final[..., n_qop:],
                                                e, soft_window, soft_outside_weight)
        soft = soft.astype(np.float32).astype(np.float64)  # stored as float32 (SOFT_DTYPE)
        soft_info = {
            "soft_nodes": "chebyshev-first-kind in e = |w| - 1, per charge sign",
            "n_soft": int(n_soft),
            "soft_window_mm": [float(v) for v in soft_window],
            "soft_outside_weight": float(soft_outside_weight),
            "soft_inside_share": round(inside, 4),
            # max |fit − tabulated| over the soft nodes inside the window, (A, B, C) per output
            "soft_max_fit_residual": {name: [float(v) for v in soft_residual[u]] for u, name in enumerate(OUTPUTS)},
        }
    elapsed = time.perf_counter() - t_start
    return UTSciFiTable(
        z_from=float(z_from), z_to=float(z_to), p_min=float(p_min), bend=bend_terms[0],
        slope_x0=float(slopes_x[0]), slope_dx=float(slopes_x[1] - slopes_x[0]),
        slope_y0=float(slopes_y[0]), slope_dy=float(slopes_y[1] - slopes_y[0]),
        degrees=degrees, coef=coef,
        bend_x2=bend_terms[1], bend_y2=bend_terms[2], bend_xy=bend_terms[3],
        p_low=float(p_low) if has_soft else float(p_min), soft_degrees=soft_degrees if has_soft else ((0, 0),) * 4,
        soft=soft,
        tabulation={
            "method": "RK4 with transport Jacobian through the field model, ideal direction from the origin",
            "bend_model": "fitted quadratic (LHCb)" if bend is None else "constant",
            "qop_nodes": "chebyshev-first-kind",
            "n_qop": int(n_qop),
            "max_step_mm": float(max_step),
            "field_hash": field.content_hash() if hasattr(field, "content_hash") else "",
            # max |fit − tabulated| over the grid and q/p nodes for (A, B, C) of each output
            "max_fit_residual": residual,
            **soft_info,
            "seconds": round(elapsed, 3),
        },
    )


# ----------------------------------------------------------------------------------------
# Evaluation (paper eqs. 21–23)
# ----------------------------------------------------------------------------------------

@nb.njit(cache=True)
def _axis_lookup(s, s0, ds, n):
    """Stencil centre index, offset ξ in cells and dξ/ds for the lookup of s on the grid
    s0 + i·ds (i < n). Centre clamped to 1 … n−2; s clamped to MAX_EXTRAPOLATION_CELLS
    cells outside the grid (then dξ/ds = 0)."""
    u = (s - s0) / ds
    dfac = 1.0 / ds
    lo = -MAX_EXTRAPOLATION_CELLS
    hi = n - 1.0 + MAX_EXTRAPOLATION_CELLS
    if u < lo:
        u = lo
        dfac = 0.0
    elif u > hi:
        u = hi
        dfac = 0.0
    elif not (u == u):  # NaN: any valid cell, the output is NaN anyway
        u = 1.0
    i = int(math.floor(u + 0.5))
    if i < 1:
        i = 1
    elif i > n - 2:
        i = n - 2
    return i, u - i, dfac


@nb.njit(cache=True)
def interpolation_weights(xi, psi):
    """Weights of the six points of paper eqs. 22–23 and their ξ and ψ derivatives.

    Returns (ex, ey, w, w_xi, w_psi) with w = (w00, w+0, w−0, w0+, w0−, wεε) as tuples,
    for the points (0,0), (+1,0), (−1,0), (0,+1), (0,−1), (εx,εy) in cell units.
    """
    ex = 1 if xi >= 0.0 else -1
    ey = 1 if psi >= 0.0 else -1
    exy = float(ex * ey)
    d = exy * xi * psi  # Fd·ξψ = d·(F00 + Fεε − Fεx0 − F0εy)
    d_xi = exy * psi
    d_psi = exy * xi
    w00 = 1.0 - xi * xi - psi * psi + d
    wp0 = 0.5 * (xi * xi + xi)
    wm0 = 0.5 * (xi * xi - xi)
    w0p = 0.5 * (psi * psi + psi)
    w0m = 0.5 * (psi * psi - psi)
    w00_xi = -2.0 * xi + d_xi
    wp0_xi = xi + 0.5
    wm0_xi = xi - 0.5
    w0p_xi = 0.0
    w0m_xi = 0.0
    w00_psi = -2.0 * psi + d_psi
    wp0_psi = 0.0
    wm0_psi = 0.0
    w0p_psi = psi + 0.5
    w0m_psi = psi - 0.5
    if ex > 0:
        wp0 -= d
        wp0_xi -= d_xi
        wp0_psi -= d_psi
    else:
        wm0 -= d
        wm0_xi -= d_xi
        wm0_psi -= d_psi
    if ey > 0:
        w0p -= d
        w0p_xi -= d_xi
        w0p_psi -= d_psi
    else:
        w0m -= d
        w0m_xi -= d_xi
        w0m_psi -= d_psi
    return (ex, ey, (w00, wp0, wm0, w0p, w0m, d), (w00_xi, wp0_xi, wm0_xi, w0p_xi, w0m_xi, d_xi),
            (w00_psi, wp0_psi, wm0_psi, w0p_psi, w0m_psi, d_psi))


@nb.njit(cache=True)
def interpolate_grid(values, s0x, dsx, s0y, dsy, sx, sy):
    """Paper eqs. 22–23 for one tabulated quantity values[nx, ny] at (sx, sy) = (x/z, y/z).

    Returns (F, ∂F/∂sx, ∂F/∂sy) with the edge and outside rules of `ut_to_scifi_extrapolate`.
    """
    nx = values.shape[0]
    ny = values.shape[1]
    i, xi, fx = _axis_lookup(sx, s0x, dsx, nx)
    j, psi, fy = _axis_lookup(sy, s0y, dsy, ny)
    ex, ey, w, wx, wy = interpolation_weights(xi, psi)
    f = (w[0] * values[i, j] + w[1] * values[i + 1, j] + w[2] * values[i - 1, j]
         + w[3] * values[i, j + 1] + w[4] * values[i, j - 1] + w[5] * values[i + ex, j + ey])
    f_xi = (wx[0] * values[i, j] + wx[1] * values[i + 1, j] + wx[2] * values[i - 1, j]
            + wx[3] * values[i, j + 1] + wx[4] * values[i, j - 1] + wx[5] * values[i + ex, j + ey])
    f_psi = (wy[0] * values[i, j] + wy[1] * values[i + 1, j] + wy[2] * values[i - 1, j]
             + wy[3] * values[i, j + 1] + wy[4] * values[i, j - 1] + wy[5] * values[i + ex, j + ey])
    return f, f_xi * fx, f_psi * fy


def without_soft_range(meta: np.ndarray) -> np.ndarray:
    """A copy of `meta` that reads the same table as one without soft range: eq. 21 on
    |w| ≤ 1, continued from the edge beyond it (status STATUS_BELOW_P_MIN), as a table of
    p_min only (the forward search's view, `pkf.seeding.forward.extend_velo_tracks`)."""
    hard = np.array(meta, dtype=np.float64, copy=True)
    if hard.size >= META_SIZE:
        hard[META_W_MAX] = 1.0
        hard[META_SOFT_DEGREES : META_SOFT_DEGREES + 8] = 0.0
    return hard


def covered_p_min(meta: np.ndarray) -> float:
    """[MeV] the lowest momentum the table of `meta` covers: p_min/w_max (p_low with a soft
    range, p_min without); 0 for an empty table."""
    if meta.size < META_SIZE or meta[META_P_MIN] <= 0.0:
        return 0.0
    return float(meta[META_P_MIN] / max(meta[META_W_MAX], 1.0))


@nb.njit(cache=True, inline="always")
def _six(cells, u, i, j, ex, ey, col, w):
    """Paper eq. 22–23 with the weights w of `interpolation_weights` for column col of output u
    (cells: `UTSciFiTable.as_arrays`)."""
    return (w[0] * cells[i, j, u, col] + w[1] * cells[i + 1, j, u, col] + w[2] * cells[i - 1, j, u, col]
            + w[3] * cells[i, j + 1, u, col] + w[4] * cells[i, j - 1, u, col] + w[5] * cells[i + ex, j + ey, u, col])


@nb.njit(cache=True, inline="always")
def _six_columns(cells, u, i, j, ex, ey, n, w, w_xi, w_psi, out, out_xi, out_psi):
    """`_six` of columns 0 … n − 1 of output u with the weights w, w_xi and w_psi into out,
    out_xi and out_psi (1-D): per column the same products and sums as `_six`, so the same
    numbers; the loop runs over contiguous columns of the six points (`cells` is C-contiguous,
    cell-major), which the compiler issues as SIMD. Measured (CPU, in one process, the 8,348
    states entering the table step of benchmarks/fit_core.py's minimum-bias tracks):
    `ut_to_scifi_extrapolate` ×0.81 (650–770 → 520–540 ns per call) against per-column `_six`
    on the (u, i, j, column) view; in the parametrized forward filter of those tracks (step,
    covariance transport and update; old and new table code alternating, in both orders of
    compilation, each against an A/B of identical code) ×0.98 ± 0.015: there the table's
    reads from the last-level cache weigh more than its arithmetic (~960 ns per call by
    perf's share of the fit; prefetching the six points' lines when a track enters the UT
    changed nothing, ×1.008). The localisation (`localize_ut_to_scifi`) ×0.97–0.99.
    Tried (2026-12-06; the 8,246 table steps of those tracks in the fit's order, one
    process, old and new alternating, min of 7): the four outputs' eq. 21 sums side by side
    (a zero-padded copy of the columns, u innermost, for SIMD over the outputs) — bitwise
    the same on 28,246 states, soft range and beyond included, but LLVM kept the 24
    accumulators scalar: 480–546 → 435–525 ns per step (the same state over and over, its
    cells in L1: 375–416 → 336–340), not worth a second copy of the table; a cell-sorted
    order of the states 455–518. So the reads of this 9 MB table cost ~100 ns of the ~500,
    the arithmetic the rest (not the other way round, as guessed above from perf's share;
    a read prefetch of a track's cells one track ahead in the fit changed nothing either,
    `pkf.fit.kalman_lanes`)."""
    a = cells[i, j, u, :n]
    b = cells[i + 1, j, u, :n]
    c = cells[i - 1, j, u, :n]
    d = cells[i, j + 1, u, :n]
    e = cells[i, j - 1, u, :n]
    f = cells[i + ex, j + ey, u, :n]
    for m in range(n):
        out[m] = w[0] * a[m] + w[1] * b[m] + w[2] * c[m] + w[3] * d[m] + w[4] * e[m] + w[5] * f[m]
        out_xi[m] = (w_xi[0] * a[m] + w_xi[1] * b[m] + w_xi[2] * c[m] + w_xi[3] * d[m] + w_xi[4] * e[m]
                     + w_xi[5] * f[m])
        out_psi[m] = (w_psi[0] * a[m] + w_psi[1] * b[m] + w_psi[2] * c[m] + w_psi[3] * d[m] + w_psi[4] * e[m]
                      + w_psi[5] * f[m])


@nb.njit(cache=True, inline="always")
def _ideal_direction(meta, sx, sy, qop):
    """(δ-offsets) of the ideal direction at (x/z, y/z) = (sx, sy): returns
    (βx, βy, ∂βx/∂sx, ∂βx/∂sy, ∂βy/∂sx, ∂βy/∂sy) [MeV], t0 = (sx + βx·qop, sy + βy·qop)."""
    bx2 = meta[META_BEND_X2]
    by2 = meta[META_BEND_Y2]
    bxy = meta[META_BEND_XY]
    return (meta[META_BEND] + bx2 * sx * sx + by2 * sy * sy, bxy * sx * sy,
            2.0 * bx2 * sx, 2.0 * by2 * sy, bxy * sy, bxy * sx)


@nb.njit(cache=True, inline="always")
def _soft_range(meta, w):
    """(wc, e, ec, side_index, status) for w = qop·p_min: wc = w clamped to [−1, 1]; e = w − wc;
    ec = e clamped to the soft range [−(w_max − 1), w_max − 1]; side_index 0 for w > 0, 1 for
    w < 0; status STATUS_BELOW_P_MIN beyond |w| = w_max."""
    w_max = meta[META_W_MAX]
    if not w_max >= 1.0:
        w_max = 1.0
    e_max = w_max - 1.0
    wc = w
    side = 0
    if w > 1.0:
        wc = 1.0
    elif w < -1.0:
        wc = -1.0
        side = 1
    e = w - wc
    ec = e
    status = STATUS_OK
    if ec > e_max:
        ec = e_max
        status = STATUS_BELOW_P_MIN
    elif ec < -e_max:
        ec = -e_max
        status = STATUS_BELOW_P_MIN
    return wc, e, ec, side, status


@nb.njit(cache=True, **NO_REFCOUNT)
def ut_to_scifi_extrapolate(meta, cells, state_in, state_out, jac_out):
    """Paper eq. 21 from z_from to z_to: writes state_out (5) and jac_out = ∂out/∂in (5×5).

    state (x, y, tx, ty, qop) in mm, 1, 1/MeV; (meta, cells) from `UTSciFiTable.as_arrays()`.
    The coefficients are interpolated at (x/z_from, y/z_from) with paper eqs. 22–23; the
    Jacobian is analytic, including the derivatives through the interpolation (x, y) and
    through the ideal direction t0 (x, y, qop). qop is unchanged (f_qop = identity).
    Between |w| = 1 and w_max (p_min > p ≥ p_low) each polynomial is continued linearly plus
    its tabulated soft correction. Returns 0, or 4 if |qop|·p_min > w_max (continued linearly
    from the edge of the range: finite, but outside the tabulated range), or 2 if (meta,
    cells) is not a valid table (state copied, identity Jacobian). No allocation: the eq. 21
    coefficients of an output, interpolated at once for all its columns (`_six_columns`),
    wait in a stack buffer.
    """
    for a in range(5):
        state_out[a] = state_in[a]
        for b in range(5):
            jac_out[a, b] = 1.0 if a == b else 0.0
    if meta.size < META_SIZE or cells.ndim != 4:
        return STATUS_INVALID_TABLE
    nx = int(meta[META_NX])
    ny = int(meta[META_NY])
    p_min = meta[META_P_MIN]
    z0 = meta[META_Z_FROM]
    if (nx < 3 or ny < 3 or cells.shape[0] != nx or cells.shape[1] != ny or cells.shape[2] != 4
            or p_min <= 0.0 or z0 == 0.0):
        return STATUS_INVALID_TABLE
    soft_offset = int(meta[META_SOFT_OFFSET])
    for u in range(4):
        n_eq21 = meta[META_DEGREES + 2 * u] + 2.0 * meta[META_DEGREES + 2 * u + 1]
        if n_eq21 > cells.shape[3] or n_eq21 > MAX_EQ21_COLUMNS:
            return STATUS_INVALID_TABLE
        if soft_offset + 2.0 * _soft_side_columns(meta, u) > cells.shape[3]:
            return STATUS_INVALID_TABLE
    dz = meta[META_Z_TO] - z0
    eq21 = stack_array((3, MAX_EQ21_COLUMNS))  # one output's coefficients and their ξ, ψ derivatives
    x = state_in[0]
    y = state_in[1]
    tx = state_in[2]
    ty = state_in[3]
    qop = state_in[4]
    inv_z0 = 1.0 / z0
    sx = x * inv_z0
    sy = y * inv_z0
    beta_x, beta_y, bx_sx, bx_sy, by_sx, by_sy = _ideal_direction(meta, sx, sy, qop)
    dtx = tx - sx - beta_x * qop  # δtx
    dty = ty - sy - beta_y * qop  # δty
    # ∂δtx/∂x, ∂δtx/∂y, ∂δty/∂x, ∂δty/∂y
    dtx_x = -(1.0 + bx_sx * qop) * inv_z0
    dtx_y = -bx_sy * qop * inv_z0
    dty_x = -by_sx * qop * inv_z0
    dty_y = -(1.0 + by_sy * qop) * inv_z0
    w = qop * p_min
    wc, excess, ec, side, status = _soft_range(meta, w)
    beyond = excess - ec  # linear continuation beyond the soft range
    i, xi, fx = _axis_lookup(sx, meta[META_SLOPE_X0], meta[META_SLOPE_DX], nx)
    j, psi, fy = _axis_lookup(sy, meta[META_SLOPE_Y0], meta[META_SLOPE_DY], ny)
    ex, ey, wt, wt_xi, wt_psi = interpolation_weights(xi, psi)
    dxi_dx = fx * inv_z0  # ∂ξ/∂x
    dpsi_dy = fy * inv_z0  # ∂ψ/∂y
    for u in range(4):
        k1 = int(meta[META_DEGREES + 2 * u])
        k2 = int(meta[META_DEGREES + 2 * u + 1])
        l1 = int(meta[META_SOFT_DEGREES + 2 * u])
        l2 = int(meta[META_SOFT_DEGREES + 2 * u + 1])
        scol = soft_offset + side * _soft_side_columns(meta, u)
        val = 0.0  # Σ A w^k + Σ (B δtx + C δty) w^k
        val_w = 0.0  # ∂val/∂w at fixed δt
        val_xi = 0.0  # ∂val/∂ξ at fixed δt, w
        val_psi = 0.0
        poly_b = 0.0  # Σ B_k w^k
        poly_c = 0.0  # Σ C_k w^k
        # all its eq. 21 columns at once, rounded up to whole SIMD rows of 8 where the cell has them
        _six_columns(cells, u, i, j, ex, ey, min((k1 + 2 * k2 + 7) // 8 * 8, cells.shape[3]), wt, wt_xi, wt_psi,
                     eq21[0], eq21[1], eq21[2])
        col = 0
        for blk in range(3):
            degree = k1 if blk == 0 else k2
            p = 0.0
            p_w = 0.0
            p_xi = 0.0
            p_psi = 0.0
            pw_xi = 0.0  # ∂²P/∂w∂ξ (for the continuation beyond |w| = 1)
            pw_psi = 0.0
            wk1 = 1.0  # wc^(k−1)
            for k in range(1, degree + 1):
                c = eq21[0, col]
                c_xi = eq21[1, col]
                c_psi = eq21[2, col]
                wk = wk1 * wc
                p += c * wk
                p_xi += c_xi * wk
                p_psi += c_psi * wk
                p_w += k * c * wk1
                pw_xi += k * c_xi * wk1
                pw_psi += k * c_psi * wk1
                wk1 = wk
                col += 1
            if excess != 0.0:
                p += p_w * excess
                p_xi += pw_xi * excess
                p_psi += pw_psi * excess
                # the soft correction Σ_{k=2..L} D_k e^k at ec, continued linearly beyond
                soft_degree = l1 if blk == 0 else l2
                ek1 = ec  # ec^(k−1)
                for k in range(2, soft_degree + 1):
                    d = _six(cells, u, i, j, ex, ey, scol, wt)
                    d_xi = _six(cells, u, i, j, ex, ey, scol, wt_xi)
                    d_psi = _six(cells, u, i, j, ex, ey, scol, wt_psi)
                    ek = ek1 * ec
                    p += d * (ek + k * ek1 * beyond)
                    p_xi += d_xi * (ek + k * ek1 * beyond)
                    p_psi += d_psi * (ek + k * ek1 * beyond)
                    p_w += k * d * ek1
                    ek1 = ek
                    scol += 1
            if blk == 0:
                m = 1.0
            elif blk == 1:
                m = dtx
                poly_b = p
            else:
                m = dty
                poly_c = p
            val += m * p
            val_w += m * p_w
            val_xi += m * p_xi
            val_psi += m * p_psi
        # straight-line part and its Jacobian (rows x, y, tx, ty)
        if u == 0:
            state_out[0] = x + tx * dz + val
            jac_out[0, 2] = dz
        elif u == 1:
            state_out[1] = y + ty * dz + val
            jac_out[1, 3] = dz
        elif u == 2:
            state_out[2] = tx + val
        else:
            state_out[3] = ty + val
        # through δtx = tx − sx − βx(sx, sy)·qop and δty = ty − sy − βy(sx, sy)·qop
        jac_out[u, 0] += val_xi * dxi_dx + poly_b * dtx_x + poly_c * dty_x
        jac_out[u, 1] += val_psi * dpsi_dy + poly_b * dtx_y + poly_c * dty_y
        jac_out[u, 2] += poly_b
        jac_out[u, 3] += poly_c
        jac_out[u, 4] = val_w * p_min - poly_b * beta_x - poly_c * beta_y
    return status


@nb.njit(cache=True, inline="always")
def _soft_side_columns(meta, u):
    """Soft-range columns of output u for one charge sign (`soft_columns`)."""
    l1 = int(meta[META_SOFT_DEGREES + 2 * u])
    l2 = int(meta[META_SOFT_DEGREES + 2 * u + 1])
    return max(l1 - 1, 0) + 2 * max(l2 - 1, 0)


@nb.njit(cache=True, inline="always")
def _used_columns(meta, u):
    """Coefficient columns of output u that an evaluation reads (eq. 21, then the soft range)."""
    n_soft = _soft_side_columns(meta, u)
    if n_soft > 0:
        return int(meta[META_SOFT_OFFSET]) + 2 * n_soft
    return int(meta[META_DEGREES + 2 * u]) + 2 * int(meta[META_DEGREES + 2 * u + 1])


# ----------------------------------------------------------------------------------------
# Evaluation with coefficients localised once per track (the forward search)
# ----------------------------------------------------------------------------------------

@nb.njit(cache=True, **NO_REFCOUNT)
def localize_ut_to_scifi(meta, cells, x, y, poly, ref):
    """Interpolate the UT→SciFi coefficients (paper eqs. 22–23) at (x/z, y/z) of z_from.

    poly (3, 4, n_coef): [0] the coefficients, [1] ∂/∂x and [2] ∂/∂y [1/mm] (through the
    interpolation weights), the soft range's from column META_SOFT_OFFSET; ref (2) = (x, y)
    of the localisation point [mm].
    """
    z0 = meta[META_Z_FROM]
    nx = int(meta[META_NX])
    ny = int(meta[META_NY])
    i, xi, fx = _axis_lookup(x / z0, meta[META_SLOPE_X0], meta[META_SLOPE_DX], nx)
    j, psi, fy = _axis_lookup(y / z0, meta[META_SLOPE_Y0], meta[META_SLOPE_DY], ny)
    ex, ey, w, wx, wy = interpolation_weights(xi, psi)
    dxi_dx = fx / z0
    dpsi_dy = fy / z0
    for u in range(4):
        n = _used_columns(meta, u)
        _six_columns(cells, u, i, j, ex, ey, n, w, wx, wy, poly[0, u], poly[1, u], poly[2, u])
        for c in range(n):
            poly[1, u, c] *= dxi_dx
            poly[2, u, c] *= dpsi_dy
    ref[0] = x
    ref[1] = y


@nb.njit(cache=True, **NO_REFCOUNT)
def ut_to_scifi_extrapolate_localized(meta, poly, ref, eloss, s_in, s_out, jac, quadratic):
    """Paper eq. 21 from the last UT layer to the first SciFi layer with localised
    coefficients (`localize_ut_to_scifi`). Writes s_out (5) and jac = ∂out/∂in (5×5).

    eloss [MeV]: the tuned energy loss upstream of the magnet (the slot's parameter 0):
    the table is evaluated at q′ = q/(1 − eloss·|q|), as `pkf.params.transport` does.
    The soft range (p_min > p ≥ p_low) as `ut_to_scifi_extrapolate`; beyond the table's
    range each polynomial is continued quadratically (quadratic=True) or linearly from the
    edge (with the edge's second derivative: of the soft correction, or of the polynomial
    for a table without soft range). Returns STATUS_OK or STATUS_BELOW_P_MIN.
    """
    z0 = meta[META_Z_FROM]
    dz = meta[META_Z_TO] - z0
    p_min = meta[META_P_MIN]
    soft_offset = int(meta[META_SOFT_OFFSET])
    x = s_in[0]
    y = s_in[1]
    tx = s_in[2]
    ty = s_in[3]
    qop = s_in[4]
    shrink = 1.0 - eloss * abs(qop)
    q = qop / shrink
    dq_dqop = 1.0 / (shrink * shrink)
    ddx = x - ref[0]
    ddy = y - ref[1]
    inv_z0 = 1.0 / z0
    sx = x * inv_z0
    sy = y * inv_z0
    beta_x, beta_y, bx_sx, bx_sy, by_sx, by_sy = _ideal_direction(meta, sx, sy, q)
    dtx = tx - sx - beta_x * q
    dty = ty - sy - beta_y * q
    dtx_x = -(1.0 + bx_sx * q) * inv_z0
    dtx_y = -bx_sy * q * inv_z0
    dty_x = -by_sx * q * inv_z0
    dty_y = -(1.0 + by_sy * q) * inv_z0
    w = q * p_min
    wc, e, ec, side, status = _soft_range(meta, w)
    beyond = e - ec
    b2 = 0.5 * beyond * beyond if quadratic else 0.0
    b1 = beyond if quadratic else 0.0
    for a in range(5):
        for b in range(5):
            jac[a, b] = 1.0 if a == b else 0.0
    for u in range(4):
        k1 = int(meta[META_DEGREES + 2 * u])
        k2 = int(meta[META_DEGREES + 2 * u + 1])
        l1 = int(meta[META_SOFT_DEGREES + 2 * u])
        l2 = int(meta[META_SOFT_DEGREES + 2 * u + 1])
        has_soft = _soft_side_columns(meta, u) > 0
        scol = soft_offset + side * _soft_side_columns(meta, u)
        val = 0.0
        val_w = 0.0
        val_x = 0.0
        val_y = 0.0
        poly_b = 0.0
        poly_c = 0.0
        col = 0
        for blk in range(3):
            degree = k1 if blk == 0 else k2
            p = 0.0
            pw = 0.0
            pww = 0.0
            px = 0.0
            pxw = 0.0
            pxww = 0.0
            py = 0.0
            pyw = 0.0
            pyww = 0.0
            wk1 = 1.0  # wc^(k−1)
            wk2 = 0.0  # wc^(k−2)
            for k in range(1, degree + 1):
                cx = poly[1, u, col]
                cy = poly[2, u, col]
                c = poly[0, u, col] + cx * ddx + cy * ddy
                wk = wk1 * wc
                p += c * wk
                pw += k * c * wk1
                pww += k * (k - 1) * c * wk2
                px += cx * wk
                pxw += k * cx * wk1
                pxww += k * (k - 1) * cx * wk2
                py += cy * wk
                pyw += k * cy * wk1
                pyww += k * (k - 1) * cy * wk2
                wk2 = wk1
                wk1 = wk
                col += 1
            if e != 0.0:
                # linear continuation from the edge |w| = 1 over the whole excess e
                p += pw * e
                px += pxw * e
                py += pyw * e
                if has_soft:
                    # the soft correction D(ec) + D'(ec)·beyond (+ ½D''(ec)·beyond²)
                    sw = 0.0
                    sxw = 0.0
                    syw = 0.0
                    pww = 0.0
                    pxww = 0.0
                    pyww = 0.0
                    soft_degree = l1 if blk == 0 else l2
                    ek1 = ec  # ec^(k−1)
                    ek2 = 1.0  # ec^(k−2)
                    for k in range(2, soft_degree + 1):
                        dx_ = poly[1, u, scol]
                        dy_ = poly[2, u, scol]
                        d = poly[0, u, scol] + dx_ * ddx + dy_ * ddy
                        ek = ek1 * ec
                        p += d * ek
                        px += dx_ * ek
                        py += dy_ * ek
                        sw += k * d * ek1
                        sxw += k * dx_ * ek1
                        syw += k * dy_ * ek1
                        pww += k * (k - 1) * d * ek2
                        pxww += k * (k - 1) * dx_ * ek2
                        pyww += k * (k - 1) * dy_ * ek2
                        ek2 = ek1
                        ek1 = ek
                        scol += 1
                    p += sw * beyond
                    px += sxw * beyond
                    py += syw * beyond
                    pw += sw
                    if quadratic:
                        p += pww * b2
                        px += pxww * b2
                        py += pyww * b2
                        pw += pww * b1
                elif quadratic:  # no soft range: the edge's Taylor quadratic (beyond = e)
                    p += pww * b2
                    px += pxww * b2
                    py += pyww * b2
                    pw += pww * b1
            if blk == 0:
                m = 1.0
            elif blk == 1:
                m = dtx
                poly_b = p
            else:
                m = dty
                poly_c = p
            val += m * p
            val_w += m * pw
            val_x += m * px
            val_y += m * py
        if u == 0:
            s_out[0] = x + tx * dz + val
            jac[0, 2] = dz
        elif u == 1:
            s_out[1] = y + ty * dz + val
            jac[1, 3] = dz
        elif u == 2:
            s_out[2] = tx + val
        else:
            s_out[3] = ty + val
        jac[u, 0] += val_x + poly_b * dtx_x + poly_c * dty_x
        jac[u, 1] += val_y + poly_b * dtx_y + poly_c * dty_y
        jac[u, 2] += poly_b
        jac[u, 3] += poly_c
        jac[u, 4] = (val_w * p_min - poly_b * beta_x - poly_c * beta_y) * dq_dqop
    s_out[4] = qop
    return status


@nb.njit(cache=True)
def ut_to_scifi_extrapolate_many(meta, cells, states, states_out, jacs_out, status_out):
    """`ut_to_scifi_extrapolate` for each row of states (n×5) into states_out (n×5),
    jacs_out (n×5×5) and status_out (n, int)."""
    for n in range(states.shape[0]):
        status_out[n] = ut_to_scifi_extrapolate(meta, cells, states[n], states_out[n], jacs_out[n])
