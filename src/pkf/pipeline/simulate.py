"""The `pkf simulate` stage: generate events, transport them, write a dataset (docs/physics.md#simulation, docs/formats.md).

A dataset directory holds ``hits.parquet``, ``particles.parquet``, ``mc_hits.parquet``,
``meta.json`` and a copy of the geometry (``geometry.toml``), written in a staging
directory that is renamed into place only when everything succeeded.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass, field
from pathlib import Path

import numpy as np
import pyarrow as pa

import pkf
from pkf.errors import InputError
from pkf.geometry import BUILTIN_GEOMETRIES, Geometry, load_geometry
from pkf.io.atomic import atomic_write_json, staged_output_dir
from pkf.io.schemas import HITS, MC_HITS, PARTICLES, table_from_columns
from pkf.io.writer import StreamingTableWriter
from pkf.pipeline.progress import progress_bar
from pkf.simulation.generators import (
    GENERATORS,
    GunSettings,
    LuminousRegion,
    MinBiasSettings,
    generate_bs2phiphi,
    generate_gun,
    generate_minbias,
)
from pkf.simulation.pythia import PYTHIA_GENERATORS, PythiaSettings, pythia_event_generator, require_pythia
from pkf.simulation.response import decay_z, simulate_response
from pkf.simulation.species import SPECIES_NAMES

#: Events written per row group (bounded memory; the files depend on it: keep it fixed).
EVENTS_PER_BATCH = 200
#: Events transported per compiled call, between progress-bar updates (~1 s at ν = 7.6). A
#: row group is the concatenation of these calls' rows, which do not depend on the split
#: (:func:`simulate_batch`): the files do not depend on it.
PROGRESS_EVENTS = 25


@dataclass(frozen=True)
class SimulationConfig:
    """Every option of `pkf simulate` (docs/cli.md). Momenta in MeV."""

    geometry: str = "lhcb-like"
    generator: str = "minbias"
    events: int = 100
    pileup: float = 1.0
    seed: int = 1
    species: str = "pion"
    particles: int = 10
    p_min: float = 2000.0
    p_max: float = 100000.0
    eta_min: float = 2.0
    eta_max: float = 5.0
    luminous_region: LuminousRegion = field(default_factory=LuminousRegion)

    def validate(self) -> None:
        """Raise InputError (one line) for an impossible configuration."""
        if self.generator not in GENERATORS:
            raise InputError(f"--generator: unknown generator {self.generator!r} (one of {', '.join(GENERATORS)})")
        require_pythia(self.generator)
        if self.events <= 0:
            raise InputError(f"--events: must be a positive number of events, not {self.events}")
        if not self.pileup > 0:
            raise InputError(f"--pileup: must be > 0, not {self.pileup}")
        if self.seed < 0:
            raise InputError(f"--seed: must be >= 0, not {self.seed}")
        if self.species not in SPECIES_NAMES:
            raise InputError(f"--species: unknown species {self.species!r} (one of {', '.join(SPECIES_NAMES)})")
        if self.particles <= 0:
            raise InputError(f"--particles: must be positive, not {self.particles}")
        if not 0 < self.p_min <= self.p_max:
            raise InputError(f"--p-min/--p-max: need 0 < p-min <= p-max, got {self.p_min}, {self.p_max}")
        if not self.eta_min <= self.eta_max:
            raise InputError(f"--eta-min/--eta-max: need eta-min <= eta-max, got {self.eta_min}, {self.eta_max}")


def _event_generator(config: SimulationConfig):
    if config.generator in PYTHIA_GENERATORS:
        settings = PythiaSettings(pileup=config.pileup, luminous_region=config.luminous_region)
        return pythia_event_generator(config.generator, settings)
    minbias = MinBiasSettings(pileup=config.pileup, luminous_region=config.luminous_region)
    if config.generator == "minbias":
        return lambda rng: generate_minbias(rng, minbias)
    if config.generator == "bs2phiphi":
        return lambda rng: generate_bs2phiphi(rng, minbias)
    gun = GunSettings(
        species=config.species, particles=config.particles, p_min=config.p_min,
        p_max=config.p_max, eta_min=config.eta_min, eta_max=config.eta_max,
        luminous_region=config.luminous_region,
    )
    return lambda rng: generate_gun(rng, gun)


def simulate_batch(
    geometry: Geometry, config: SimulationConfig, first_event: int, n_events: int
) -> tuple[pa.Table, pa.Table, pa.Table]:
    """Simulate events first_event … first_event+n_events−1; returns (hits, particles, mc_hits).

    Event e draws everything from seeds derived from (config.seed, e) alone, so the
    result does not depend on how events are split into batches.
    """
    generate = _event_generator(config)
    events, transport_seeds = [], np.empty(n_events, dtype=np.int64)
    for i in range(n_events):
        rng = np.random.default_rng([config.seed, first_event + i])
        events.append(generate(rng))
        transport_seeds[i] = rng.integers(0, 2**32 - 1)
    counts = np.array([e["pdg"].size for e in events], dtype=np.int64)
    offsets = np.concatenate([[0], np.cumsum(counts)])
    cols = {name: np.concatenate([e[name] for e in events]) for name in events[0]}
    event_of_particle = np.repeat(np.arange(n_events), counts)
    particle_id = np.arange(offsets[-1]) - offsets[event_of_particle] + 1

    # Production state (x, y, tx, ty, q/p); particles not moving forward get q/p = NaN.
    pz = cols["pz"]
    forward = pz > 0
    safe_pz = np.where(forward, pz, 1.0)
    p = np.sqrt(cols["px"] ** 2 + cols["py"] ** 2 + pz**2)
    state = np.column_stack([
        cols["vx"], cols["vy"], cols["px"] / safe_pz, cols["py"] / safe_pz,
        np.where(forward, cols["charge"] / p, np.nan),
    ])
    records = simulate_response(
        geometry, transport_seeds, offsets, state, cols["vz"], cols["mass"], cols["charge"],
        np.abs(cols["pdg"]) == 11, stop_z=decay_z(offsets, cols["parent_id"], cols["vz"]),
    )

    event_id = first_event + np.arange(n_events, dtype=np.int64)
    particles = table_from_columns(PARTICLES, {
        "event_id": event_id[event_of_particle], "particle_id": particle_id, **cols,
    })
    order = np.lexsort((records.u, records.layer, records.event))
    hit_event = records.event[order]
    hits_per_event = np.bincount(hit_event, minlength=n_events)
    hit_offsets = np.concatenate([[0], np.cumsum(hits_per_event)])
    hit_id = np.arange(order.size) - hit_offsets[hit_event]
    layer = records.layer[order]
    is_strip = np.isnan(records.v[order])
    sigma = geometry.layer_sigma[layer]
    hits = table_from_columns(HITS, {
        "event_id": event_id[hit_event], "hit_id": hit_id, "layer": layer,
        "z": geometry.layer_z[layer], "u": records.u[order], "v": records.v[order],
        "sigma_u": sigma, "sigma_v": np.where(is_strip, np.nan, sigma),
    })
    particle_index = records.particle[order]
    mc_particle = np.where(particle_index >= 0, particle_id[np.maximum(particle_index, 0)], 0)
    mc_hits = table_from_columns(MC_HITS, {
        "event_id": event_id[hit_event], "hit_id": hit_id, "particle_id": mc_particle,
        "x": records.x[order], "y": records.y[order], "z": records.z[order],
        "tx": records.tx[order], "ty": records.ty[order], "qop": records.qop[order],
    })
    return hits, particles, mc_hits


def _simulate_with_progress(geometry: Geometry, config: SimulationConfig, first_event: int, n_events: int,
                            bar) -> tuple[pa.Table, pa.Table, pa.Table]:
    """:func:`simulate_batch` of events first_event … first_event+n_events−1, in calls of
    :data:`PROGRESS_EVENTS` events, each followed by ``bar.update``."""
    pieces = []
    for first in range(first_event, first_event + n_events, PROGRESS_EVENTS):
        n = min(PROGRESS_EVENTS, first_event + n_events - first)
        pieces.append(simulate_batch(geometry, config, first, n))
        bar.update(n)
    hits, particles, mc_hits = (pa.concat_tables(tables) for tables in zip(*pieces))
    return hits, particles, mc_hits


def run_simulation(config: SimulationConfig, out: str | Path, overwrite: bool = False,
                   progress: bool | None = None) -> dict:
    """Simulate `config.events` events into the dataset directory `out`; returns meta.json.

    progress: show a progress bar (None: only when stderr is a terminal).
    """
    config.validate()
    geometry_file = None if config.geometry in BUILTIN_GEOMETRIES else config.geometry
    geometry = load_geometry(config.geometry)
    n_hits = 0
    with staged_output_dir(out, overwrite, inputs=[geometry_file]) as staging:
        writers = {
            name: StreamingTableWriter(staging / f"{name}.parquet", schema)
            for name, schema in (("hits", HITS), ("particles", PARTICLES), ("mc_hits", MC_HITS))
        }
        with progress_bar(config.events, "simulate", progress=progress) as bar:
            for first in range(0, config.events, EVENTS_PER_BATCH):
                n = min(EVENTS_PER_BATCH, config.events - first)
                hits, particles, mc_hits = _simulate_with_progress(geometry, config, first, n, bar)
                writers["hits"].write(hits)
                writers["particles"].write(particles)
                writers["mc_hits"].write(mc_hits)
                n_hits += hits.num_rows
        for writer in writers.values():
            writer.close()
        (staging / "geometry.toml").write_text(geometry.text)
        meta = {
            "pkf_version": pkf.__version__,
            "kind": "dataset",
            "geometry": {"name": geometry.name, "hash": geometry.content_hash, "file": "geometry.toml"},
            "field_hash": geometry.field.content_hash(),
            "generator": config.generator,
            "seed": config.seed,
            "config": {k: v for k, v in asdict(config).items() if k != "luminous_region"}
            | {"luminous_region": asdict(config.luminous_region)},
            "counts": {"events": config.events, "hits": n_hits},
        }
        atomic_write_json(meta, staging / "meta.json")
    return meta
