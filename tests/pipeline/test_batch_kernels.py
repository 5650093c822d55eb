"""The compiled passes of the batch stage (pkf.pipeline.batch_kernels) against the numpy
expressions they replace: same values, same dtypes, bit for bit."""

import numpy as np

from pkf.io.schemas import COV_COLUMNS, pack_covariance, particle_key
from pkf.pipeline.batch_kernels import (
    equal,
    hit_keys,
    match_candidates,
    particle_column_counts,
    pull_columns,
    state_columns,
    subdetector_counts,
)
from pkf.pipeline.matching import _match_sorting, match_tracks, matches_of


def _grouped_tracks(rng, n_tracks=300, n_particles=40):
    n_hits = rng.integers(0, 12, n_tracks)
    offsets = np.concatenate([[0], np.cumsum(n_hits)]).astype(np.int64)
    track_of_hit = np.repeat(np.arange(n_tracks), n_hits)
    particle = rng.integers(0, n_particles, track_of_hit.size).astype(np.int64)  # 0: noise
    return offsets, track_of_hit, particle


def test_hit_keys_are_particle_keys():
    rng = np.random.default_rng(1)
    event = rng.integers(-50, 50, 1000).astype(np.int64)
    pid = rng.integers(0, 30, 1000).astype(np.int64)
    out = np.empty(1000, np.int64)
    hit_keys(event, pid, out)
    assert np.array_equal(out, particle_key(event, pid))


def test_equal_is_array_equal():
    a = np.arange(10, dtype=np.int64)
    assert equal(a, a.copy()) and not equal(a, a[:-1])
    b = a.copy()
    b[7] = -1
    assert not equal(a, b)


def test_grouped_matching_equals_the_sorting_one():
    rng = np.random.default_rng(2)
    offsets, track_of_hit, particle = _grouped_tracks(rng)
    n_tracks = offsets.size - 1
    best, fraction = _match_sorting(track_of_hit, particle, n_tracks)
    matched = fraction >= 0.7
    expected = (np.where(matched, best, -1), fraction, ~matched)
    for got, want in zip(match_tracks(track_of_hit, particle, n_tracks), expected, strict=True):
        assert got.dtype == want.dtype and got.tobytes() == want.tobytes()
    # hits not grouped by track: the sorting path
    shuffled = rng.permutation(track_of_hit.size)
    for got, want in zip(match_tracks(track_of_hit[shuffled], particle[shuffled], n_tracks), expected, strict=True):
        assert got.tobytes() == want.tobytes()


def test_match_candidates_equals_match_tracks_of_all_and_of_velo_hits():
    rng = np.random.default_rng(3)
    offsets, track_of_hit, key = _grouped_tracks(rng)
    n_tracks = offsets.size - 1
    n_layers = 8
    layer_subdetector = np.array([0, 0, 0, 1, 1, 2, 2, -1], dtype=np.int64)
    cand_row = rng.permutation(track_of_hit.size).astype(np.int64)  # candidate hit → hit row
    hit_key = np.empty(track_of_hit.size, np.int64)
    hit_key[cand_row] = key
    layer = rng.integers(0, n_layers, track_of_hit.size).astype(np.int64)
    matches = np.empty((7, n_tracks), np.int64)
    longest = int(np.diff(offsets).max())
    match_candidates(offsets, cand_row, hit_key, layer, layer_subdetector, 0, 2, np.empty((2, longest), np.int64),
                     matches)
    sub = layer_subdetector[layer[cand_row]]
    for got, want in zip(matches_of(*matches[0:3]), match_tracks(track_of_hit, key, n_tracks), strict=True):
        assert got.tobytes() == want.tobytes()
    velo = sub == 0
    for got, want in zip(matches_of(*matches[3:6]), match_tracks(track_of_hit[velo], key[velo], n_tracks),
                         strict=True):
        assert got.tobytes() == want.tobytes()
    assert np.array_equal(matches[5], np.bincount(track_of_hit[velo], minlength=n_tracks))
    assert np.array_equal(matches[6] > 0, np.bincount(track_of_hit, weights=sub == 2, minlength=n_tracks) > 0)


def test_particle_column_counts_equal_unique_and_bincount():
    rng = np.random.default_rng(4)
    key = rng.choice(np.array([0, 5, 1 << 30, 7 << 24, 3, 99], dtype=np.int64), 2000)
    layer = rng.integers(0, 6, key.size).astype(np.int64)
    column_of_layer = np.array([0, 0, 1, 2, 3, 3], dtype=np.int64)
    keys, counts = particle_column_counts(key, layer, column_of_layer, 4)
    order = np.argsort(keys)
    signal = key > 0
    want_keys, inverse = np.unique(key[signal], return_inverse=True)
    want = np.bincount(inverse * 4 + column_of_layer[layer[signal]], minlength=want_keys.size * 4)
    assert np.array_equal(keys[order], want_keys)
    assert counts.dtype == want.dtype and np.array_equal(counts[order], want.reshape(-1, 4))


def test_subdetector_counts_equal_masked_bincounts():
    rng = np.random.default_rng(5)
    offsets, track_of_node, _ = _grouped_tracks(rng)
    layer_subdetector = np.array([0, 1, 2, 2, -1], dtype=np.int64)
    layer = rng.integers(0, 5, track_of_node.size).astype(np.int64)
    active = rng.random(track_of_node.size) < 0.8
    out = np.zeros((3, offsets.size - 1), np.int64)
    subdetector_counts(offsets, layer, layer_subdetector, active, out)
    for s in range(3):
        sel = (layer_subdetector[layer] == s) & active
        assert np.array_equal(out[s], np.bincount(track_of_node[sel], minlength=offsets.size - 1))


def test_state_and_pull_columns_equal_the_numpy_ones():
    rng = np.random.default_rng(6)
    n = 50
    z, state = rng.normal(size=n), rng.normal(size=(n, 5))
    cov = rng.normal(size=(n, 5, 5))
    cov[0, 1, 1], cov[1, 2, 2], cov[2, 3, 3] = np.nan, -0.0, 0.0  # NaN, signed and unsigned zero variances
    rows = np.flatnonzero(rng.random(n) < 0.6)
    values = np.empty((21, rows.size))
    state_columns(rows, z, state, cov, values)
    packed = pack_covariance(cov[rows])
    assert values[0].tobytes() == z[rows].tobytes()
    assert values[1:6].tobytes() == np.ascontiguousarray(state[rows].T).tobytes()
    assert all(values[6 + k].tobytes() == packed[name].tobytes() for k, name in enumerate(COV_COLUMNS))
    rows = np.arange(n)
    truth = rng.normal(size=(n, 5))
    out = np.empty((11, n))
    with np.errstate(divide="ignore", invalid="ignore"):
        pull_columns(rows, state, cov, truth, out)
        res = state - truth
        sigma = np.sqrt(np.maximum(np.einsum("nii->ni", cov), 0.0))
        assert out[0].tobytes() == (1.0 / np.abs(truth[:, 4])).tobytes()
        assert out[1:6].tobytes() == np.ascontiguousarray(res.T).tobytes()
        assert out[6:].tobytes() == np.ascontiguousarray((res / sigma).T).tobytes()
