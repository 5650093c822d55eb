"""The truth a pull compares with is the matched particle's, also where a track's first or last hit
is another particle's (`pkf.pipeline.matching.particle_truth_at_hits`, issue 15)."""

import numpy as np

from pkf.pipeline.matching import particle_truth_at_hits


def _hits():
    # rows: particle 7 on layers 0, 1 (z 100, 110), particle 9 on layer 0 (z 101: the other side
    # of the module), noise on layer 1, particle 7 on layer 2 with no other hit there
    key = np.array([7, 7, 9, 0, 7, 9])
    layer = np.array([0, 1, 0, 1, 2, 3])
    z = np.array([100.0, 110.0, 101.0, 110.0, 120.0, 130.0])
    state = np.array([[1.0, 2.0, 0.1, -0.2, 1e-3],
                      [2.0, 0.0, 0.1, -0.2, 1e-3],
                      [5.0, 5.0, 0.3, 0.3, -2e-3],
                      [np.nan] * 5,
                      [3.0, -2.0, 0.1, -0.2, 1e-3],
                      [0.0, 0.0, 0.0, 0.0, 1e-4]])
    return key, state, z, layer


def test_own_hits_keep_their_mc_state():
    key, state, z, layer = _hits()
    rows = np.array([0, 1, 4])
    out = particle_truth_at_hits(rows, np.full(3, 7), key, state, z, layer)
    np.testing.assert_array_equal(out, state[rows])


def test_a_foreign_hit_takes_the_particles_own_hit_on_its_layer_moved_to_its_z():
    key, state, z, layer = _hits()
    # track of particle 7 whose first hit is particle 9's (layer 0, z 101) and last hit noise
    out = particle_truth_at_hits(np.array([2, 3]), np.array([7, 7]), key, state, z, layer)
    expected_first = state[0] + np.array([0.1, -0.2, 0.0, 0.0, 0.0]) * 1.0  # moved by Δz = +1 mm
    np.testing.assert_allclose(out[0], expected_first, rtol=0, atol=1e-15)
    np.testing.assert_array_equal(out[1], state[1])  # same plane: Δz = 0
    # and particle 9's hit asked for particle 9 is its own
    np.testing.assert_array_equal(particle_truth_at_hits(np.array([2]), np.array([9]), key, state, z, layer)[0],
                                  state[2])


def test_no_own_hit_on_the_layer_gives_nan():
    key, state, z, layer = _hits()
    out = particle_truth_at_hits(np.array([5, 4]), np.array([7, 9]), key, state, z, layer)
    assert np.all(np.isnan(out))


def test_the_lookup_equals_a_brute_force_search():
    """Random hits with repeated (particle, layer) pairs, repeated requests and missing pairs:
    the first own row of each request, as a plain search finds it."""
    rng = np.random.default_rng(3)
    n = 5000
    key = rng.integers(0, 300, n)  # 0: noise
    layer = rng.integers(0, 40, n)
    z = layer * 10.0 + rng.random(n)
    state = rng.normal(size=(n, 5))
    rows = rng.integers(0, n, 2000)
    wanted = np.where(rng.random(rows.size) < 0.5, key[rows], rng.integers(1, 300, rows.size))
    wanted = np.maximum(wanted, 1)
    out = particle_truth_at_hits(rows, wanted, key, state, z, layer)
    for i, (r, w) in enumerate(zip(rows, wanted)):
        if key[r] == w:
            np.testing.assert_array_equal(out[i], state[r])
            continue
        own = np.flatnonzero((key == w) & (layer == layer[r]))
        if own.size == 0:
            assert np.all(np.isnan(out[i]))
            continue
        expected = state[own[0]].copy()
        expected[:2] += expected[2:4] * (z[r] - z[own[0]])
        np.testing.assert_array_equal(out[i], expected)
