"""Why long-track q/p pulls are wider on minimum bias than on a gun (issue 15, acceptance 1.00 ± 0.05).

Reads a run of `pkf reconstruct` with MC (triplet pattern; e.g. the run `benchmarks/fit_quality.py`
makes) and its dataset, and prints, for the real (non-ghost) long candidates:

1. the first-hit q/p pull core per fitter and true-momentum bin, split by the candidate's hits
   (``clean``: every hit is the matched particle's; ``foreign UT``: a UT hit of another particle
   or noise; ``foreign SciFi`` / ``foreign VELO`` likewise) and by the particle's true species
   (the fit assumes a pion);
2. a refit of the real long candidates that hold a foreign UT hit, three ways — as found, without
   the foreign UT hits, and with the particle's own UT hit on those layers — with the
   parametrized and the reference fitter (their default passes; least-squares seeds, since the
   run's pattern state is not stored).

    PYTHONPATH=src python benchmarks/foreign_hits.py RUN_DIR DATASET_DIR

Pull cores are `pkf.params.gauss.gaussian_core` widths ± their errors; bins in GeV.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pyarrow.dataset as ds

from pkf.fit.beamline import straight_line_extrapolator
from pkf.fit.candidates import Candidates
from pkf.fit.fitters import get_fitter
from pkf.fit.options import FitOptions
from pkf.fit.tracks import TrackBatch, seed_batch
from pkf.geometry import load_geometry
from pkf.geometry.detector import SUBDETECTORS
from pkf.params.gauss import gaussian_core

KEY = 1 << 32
P_BINS_MEV = ((1500.0, 3000.0), (3000.0, 5000.0), (5000.0, 10000.0), (10000.0, 100000.0))
SPECIES = {"pion": 211, "kaon": 321, "proton": 2212, "muon": 13, "electron": 11}


def _table(root: Path, name: str):
    for path in (root / name, root / f"{name}.parquet"):
        if path.exists():
            return ds.dataset(path).to_table()
    raise FileNotFoundError(f"{root}: no {name} table")


def _col(table, name, dtype=None):
    values = table.column(name).to_numpy(zero_copy_only=False)
    return values.astype(dtype) if dtype is not None else values


def _cores(pull: np.ndarray, p_true: np.ndarray, select: np.ndarray) -> str:
    cells = []
    for lo, hi in P_BINS_MEV:
        sel = select & (p_true >= lo) & (p_true < hi)
        core = gaussian_core(pull[sel])
        cells.append(f"{core.sigma:5.2f}±{core.sigma_error:4.2f} ({sel.sum():5d})")
    return " | ".join(cells)


def _header() -> str:
    return " | ".join(f"{lo / 1000:g}–{hi / 1000:g} GeV".center(18) for lo, hi in P_BINS_MEV)


class Sample:
    """The run's real long candidates with the truth of their hits."""

    def __init__(self, run: Path, dataset: Path, fitter: str = "reference"):
        self.geometry = load_geometry("lhcb-like")
        hits, mc = _table(dataset, "hits"), _table(dataset, "mc_hits")
        self.hit_event = _col(hits, "event_id", np.int64)
        hit_key = self.hit_event * KEY + _col(hits, "hit_id", np.int64)
        if np.any(np.diff(hit_key) <= 0):
            raise SystemExit("hits are expected sorted by (event, hit_id)")
        self.layer = _col(hits, "layer", np.int64)
        self.hit_columns = [_col(hits, c, float) for c in ("u", "v", "sigma_u", "sigma_v")]
        mc_key = _col(mc, "event_id", np.int64) * KEY + _col(mc, "hit_id", np.int64)
        mc_order = np.argsort(mc_key)
        mc_row = mc_order[np.searchsorted(mc_key[mc_order], hit_key)]
        self.hit_particle = _col(mc, "particle_id", np.int64)[mc_row]
        self.hit_truth = np.column_stack([_col(mc, c, float)[mc_row] for c in ("x", "y", "tx", "ty", "qop")])
        particles = _table(dataset, "particles")
        pkey = _col(particles, "event_id", np.int64) * KEY + _col(particles, "particle_id", np.int64)
        order = np.argsort(pkey)
        self.particle_key = pkey[order]
        momentum = np.sqrt(sum(_col(particles, c, float) ** 2 for c in ("px", "py", "pz")))
        self.particle_qop = (_col(particles, "charge", float) / momentum)[order]
        self.particle_pdg = np.abs(_col(particles, "pdg", np.int64))[order]
        cand = _table(run, "candidates")
        self.cand_event = _col(cand, "event_id", np.int64)
        self.cand_track = _col(cand, "track_id", np.int64)
        self.cand_row = np.searchsorted(hit_key, self.cand_event * KEY + _col(cand, "hit_id", np.int64))
        chi2 = _table(run, "chi2")
        mine = _col(chi2, "fitter") == fitter
        track_key = (_col(chi2, "event_id", np.int64) * KEY + _col(chi2, "track_id", np.int64))[mine]
        order = np.argsort(track_key)
        self.track_key = track_key[order]
        self.track_particle = _col(chi2, "mc_particle_id", np.int64)[mine][order]
        self.real_long = ((_col(chi2, "track_type")[mine] == "long") & ~_col(chi2, "is_ghost")[mine])[order]
        self.cand_track_index = np.searchsorted(self.track_key, self.cand_event * KEY + self.cand_track)
        cand_sub = self.geometry.layer_subdetector[self.layer[self.cand_row]]
        self.foreign = self.hit_particle[self.cand_row] != self.track_particle[self.cand_track_index]
        self.foreign_ut = self.foreign & (cand_sub == SUBDETECTORS.index("ut"))
        self.n_foreign = {name: np.bincount(self.cand_track_index[self.foreign & (cand_sub == i)],
                                            minlength=self.track_key.size)
                          for i, name in enumerate(SUBDETECTORS) if name in ("velo", "ut", "scifi")}

    def track_of(self, event: np.ndarray, track: np.ndarray) -> np.ndarray:
        return np.searchsorted(self.track_key, event * KEY + track)

    def species_of(self, tracks: np.ndarray) -> np.ndarray:
        key = self.track_key[tracks] // KEY * KEY + self.track_particle[tracks]
        pos = np.minimum(np.searchsorted(self.particle_key, key), self.particle_key.size - 1)
        return np.where(self.particle_key[pos] == key, self.particle_pdg[pos], 0)


