"""The propagator's navigator (pkf.fit.propagate): which planes it visits, in which order."""

from typing import NamedTuple

import numba as nb
import numpy as np
import pytest

from pkf.fit.propagate import propagate, register_actor
from pkf.fit.status import STATUS_EXTRAPOLATION_FAILED, STATUS_OK


class _Planes(NamedTuple):
    plane_z: np.ndarray


class _Recorder(NamedTuple):
    """Test actor: records the segments (z_from, z_to, crossed) and the planes (k, direction)."""

    segments: np.ndarray
    planes: np.ndarray
    counts: np.ndarray
    fail_at_plane: int


@nb.njit
def _record_transport(actor, ext, z_from, z_to, crossed):
    i = actor.counts[0]
    actor.segments[i, 0] = z_from
    actor.segments[i, 1] = z_to
    actor.segments[i, 2] = crossed
    actor.counts[0] = i + 1
    return STATUS_OK


@nb.njit
def _record_interact(actor, ext, k, direction):
    i = actor.counts[1]
    actor.planes[i, 0] = k
    actor.planes[i, 1] = direction
    actor.counts[1] = i + 1
    return STATUS_EXTRAPOLATION_FAILED if k == actor.fail_at_plane else STATUS_OK


register_actor(_Recorder, _record_transport, _record_interact)


@nb.njit
def _run(ext, actor, z_from, z_to):
    return propagate(ext, actor, z_from, z_to)


def _propagate(z_from, z_to, fail_at_plane=-1):
    ext = _Planes(np.array([100.0, 200.0, 300.0, 400.0]))
    actor = _Recorder(np.zeros((10, 3)), np.zeros((10, 2)), np.zeros(2, dtype=np.int64), fail_at_plane)
    status = _run(ext, actor, z_from, z_to)
    return status, actor.segments[:actor.counts[0]].tolist(), actor.planes[:actor.counts[1]].tolist()


@pytest.mark.parametrize(("z_from", "z_to", "planes", "direction"), [
    (100.0, 300.0, [1, 2], 1.0),  # downstream: planes in (z_from, z_to]
    (50.0, 250.0, [0, 1], 1.0),
    (300.0, 100.0, [2, 1], -1.0),  # upstream: planes in (z_to, z_from], in flight order
    (350.0, 50.0, [2, 1, 0], -1.0),
    (150.0, 180.0, [], 1.0),
    (200.0, 200.0, [], 1.0),
])
def test_planes_in_the_half_open_range_in_flight_order(z_from, z_to, planes, direction):
    status, segments, visited = _propagate(z_from, z_to)
    assert status == STATUS_OK
    assert [int(k) for k, _ in visited] == planes
    assert all(d == direction for _, d in visited)
    plane_z = [100.0, 200.0, 300.0, 400.0]
    # one segment before each plane and one to the end, chained, with the planes crossed so far
    stops = [z_from] + [plane_z[k] for k in planes] + [z_to]
    assert segments == [[a, b, i] for i, (a, b) in enumerate(zip(stops[:-1], stops[1:]))]


def test_a_failing_actor_stops_the_propagation():
    status, segments, visited = _propagate(50.0, 450.0, fail_at_plane=1)
    assert status == STATUS_EXTRAPOLATION_FAILED
    assert [int(k) for k, _ in visited] == [0, 1]
    assert len(segments) == 2  # nothing transported after the failure
