"""Transport of particles through the detector and its response (docs/physics.md#simulation).

One compiled kernel per batch of events: Runge–Kutta through the analytic field from the
production vertex through every plane; at each crossed plane inside its active area a
hit (efficiency, Gaussian smearing in the measured coordinate(s)) and the material
effects (Highland scattering, Bethe energy loss with Moyal fluctuations,
Bethe–Heitler bremsstrahlung for electrons); then noise hits uniformly over each
layer's active area. numba's generator is re-seeded per event, so an event's content
does not depend on how events are batched.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numba as nb
import numpy as np

from pkf.geometry.acceptance import in_active_area
from pkf.geometry.detector import KIND_PIXEL, SIDE_LEFT, SIDE_RIGHT, Geometry
from pkf.physics.materials import (
    SI_X0_MM,
    apply_bremsstrahlung_to_qop,
    apply_energy_loss_to_qop,
    apply_scattering,
    highland_theta0,
    sample_bremsstrahlung_fraction,
    sample_energy_loss,
)
from pkf.physics.transport import rk4_propagate_scalar

#: Longest Runge–Kutta step [mm]; transport also checks the envelope after each one.
SIMULATION_MAX_STEP = 100.0


@dataclass
class HitRecords:
    """Hits of a batch (particle hits then noise), unsorted. `event` is the index of the
    event in the batch; `particle` the index of the particle in the batch, −1 for noise."""

    event: np.ndarray
    particle: np.ndarray
    layer: np.ndarray
    u: np.ndarray
    v: np.ndarray
    x: np.ndarray
    y: np.ndarray
    z: np.ndarray
    tx: np.ndarray
    ty: np.ndarray
    qop: np.ndarray


@nb.njit(cache=True)
def _simulate_batch(
    event_seeds, event_offsets, start_state, start_z, stop_z, mass, charge, is_electron,
    plane_z, plane_layer, plane_x0, plane_half_x, plane_half_y, plane_hole_r,
    plane_hole_hx, plane_hole_hy, plane_side, plane_overlap,
    layer_kind, layer_cos, layer_sin, layer_sigma, layer_efficiency, layer_noise,
    layer_plane, envelope_half_width, envelope_max_slope, envelope_min_p, max_step,
    field_kind, field_params, field_grid, out_int, out_float,
):
    """Transport particles event by event and record hits.

    out_int columns: event, particle, layer; out_float: u, v, x, y, z, tx, ty, qop.
    Returns the number of hits written, or −1 if the output arrays are too small.
    """
    capacity = out_int.shape[0]
    n_hits = 0
    n_planes = plane_z.size
    for ev in range(event_seeds.size):
        np.random.seed(event_seeds[ev])
        for ip in range(event_offsets[ev], event_offsets[ev + 1]):
            x = start_state[ip, 0]
            y = start_state[ip, 1]
            tx = start_state[ip, 2]
            ty = start_state[ip, 3]
            qop = start_state[ip, 4]
            z = start_z[ip]
            if charge[ip] == 0 or not np.isfinite(qop) or 1.0 / abs(qop) < envelope_min_p:
                continue
            for k in range(n_planes):
                zp = plane_z[k]
                if zp <= z:
                    continue
                if zp > stop_z[ip]:  # decayed before this plane
                    break
                # Transport in steps of at most max_step, checking the envelope.
                alive = True
                while z < zp:
                    z_next = min(zp, z + max_step)
                    x, y, tx, ty = rk4_propagate_scalar(
                        x, y, tx, ty, qop, z, z_next, max_step, field_kind, field_params, field_grid
                    )
                    z = z_next
                    if not (abs(x) <= envelope_half_width and abs(y) <= envelope_half_width
                            and abs(tx) <= envelope_max_slope and abs(ty) <= envelope_max_slope):
                        alive = False
                        break
                if not alive:
                    break
                if not in_active_area(x, y, plane_half_x[k], plane_half_y[k], plane_hole_r[k],
                                      plane_hole_hx[k], plane_hole_hy[k], plane_side[k],
                                      plane_overlap[k]):
                    continue
                layer = plane_layer[k]
                record = False
                if layer >= 0 and np.random.random() < layer_efficiency[layer]:
                    record = True
                    if n_hits >= capacity:
                        return -1
                    sigma = layer_sigma[layer]
                    out_int[n_hits, 0] = ev
                    out_int[n_hits, 1] = ip
                    out_int[n_hits, 2] = layer
                    if layer_kind[layer] == KIND_PIXEL:
                        out_float[n_hits, 0] = x + sigma * np.random.normal()
                        out_float[n_hits, 1] = y + sigma * np.random.normal()
                    else:
                        u = x * layer_cos[layer] + y * layer_sin[layer]
                        out_float[n_hits, 0] = u + sigma * np.random.normal()
                        out_float[n_hits, 1] = np.nan
                    out_float[n_hits, 2] = x
                    out_float[n_hits, 3] = y
                    out_float[n_hits, 4] = zp
                # Material effects of a thin plane (docs/physics.md#material-effects).
                tx_in, ty_in, qop_in = tx, ty, qop
                t = plane_x0[k] * math.sqrt(1.0 + tx * tx + ty * ty)
                if t > 0.0:
                    p = 1.0 / abs(qop)
                    theta0 = highland_theta0(p, mass[ip], charge[ip], t)
                    tx, ty = apply_scattering(tx, ty, theta0)
                    qop = apply_energy_loss_to_qop(qop, mass[ip], sample_energy_loss(p, mass[ip], t * SI_X0_MM))
                    if is_electron[ip] and np.isfinite(qop):
                        qop = apply_bremsstrahlung_to_qop(qop, mass[ip], sample_bremsstrahlung_fraction(t))
                stopped = not (np.isfinite(qop) and np.isfinite(tx) and np.isfinite(ty)
                               and 1.0 / abs(qop) >= envelope_min_p)
                if record:
                    # a particle that stops in this plane keeps its incoming state as the
                    # truth of its last hit (its state after the material is not defined)
                    out_float[n_hits, 5] = tx_in if stopped else tx
                    out_float[n_hits, 6] = ty_in if stopped else ty
                    out_float[n_hits, 7] = qop_in if stopped else qop
                    n_hits += 1
                if stopped:
                    break
        # Noise hits: a Poisson number per layer, uniform over the active area.
        for layer in range(layer_kind.size):
            k = layer_plane[layer]
            n_noise = np.random.poisson(layer_noise[layer]) if layer_noise[layer] > 0.0 else 0
            x_lo = -plane_half_x[k]
            x_hi = plane_half_x[k]
            if plane_side[k] == SIDE_LEFT:
                x_hi = min(x_hi, plane_overlap[k])
            elif plane_side[k] == SIDE_RIGHT:
                x_lo = max(x_lo, -plane_overlap[k])
            for _ in range(n_noise):
                if n_hits >= capacity:
                    return -1
                while True:
                    x = np.random.uniform(x_lo, x_hi)
                    y = np.random.uniform(-plane_half_y[k], plane_half_y[k])
                    if in_active_area(x, y, plane_half_x[k], plane_half_y[k], plane_hole_r[k],
                                      plane_hole_hx[k], plane_hole_hy[k], plane_side[k],
                                      plane_overlap[k]):
                        break
                out_int[n_hits, 0] = ev
                out_int[n_hits, 1] = -1
                out_int[n_hits, 2] = layer
                if layer_kind[layer] == KIND_PIXEL:
                    out_float[n_hits, 0] = x
                    out_float[n_hits, 1] = y
                else:
                    out_float[n_hits, 0] = x * layer_cos[layer] + y * layer_sin[layer]
                    out_float[n_hits, 1] = np.nan
                out_float[n_hits, 2] = x
                out_float[n_hits, 3] = y
                out_float[n_hits, 4] = plane_z[k]
                out_float[n_hits, 5] = np.nan
                out_float[n_hits, 6] = np.nan
                out_float[n_hits, 7] = np.nan
                n_hits += 1
    return n_hits


def decay_z(event_offsets: np.ndarray, parent_id: np.ndarray, vz: np.ndarray) -> np.ndarray:
    """z [mm] where each particle of a batch decays: the smallest production z of its
    daughters (parent_id: 1-based position within the event, 0 for none), +inf for a
    particle without daughters. event_offsets: CSR offsets of the events' particles."""
    stop = np.full(vz.size, np.inf)
    event = np.repeat(np.arange(event_offsets.size - 1), np.diff(event_offsets))
    child = parent_id > 0
    parent_index = event_offsets[event[child]] + parent_id[child] - 1
    np.minimum.at(stop, parent_index, vz[child])
    return stop