def run_pulls(sample: Sample, run: Path) -> None:
    """Section 1: the run's own first-hit q/p pulls, split by foreign hits and by species."""
    pulls = _table(run, "pulls")
    print(f"{'':31s}{_header()}")
    for fitter in sorted(set(_col(pulls, "fitter"))):
        sel = (_col(pulls, "fitter") == fitter) & (_col(pulls, "location") == "first_hit")
        tracks = sample.track_of(_col(pulls, "event_id", np.int64)[sel], _col(pulls, "track_id", np.int64)[sel])
        pull, p_true = _col(pulls, "pull_qop", float)[sel], _col(pulls, "p_true", float)[sel]
        real = sample.real_long[tracks]
        f = {name: counts[tracks] > 0 for name, counts in sample.n_foreign.items()}
        clean = ~(f["velo"] | f["ut"] | f["scifi"])
        print(f"{fitter}: real long candidates {real.sum()}, with a foreign VELO/UT/SciFi hit "
              f"{(real & f['velo']).sum()}/{(real & f['ut']).sum()}/{(real & f['scifi']).sum()}")
        species = sample.species_of(tracks)
        rows = [("all", real), ("clean", real & clean), ("foreign UT", real & f["ut"]),
                ("foreign SciFi, not UT", real & f["scifi"] & ~f["ut"]),
                ("foreign VELO", real & f["velo"])]
        rows += [(f"{name}", real & (species == pdg)) for name, pdg in SPECIES.items()]
        rows += [(f"{name}, clean", real & clean & (species == pdg)) for name, pdg in SPECIES.items()
                 if name in ("pion", "kaon", "proton")]
        for name, select in rows:
            print(f"  {name:29s}{_cores(pull, p_true, select)}")


def refits(sample: Sample) -> None:
    """Section 2: refit the real long candidates with a foreign UT hit three ways."""
    g = sample.geometry
    has_foreign_ut = np.bincount(sample.cand_track_index[sample.foreign_ut], minlength=sample.track_key.size) > 0
    in_sample = (sample.real_long & has_foreign_ut)[sample.cand_track_index]
    # the particle's own hit on the layer of each candidate hit, if it has one
    hit_group = (sample.hit_event * KEY + np.maximum(sample.hit_particle, 0)) * 64 + sample.layer
    order = np.argsort(hit_group, kind="stable")
    wanted = ((sample.cand_event * KEY + sample.track_particle[sample.cand_track_index]) * 64
              + sample.layer[sample.cand_row])
    pos = np.minimum(np.searchsorted(hit_group[order], wanted), order.size - 1)
    own_row = order[pos]
    has_own = hit_group[own_row] == wanted
    variants = {
        "as found": (in_sample, sample.cand_row),
        "without the foreign UT hits": (in_sample & ~sample.foreign_ut, sample.cand_row),
        "with the particle's own UT hits": (in_sample & ~(sample.foreign_ut & ~has_own),
                                            np.where(sample.foreign_ut & has_own, own_row, sample.cand_row)),
    }
    field = g.reconstruction_field()
    beamline = straight_line_extrapolator(g)
    print(f"refit of the {np.unique(sample.cand_track_index[in_sample]).size} real long candidates with a "
          f"foreign UT hit")
    print(f"{'':48s}{_header()}")
    for name, (select, rows) in variants.items():
        candidates = Candidates.from_hit_lists(sample.cand_event[select], sample.cand_track[select], rows[select])
        batch = TrackBatch.from_candidates(g, candidates, sample.layer, *sample.hit_columns)
        seeds, covs, _ = seed_batch(batch, field)
        first_row = batch.hit_row[batch.offsets[:-1]]
        tracks = sample.track_of(candidates.event_id, candidates.track_id)
        key = candidates.event_id * KEY + sample.track_particle[tracks]
        production_qop = sample.particle_qop[np.minimum(np.searchsorted(sample.particle_key, key),
                                                        sample.particle_key.size - 1)]
        local_qop = sample.hit_truth[first_row, 4]
        for fitter_name in ("parametrized", "reference"):
            fitter = get_fitter(fitter_name)
            options = FitOptions.from_flat(iterations=fitter.iterations)
            result = fitter.fit(fitter.make_extrapolator(g), batch, options, seeds, covs, beamline)
            _, state, cov = result.locations["first_hit"]
            truth = production_qop if fitter.qop_at_production else local_qop
            pull = (state[:, 4] - truth) / np.sqrt(cov[:, 4, 4])
            print(f"  {name:33s}{fitter_name:13s}{_cores(pull, 1.0 / np.abs(local_qop), result.status == 0)}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run", type=Path)
    parser.add_argument("dataset", type=Path)
    parser.add_argument("--no-refit", action="store_true", help="only the run's own pulls (section 1)")
    args = parser.parse_args(argv)
    sample = Sample(args.run, args.dataset)
    run_pulls(sample, args.run)
    if not args.no_refit:
        refits(sample)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
