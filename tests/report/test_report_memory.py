"""What `pkf report` keeps per track while it reads a run (issue 17: 10,000 events of ν = 7.6,
~3 M tracks per fitter, in bounded memory): a few bytes per track, nothing that grows with the
run in what the plots keep."""

from __future__ import annotations

import tracemalloc

import numpy as np
from report_helpers import write_synthetic_run

from pkf.io.schemas import particle_key
from pkf.report.metrics import (
    ETA_EDGES,
    P_EDGES_MEV,
    TRACK_TYPES,
    DatasetTruth,
    _fitter_report,
    bin_index,
    read_entries,
)
from pkf.report.runs import load_run

N_TRACKS = 20_000
#: Bytes kept per track of a fitter after reading (first-hit rows of the 80 % matched tracks:
#: p bin int8 + 10 float32 = 41 B; χ²/ndf, ghost flag and type of the ok tracks: 10 B; found
#: flags: 11 B per reconstructible particle): 54 B measured. Before (float64 values and p_true,
#: the matched particle keys of every part): 99 B.
MAX_BYTES_PER_TRACK = 64


def _truth(n_tracks: int) -> DatasetTruth:
    """Every synthetic particle (event i // 100, particle i % 100 + 1) reconstructible as every type."""
    i = np.arange(n_tracks, dtype=np.int64)
    keys = np.sort(particle_key(i // 100, i % 100 + 1))
    p_bin = bin_index(np.full(keys.size, 5000.0), P_EDGES_MEV)
    eta_bin = bin_index(np.full(keys.size, 3.0), ETA_EDGES)
    return DatasetTruth("ok", n_tracks // 100, keys, p_bin, eta_bin,
                        by_type={kind: (keys, p_bin, eta_bin) for kind in TRACK_TYPES[1:]})


def test_bytes_kept_per_track_while_reading(tmp_path):
    write_synthetic_run(tmp_path / "run", n_tracks=N_TRACKS, track_types=("long",))
    run, truth = load_run(tmp_path / "run"), _truth(N_TRACKS)
    tracemalloc.start()
    try:
        before = tracemalloc.get_traced_memory()[0]
        entries = read_entries(run, truth)
        kept = tracemalloc.get_traced_memory()[0] - before
    finally:
        tracemalloc.stop()
    assert entries["parametrized"].total == N_TRACKS
    assert kept / N_TRACKS < MAX_BYTES_PER_TRACK, f"{kept / N_TRACKS:.0f} bytes per track"


def test_plots_keep_histograms_not_tracks(tmp_path):
    """What an entry keeps for the figures until they are drawn does not grow with its tracks;
    the histograms hold every track they stand for."""
    written = write_synthetic_run(tmp_path / "run", n_tracks=2_000, track_types=("long", "velo"))
    run, truth = load_run(tmp_path / "run"), _truth(2_000)
    entries = read_entries(run, truth)
    _, arrays = _fitter_report(run, 0, "parametrized", truth, entries["parametrized"])
    per_track = [value for value in vars(arrays).values() if isinstance(value, np.ndarray) and value.size >= 100]
    assert per_track == []
    ok, ghost, types = (written["parametrized"][k] for k in ("ok", "ghost", "type"))
    assert arrays.chi2_ndf_real.sum() == np.sum(ok & ~ghost)
    assert arrays.chi2_ndf_ghost.sum() == np.sum(ok & ghost)
    for kind in ("long", "velo"):
        real, fake = arrays.chi2_ndf_by_type[kind]
        assert real.sum() == np.sum(ok & ~ghost & (types == kind))
        assert fake.sum() == np.sum(ok & ghost & (types == kind))
    for par, h in arrays.pulls.items():  # long matched tracks: their pulls within ±5 or outside
        assert h.sum(flow=True) == np.sum(ok & ~ghost & (types == "long"))
        assert arrays.pulls_outside[par] <= h.sum(flow=True) - h.sum()


def test_bin_index_selects_the_same_values_as_the_half_open_bins():
    """The int8 bins kept instead of p_true and η select exactly the values [lo, hi) selected."""
    for edges in (P_EDGES_MEV, ETA_EDGES):
        values = np.r_[edges, np.nextafter(edges, -np.inf), np.nextafter(edges, np.inf),
                       np.linspace(edges[0] - 1, edges[-1] + 1, 1001), np.nan, np.inf, -np.inf]
        index = bin_index(values, edges)
        assert index.dtype == np.int8
        for i, (lo, hi) in enumerate(zip(edges[:-1], edges[1:])):
            np.testing.assert_array_equal(index == i, (values >= lo) & (values < hi))
