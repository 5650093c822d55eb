"""B_s candidates from all kaon tracks (pkf.report.combinatorics): exact masses on constructed
kinematics, the φ window, distinct kaons, the vertex cut."""

import numpy as np

from pkf.physics.constants import MASS_KAON, MASS_PHI
from pkf.report.combinatorics import PHI_WINDOW, VERTEX_DZ, combinatorial_bs_masses


def _track_state(p, direction, charge):
    """(qop, tx, ty) of a track of momentum p [MeV] along direction (x, y, z>0)."""
    d = np.asarray(direction, float)
    return charge / p, d[0] / d[2], d[1] / d[2]


def _phi_decay(p_phi, direction):
    """Two kaons of a φ at rest boost: back to back in the φ frame across the direction,
    boosted along it; returns two (p_vec) momenta."""
    d = np.asarray(direction, float) / np.linalg.norm(direction)
    perp = np.cross(d, [0.0, 1.0, 0.0])
    perp /= np.linalg.norm(perp)
    q = np.sqrt((MASS_PHI / 2) ** 2 - MASS_KAON**2)  # kaon momentum in the φ frame
    e_phi = np.hypot(p_phi, MASS_PHI)
    gamma, beta_gamma = e_phi / MASS_PHI, p_phi / MASS_PHI
    e_k = MASS_PHI / 2
    along = beta_gamma * e_k  # boosted longitudinal momentum of each kaon (transverse q)
    return [along * d + q * perp, along * d - q * perp], gamma


def _kaons(event, p_phi, dirs, z):
    rows = []
    for direction in dirs:
        (k1, k2), _ = _phi_decay(p_phi, direction)
        for vec, charge in ((k1, +1), (k2, -1)):
            p = np.linalg.norm(vec)
            rows.append((event, *_track_state(p, vec, charge), z))
    return rows


def test_two_phis_give_their_mass_and_nothing_else():
    rows = _kaons(1, 20000.0, [(0.05, 0.02, 1.0), (-0.03, 0.04, 1.0)], z=3.0)
    event, qop, tx, ty, z = (np.array(c) for c in zip(*rows))
    masses, signal = combinatorial_bs_masses(event, qop, tx, ty, z, np.ones(4, bool))
    assert masses.size == 1 and signal.all()
    # the sum of two φ four-momenta: check against a direct computation
    mom = []
    for q, a, b in zip(qop, tx, ty):
        p = 1 / abs(q)
        pz = p / np.sqrt(1 + a * a + b * b)
        mom.append([np.hypot(p, MASS_KAON), a * pz, b * pz, pz])
    total = np.sum(mom, axis=0)
    assert abs(masses[0] - np.sqrt(total[0] ** 2 - np.sum(total[1:] ** 2))) < 1e-6


def test_wrong_charge_pairs_and_far_vertices_are_no_candidates():
    rows = _kaons(1, 20000.0, [(0.05, 0.02, 1.0), (-0.03, 0.04, 1.0)], z=3.0)
    event, qop, tx, ty, z = (np.array(c, dtype=float) for c in zip(*rows))
    event = event.astype(np.int64)
    far = z.copy()
    far[2:] += 2 * VERTEX_DZ  # the second φ from another pile-up vertex
    assert combinatorial_bs_masses(event, qop, tx, ty, far, np.ones(4, bool))[0].size == 0
    other_event = event.copy()
    other_event[2:] = 2  # the second φ in another event
    assert combinatorial_bs_masses(other_event, qop, tx, ty, z, np.ones(4, bool))[0].size == 0
    assert PHI_WINDOW < 50


def test_combinations_grow_with_more_kaons():
    """Three φ in one event: three pairs of φ, each a candidate (background for all but one)."""
    rows = _kaons(7, 15000.0, [(0.15, 0.02, 1.0), (-0.13, 0.04, 1.0), (0.01, -0.16, 1.0)], z=0.0)
    event, qop, tx, ty, z = (np.array(c) for c in zip(*rows))
    signal = np.array([True] * 4 + [False] * 2)
    masses, is_signal = combinatorial_bs_masses(event.astype(np.int64), qop, tx, ty, z, signal)
    assert masses.size == 3 and is_signal.sum() == 1
