"""Pythia 8 event generators (docs/physics.md#simulation): ``pythia`` and ``pythia-bs2phiphi``.

Needs the optional ``pythia`` extra (the ``pythia8mc`` wheel). Units: mm, MeV.

Physics choices
---------------
- pp at √s = 13.6 TeV. ``pythia``: ``SoftQCD:inelastic`` (non-diffractive and
  diffractive); ``pythia-bs2phiphi``: ``HardQCD:hardbbbar`` with every B_s⁰ and B̄_s⁰
  forced to φφ and every φ to K⁺K⁻ (``ParticleDecays:mixB = off``, so the kaons' chain is
  kaon → φ → B_s without an oscillation entry).
- Decays: Pythia decays every particle with cτ < 1000 mm (``ParticleDecays:tau0Max``), at
  the decay vertex it samples: K⁰_S, Λ, Ξ, Ω, Σ± and all heavier hadrons decay in Pythia;
  π±, K±, μ±, p, e± (and K⁰_L, n) are stable and pkf transports them without decays in
  flight (as the built-in generators). A charged particle that Pythia decayed (Σ±, Ξ⁻,
  D±, …) is transported from its production to its decay vertex
  (:func:`pkf.simulation.response.decay_z`).
- Table: every final-state charged particle with p > 100 MeV (the transport's own cut) in
  any direction, and every decayed ancestor of those back to the primary hadron, so that
  ``parent_id`` chains are complete (kaon → φ → B_s⁰; π → K⁰_S). A primary hadron (from
  the string or a beam remnant) has ``parent_id`` 0. Photons, neutrinos and neutral
  stable hadrons are not written.
- Pileup (``--pileup`` ν): ``pythia`` draws, as the built-in ``minbias``, a Poisson(ν)
  number of interactions truncated at zero (an event is a crossing with at least one
  interaction). ``pythia-bs2phiphi``: the signal interaction (index 0) plus a Poisson(ν)
  number of inelastic interactions from a second Pythia instance (the other interactions
  of a crossing are independent of the signal one).
- Signal acceptance: a ``pythia-bs2phiphi`` interaction is kept only if one B_s⁰ (or B̄_s⁰)
  has its four kaons in 2 < η < 5 (the report's mass needs four long kaons); others are
  generated again with the next seed. ``from_signal`` marks every B_s and its descendants
  in the signal interaction.
- Vertices: each interaction's vertex is drawn from the luminous region
  (σ_z = 45 mm, σ_xy = 0.04 mm) and added to Pythia's production vertices.
- Seeds: Pythia is initialised once per process with a fixed seed; each interaction then
  re-seeds it (``Rndm::init``) with a number drawn from the event's numpy generator, so an
  event depends on (``--seed``, event number) only, not on the batch or on what the
  process generated before.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from pkf.errors import InputError
from pkf.simulation.generators import PARTICLE_COLUMNS, LuminousRegion, concat_events, sample_interaction_vertices
from pkf.physics.constants import PDG_BS, PDG_KAON, PDG_PHI

PYTHIA_GENERATORS = ("pythia", "pythia-bs2phiphi")
MISSING_EXTRA = "needs the pythia extra: pip install 'pkf[pythia]'"

#: Centre-of-mass energy [GeV] (Pythia's unit).
ECM_GEV = 13600.0
#: Pythia decays particles with cτ below this [mm]; longer-lived ones are stable.
TAU0_MAX_MM = 1000.0
#: Final-state charged particles below this momentum [MeV] are not written.
MIN_MOMENTUM = 100.0
#: Signal acceptance: the four kaons of a B_s⁰ in this pseudorapidity range.
SIGNAL_ETA = (2.0, 5.0)
#: Seed of Pythia's initialisation (its MPI tables): the same in every process.
INIT_SEED = 19780503
#: Largest seed Pythia accepts.
_MAX_SEED = 900_000_000
#: Give up after this many rejected signal interactions in one event.
_MAX_SIGNAL_TRIALS = 100_000

_COMMON = (
    "Print:quiet = on",
    f"Beams:eCM = {ECM_GEV}",
    "Random:setSeed = on",
    f"Random:seed = {INIT_SEED}",
    "ParticleDecays:limitTau0 = on",
    f"ParticleDecays:tau0Max = {TAU0_MAX_MM}",
)
_MODES = {
    "minbias": ("SoftQCD:inelastic = on",),
    "bs2phiphi": (
        "HardQCD:hardbbbar = on",
        "ParticleDecays:mixB = off",
        f"{PDG_BS}:onMode = off",
        f"{PDG_BS}:onIfMatch = {PDG_PHI} {PDG_PHI}",
        f"{PDG_PHI}:onMode = off",
        f"{PDG_PHI}:onIfMatch = {PDG_KAON} -{PDG_KAON}",
    ),
}


def pythia_available() -> bool:
    """True when the pythia8mc module can be imported."""
    try:
        import pythia8mc  # noqa: F401
    except ImportError:
        return False
    return True


def require_pythia(generator: str) -> None:
    """Raise InputError (one line) when `generator` needs Pythia and it is not installed."""
    if generator in PYTHIA_GENERATORS and not pythia_available():
        raise InputError(f"--generator {generator}: {MISSING_EXTRA}")


@functools.cache
def _pythia(mode: str):
    """An initialised Pythia instance for `mode` ("minbias" or "bs2phiphi"), one per process."""
    import pythia8mc

    pythia = pythia8mc.Pythia("", False)
    for line in _COMMON + _MODES[mode]:
        if not pythia.readString(line):
            raise RuntimeError(f"Pythia rejected the setting {line!r}")
    if not pythia.init():
        raise RuntimeError(f"Pythia failed to initialise ({mode})")
    return pythia


def _next_event(pythia, rng: np.random.Generator) -> None:
    """Generate one interaction, seeded from `rng` (a failed event is redone with a new seed)."""
    while True:
        pythia.rndm.init(int(rng.integers(1, _MAX_SEED)))
        if pythia.next():
            return


def _record(pythia) -> dict[str, np.ndarray]:
    """Pythia's event record as arrays: id, status, mother1, charge, final, hadron-or-lepton,
    vertex [mm] and four-momentum/mass [GeV]."""
    rows = [
        (q.id(), q.status(), q.mother1(), q.charge(), q.isFinal(), q.isHadron() or q.isLepton(),
         q.xProd(), q.yProd(), q.zProd(), q.px(), q.py(), q.pz(), q.m())
        for q in pythia.event.particles()
    ]
    a = np.array(rows, dtype=np.float64)
    return {
        "id": a[:, 0].astype(np.int64), "status": a[:, 1].astype(np.int64),
        "mother": a[:, 2].astype(np.int64), "charge": np.rint(a[:, 3]).astype(np.int64),
        "final": a[:, 4] > 0, "physical": a[:, 5] > 0, "vertex": a[:, 6:9],
        "momentum": a[:, 9:12], "mass": a[:, 12],
    }


def _decay_parents(record: dict[str, np.ndarray]) -> np.ndarray:
    """Index of each entry's decayed parent hadron/lepton, −1 for a primary.

    A decay product (|status| 91–99) has the decayed particle as mother; hadrons made from
    the partons of a decay (e.g. B → c c̄ s) reach it through those partons.
    """
    status = np.abs(record["status"])
    mother = record["mother"]
    physical = record["physical"]
    is_decay = (status >= 91) & (status <= 99)
    parent = np.full(status.size, -1, dtype=np.int64)
    for i in range(status.size):
        a = mother[i]
        if not is_decay[i] and not (0 < a and is_decay[a] and not physical[a]):
            continue
        while a > 0 and not physical[a] and is_decay[a]:
            a = mother[a]
        if a > 0 and physical[a] and status[a] >= 81:
            parent[i] = a
    return parent


def _interaction_particles(
    pythia, vertex: np.ndarray, interaction: int, signal: bool
) -> dict[str, np.ndarray]:
    """The particles of Pythia's current event as `particles` columns (docs/formats.md), parent_id
    1-based within this block, production vertices shifted by `vertex` [mm]."""
    record = _record(pythia)
    parent = _decay_parents(record)
    p = np.linalg.norm(record["momentum"], axis=1) * 1000.0
    keep = record["final"] & (record["charge"] != 0) & (p > MIN_MOMENTUM)
    while True:  # add the decayed ancestors of what is kept
        ancestors = parent[keep & (parent >= 0)]
        if np.all(keep[ancestors]):
            break
        keep[ancestors] = True
    index = np.flatnonzero(keep)
    position = np.zeros(record["id"].size, dtype=np.int64)
    position[index] = np.arange(1, index.size + 1)
    parent_id = np.where(parent[index] >= 0, position[np.maximum(parent[index], 0)], 0)
    pdg = record["id"][index]
    from_signal = np.zeros(index.size, dtype=bool)
    if signal:
        from_signal = np.abs(pdg) == PDG_BS
        for _ in range(3):  # B_s → φ → K: descendants within three generations
            from_signal |= (parent_id > 0) & from_signal[np.maximum(parent_id - 1, 0)]
    n = index.size
    v = record["vertex"][index] + vertex
    mom = record["momentum"][index] * 1000.0
    cols = {
        "pdg": pdg, "charge": record["charge"][index], "mass": record["mass"][index] * 1000.0,
        "vx": v[:, 0], "vy": v[:, 1], "vz": v[:, 2], "px": mom[:, 0], "py": mom[:, 1], "pz": mom[:, 2],
        "parent_id": parent_id, "interaction": np.full(n, interaction), "from_signal": from_signal,
    }
    return {name: cols[name].astype(dtype) for name, dtype in PARTICLE_COLUMNS}


def _pseudorapidity(px: np.ndarray, py: np.ndarray, pz: np.ndarray) -> np.ndarray:
    return np.arcsinh(pz / np.hypot(px, py))


def signal_in_acceptance(event: dict[str, np.ndarray]) -> bool:
    """True when one B_s⁰ of `event` has four kaons (via φ) in 2 < η < 5."""
    pdg, parent_id = event["pdg"], event["parent_id"]
    parent_pdg = np.where(parent_id > 0, pdg[np.maximum(parent_id - 1, 0)], 0)
    grand = np.where(parent_id > 0, parent_id[np.maximum(parent_id - 1, 0)], 0)
    grand_pdg = np.where(grand > 0, pdg[np.maximum(grand - 1, 0)], 0)
    eta = _pseudorapidity(event["px"], event["py"], event["pz"])
    kaon = (np.abs(pdg) == PDG_KAON) & (parent_pdg == PDG_PHI) & (np.abs(grand_pdg) == PDG_BS)
    kaon_in = kaon & (eta > SIGNAL_ETA[0]) & (eta < SIGNAL_ETA[1])
    return bool(np.any(np.bincount(grand[kaon_in], minlength=1) == 4))


@dataclass(frozen=True)
class PythiaSettings:
    """Pileup ν (mean pp interactions per crossing, docs/physics.md#simulation) and the luminous region."""

    pileup: float = 1.0
    luminous_region: LuminousRegion = field(default_factory=LuminousRegion)


def _shift_parents(block: dict[str, np.ndarray], offset: int) -> dict[str, np.ndarray]:
    block["parent_id"] = np.where(block["parent_id"] > 0, block["parent_id"] + offset, 0)
    return block


def _pileup_blocks(rng, vertices: np.ndarray, first_interaction: int) -> list[dict[str, np.ndarray]]:
    pythia = _pythia("minbias")
    blocks = []
    for k, vertex in enumerate(vertices):
        _next_event(pythia, rng)
        blocks.append(_interaction_particles(pythia, vertex, first_interaction + k, signal=False))
    return blocks


def _join(blocks: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    offset = 0
    for block in blocks:
        _shift_parents(block, offset)
        offset += block["pdg"].size
    return concat_events(blocks)


def generate_pythia_minbias(rng: np.random.Generator, settings: PythiaSettings) -> dict[str, np.ndarray]:
    """One crossing of Pythia inelastic pp interactions (zero-truncated Poisson(ν) of them)."""
    vertices = sample_interaction_vertices(rng, settings.pileup, settings.luminous_region)
    return _join(_pileup_blocks(rng, vertices, 0))


def generate_pythia_bs2phiphi(rng: np.random.Generator, settings: PythiaSettings) -> dict[str, np.ndarray]:
    """One Pythia bb̄ interaction with a B_s⁰ → φφ → 4K in acceptance, plus Poisson(ν) pileup."""
    vertex = settings.luminous_region.sample(rng, 1)[0]
    pythia = _pythia("bs2phiphi")
    for _ in range(_MAX_SIGNAL_TRIALS):
        _next_event(pythia, rng)
        signal = _interaction_particles(pythia, vertex, 0, signal=True)
        if signal_in_acceptance(signal):
            break
    else:
        raise RuntimeError(f"no B_s⁰ → φφ in acceptance in {_MAX_SIGNAL_TRIALS} Pythia events")
    n_pileup = int(rng.poisson(settings.pileup))
    pileup = _pileup_blocks(rng, settings.luminous_region.sample(rng, n_pileup), 1)
    return _join([signal] + pileup)


def pythia_event_generator(generator: str, settings: PythiaSettings):
    """The per-event function (rng → particle columns) of a Pythia generator name."""
    require_pythia(generator)
    if generator == "pythia":
        return lambda rng: generate_pythia_minbias(rng, settings)
    return lambda rng: generate_pythia_bs2phiphi(rng, settings)
