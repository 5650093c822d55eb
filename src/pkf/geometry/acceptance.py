"""Whether a point lies on a plane's active (and material) area — shared by simulation and fits."""

from __future__ import annotations

import numba as nb

from pkf.geometry.detector import SIDE_LEFT, SIDE_RIGHT


@nb.njit(cache=True)
def in_active_area(x, y, half_x, half_y, hole_radius, hole_half_x, hole_half_y, side, overlap):
    """True if (x, y) [mm] lies on the plane: inside the outer half-widths, outside the
    round (hole_radius) or square (hole_half_x, hole_half_y) beam hole, and on the side
    the plane covers (SIDE_LEFT: x ≤ +overlap, SIDE_RIGHT: x ≥ −overlap)."""
    if abs(x) > half_x or abs(y) > half_y:
        return False
    if hole_radius > 0.0 and x * x + y * y < hole_radius * hole_radius:
        return False
    if hole_half_x > 0.0 and abs(x) < hole_half_x and abs(y) < hole_half_y:
        return False
    if side == SIDE_LEFT and x > overlap:
        return False
    if side == SIDE_RIGHT and x < -overlap:
        return False
    return True