def simulate_response(
    geometry: Geometry,
    event_seeds: np.ndarray,
    event_offsets: np.ndarray,
    start_state: np.ndarray,
    start_z: np.ndarray,
    mass: np.ndarray,
    charge: np.ndarray,
    is_electron: np.ndarray,
    max_step: float = SIMULATION_MAX_STEP,
    stop_z: np.ndarray | None = None,
) -> HitRecords:
    """Transport a batch of particles and return their hits plus noise hits.

    event_seeds: uint32 seed per event; event_offsets: CSR offsets of each event's
    particles; start_state: (n, 5) production state (x, y, tx, ty, qop) at start_z [mm];
    neutral particles (charge 0) and those with pz ≤ 0 (qop NaN) make no hits; stop_z:
    z [mm] where each particle decays (no hits on planes beyond it), default never.
    """
    if stop_z is None:
        stop_z = np.full(start_z.size, np.inf)
    planes = geometry.planes
    layer_plane = geometry.layer_plane
    env = geometry.envelope
    field = geometry.field
    expected_noise = float(np.sum(geometry.layer_noise_hits))
    capacity = int(start_z.size * geometry.n_layers + event_seeds.size * (3 * expected_noise + 50))
    while True:
        out_int = np.empty((capacity, 3), dtype=np.int64)
        out_float = np.empty((capacity, 8), dtype=np.float64)
        n = _simulate_batch(
            event_seeds.astype(np.int64), event_offsets.astype(np.int64),
            np.ascontiguousarray(start_state, dtype=np.float64), start_z.astype(np.float64),
            stop_z.astype(np.float64),
            mass.astype(np.float64), charge.astype(np.int64), is_electron.astype(np.bool_),
            planes.z, planes.layer, planes.x_over_x0, planes.half_x, planes.half_y,
            planes.hole_radius, planes.hole_half_x, planes.hole_half_y, planes.side,
            planes.side_overlap, geometry.layer_kind, geometry.layer_cos, geometry.layer_sin,
            geometry.layer_sigma, geometry.layer_efficiency, geometry.layer_noise_hits,
            layer_plane, env.half_width, env.max_slope, env.min_momentum, max_step,
            *field.args, out_int, out_float,
        )
        if n >= 0:
            break
        capacity *= 2
    i, f = out_int[:n], out_float[:n]
    return HitRecords(
        event=i[:, 0], particle=i[:, 1], layer=i[:, 2], u=f[:, 0], v=f[:, 1], x=f[:, 2],
        y=f[:, 3], z=f[:, 4], tx=f[:, 5], ty=f[:, 6], qop=f[:, 7],
    )
