"""Event generators (docs/physics.md#simulation): minimum bias, particle gun and B_s⁰ → φφ.

Each generator turns a numpy Generator into the particles of one event, as columns
of the `particles` table (docs/formats.md) without the event number. Units: mm, MeV.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pkf.physics.constants import CTAU_BS, MASS_BS, MASS_KAON, MASS_PHI, PDG_BS, PDG_KAON, PDG_PHI
from pkf.simulation.species import MINBIAS_FRACTIONS, SPECIES_NAMES, species_arrays

GENERATORS = ("minbias", "gun", "bs2phiphi", "pythia", "pythia-bs2phiphi")

PARTICLE_COLUMNS = (
    ("pdg", np.int32), ("charge", np.int8), ("mass", np.float64), ("vx", np.float64),
    ("vy", np.float64), ("vz", np.float64), ("px", np.float64), ("py", np.float64),
    ("pz", np.float64), ("parent_id", np.int64), ("interaction", np.int16),
    ("from_signal", np.bool_),
)


@dataclass(frozen=True)
class LuminousRegion:
    """Gaussian luminous region: σ_z and σ_xy in mm, centred on the origin."""

    sigma_z: float = 45.0
    sigma_xy: float = 0.04

    def sample(self, rng: np.random.Generator, n: int) -> np.ndarray:
        """n primary vertices, shape (n, 3) [mm]."""
        sig = np.array([self.sigma_xy, self.sigma_xy, self.sigma_z])
        return rng.normal(size=(n, 3)) * sig


@dataclass(frozen=True)
class MinBiasSettings:
    """Built-in minimum-bias model (docs/physics.md#simulation).

    pileup: mean number ν of pp interactions per event. An event is a crossing with at
        least one visible interaction, so the number is drawn from a Poisson(ν)
        truncated at zero (the mean is ν/(1 − e^−ν): 1.58 for ν = 1, 7.6 for ν = 7.6).
    multiplicity_mean, multiplicity_shape: negative binomial of charged primaries.
    eta_range: primaries are flat in η here. pt_mean: mean pT [MeV] of a Gamma(2)
        spectrum dN/dpT ∝ pT·exp(−2pT/⟨pT⟩).
    """

    pileup: float = 1.0
    multiplicity_mean: float = 40.0
    multiplicity_shape: float = 2.0
    eta_range: tuple[float, float] = (1.8, 5.2)
    pt_mean: float = 600.0
    luminous_region: LuminousRegion = field(default_factory=LuminousRegion)


@dataclass(frozen=True)
class GunSettings:
    """Particle gun: `particles` per event of one species, p flat in [p_min, p_max] MeV,
    η flat in [eta_min, eta_max], φ flat, charge ±1 at random, vertices from the
    luminous region."""

    species: str = "pion"
    particles: int = 10
    p_min: float = 2000.0
    p_max: float = 100000.0
    eta_min: float = 2.0
    eta_max: float = 5.0
    luminous_region: LuminousRegion = field(default_factory=LuminousRegion)


def _empty_event() -> dict[str, np.ndarray]:
    return {name: np.empty(0, dtype=dtype) for name, dtype in PARTICLE_COLUMNS}


def concat_events(parts: list[dict[str, np.ndarray]]) -> dict[str, np.ndarray]:
    """Concatenate particle-column blocks (parent_id already offset by the caller)."""
    parts = [p for p in parts if p["pdg"].size] or [_empty_event()]
    return {name: np.concatenate([p[name] for p in parts]).astype(dtype) for name, dtype in PARTICLE_COLUMNS}


def _momenta(pt: np.ndarray, eta: np.ndarray, phi: np.ndarray) -> np.ndarray:
    """(px, py, pz) [MeV] from transverse momentum, pseudorapidity and azimuth."""
    return np.stack([pt * np.cos(phi), pt * np.sin(phi), pt * np.sinh(eta)], axis=1)


def _primaries(
    rng: np.random.Generator,
    species_index: np.ndarray,
    momenta: np.ndarray,
    vertex: np.ndarray,
    interaction: int,
) -> dict[str, np.ndarray]:
    n = species_index.size
    charge = rng.choice(np.array([-1, 1], dtype=np.int8), size=n)
    pdg, mass = species_arrays(species_index, charge)
    return {
        "pdg": pdg, "charge": charge, "mass": mass,
        "vx": np.full(n, vertex[0]), "vy": np.full(n, vertex[1]), "vz": np.full(n, vertex[2]),
        "px": momenta[:, 0], "py": momenta[:, 1], "pz": momenta[:, 2],
        "parent_id": np.zeros(n, dtype=np.int64),
        "interaction": np.full(n, interaction, dtype=np.int16),
        "from_signal": np.zeros(n, dtype=bool),
    }


def generate_minbias(rng: np.random.Generator, settings: MinBiasSettings) -> dict[str, np.ndarray]:
    """Charged primaries of one minimum-bias event (zero-truncated Poisson pileup)."""
    return _minbias_with_vertices(rng, settings)[0]


def sample_interaction_vertices(rng: np.random.Generator, pileup: float, region: LuminousRegion) -> np.ndarray:
    """Vertices [mm], shape (n, 3), of a crossing's pp interactions: n ~ Poisson(pileup)
    truncated at zero (a crossing with at least one interaction)."""
    n_interactions = 0
    while n_interactions == 0:
        n_interactions = int(rng.poisson(pileup))
    return region.sample(rng, n_interactions)


def _minbias_with_vertices(rng: np.random.Generator, settings: MinBiasSettings):
    vertices = sample_interaction_vertices(rng, settings.pileup, settings.luminous_region)
    probabilities = np.array([MINBIAS_FRACTIONS[name] for name in SPECIES_NAMES])
    parts = []
    for interaction, vertex in enumerate(vertices):
        k = settings.multiplicity_shape
        n = int(rng.negative_binomial(k, k / (k + settings.multiplicity_mean)))
        species_index = rng.choice(len(SPECIES_NAMES), size=n, p=probabilities)
        eta = rng.uniform(*settings.eta_range, size=n)
        phi = rng.uniform(-np.pi, np.pi, size=n)
        pt = rng.gamma(2.0, settings.pt_mean / 2.0, size=n)
        parts.append(_primaries(rng, species_index, _momenta(pt, eta, phi), vertex, interaction))
    return concat_events(parts), vertices


def generate_gun(rng: np.random.Generator, settings: GunSettings) -> dict[str, np.ndarray]:
    """One particle-gun event: `settings.particles` particles from one vertex."""
    n = settings.particles
    vertex = settings.luminous_region.sample(rng, 1)[0]
    p = rng.uniform(settings.p_min, settings.p_max, size=n)
    eta = rng.uniform(settings.eta_min, settings.eta_max, size=n)
    phi = rng.uniform(-np.pi, np.pi, size=n)
    pt = p / np.cosh(eta)
    species_index = np.full(n, SPECIES_NAMES.index(settings.species))
    return _primaries(rng, species_index, _momenta(pt, eta, phi), vertex, 0)


def _boost(p4: np.ndarray, beta: np.ndarray) -> np.ndarray:
    """Lorentz-boost four-vectors p4 = (E, px, py, pz) (shape (n, 4)) by velocity beta (n, 3)."""
    b2 = np.sum(beta * beta, axis=1)
    gamma = 1.0 / np.sqrt(1.0 - b2)
    bp = np.sum(beta * p4[:, 1:], axis=1)
    coef = np.where(b2 > 0, (gamma - 1.0) / np.where(b2 > 0, b2, 1.0), 0.0)
    energy = gamma * (p4[:, 0] + bp)
    momentum = p4[:, 1:] + (coef * bp + gamma * p4[:, 0])[:, None] * beta
    return np.column_stack([energy, momentum])


def _two_body(rng: np.random.Generator, parent: np.ndarray, m_parent: float, m1: float, m2: float):
    """Isotropic two-body decay of a parent four-vector; returns the two daughters' four-vectors."""
    q = np.sqrt((m_parent**2 - (m1 + m2) ** 2) * (m_parent**2 - (m1 - m2) ** 2)) / (2.0 * m_parent)
    cos_t = rng.uniform(-1.0, 1.0)
    phi = rng.uniform(-np.pi, np.pi)
    sin_t = np.sqrt(1.0 - cos_t**2)
    direction = np.array([sin_t * np.cos(phi), sin_t * np.sin(phi), cos_t])
    d1 = np.concatenate([[np.hypot(m1, q)], q * direction])
    d2 = np.concatenate([[np.hypot(m2, q)], -q * direction])
    beta = parent[1:] / parent[0]
    return _boost(np.stack([d1, d2]), np.stack([beta, beta]))


def generate_bs2phiphi_decay(
    rng: np.random.Generator, primary_vertex: np.ndarray
) -> dict[str, np.ndarray]:
    """One B_s⁰ → φφ, φ → K⁺K⁻ decay chain: 7 particles (B_s, 2 φ, 4 K).

    B_s pT ~ Gamma(2) with mean 5 GeV, flat in 2 < η < 5; proper decay length
    exponential with the PDG cτ (`CTAU_BS`, 0.454 mm); both decays isotropic; PDG masses (the φ at its
    pole mass). ``parent_id`` holds 1-based positions within this block (the caller
    offsets them); the B_s is produced at `primary_vertex` by interaction 0.
    """
    pt = rng.gamma(2.0, 2500.0)
    eta = rng.uniform(2.0, 5.0)
    phi = rng.uniform(-np.pi, np.pi)
    p_bs = _momenta(np.array([pt]), np.array([eta]), np.array([phi]))[0]
    bs = np.concatenate([[np.sqrt(MASS_BS**2 + p_bs @ p_bs)], p_bs])
    flight = rng.exponential(CTAU_BS) * p_bs / MASS_BS  # βγcτ along the momentum
    decay_vertex = primary_vertex + flight
    phis = _two_body(rng, bs, MASS_BS, MASS_PHI, MASS_PHI)
    kaons = np.concatenate([_two_body(rng, phis[i], MASS_PHI, MASS_KAON, MASS_KAON) for i in range(2)])
    p4 = np.concatenate([bs[None, :], phis, kaons])
    vertices = np.stack([primary_vertex] + [decay_vertex] * 6)
    return {
        "pdg": np.array([PDG_BS, PDG_PHI, PDG_PHI, PDG_KAON, -PDG_KAON, PDG_KAON, -PDG_KAON], dtype=np.int32),
        "charge": np.array([0, 0, 0, 1, -1, 1, -1], dtype=np.int8),
        "mass": np.array([MASS_BS, MASS_PHI, MASS_PHI] + [MASS_KAON] * 4),
        "vx": vertices[:, 0], "vy": vertices[:, 1], "vz": vertices[:, 2],
        "px": p4[:, 1], "py": p4[:, 2], "pz": p4[:, 3],
        "parent_id": np.array([0, 1, 1, 2, 2, 3, 3], dtype=np.int64),
        "interaction": np.zeros(7, dtype=np.int16),
        "from_signal": np.ones(7, dtype=bool),
    }


def generate_bs2phiphi(rng: np.random.Generator, settings: MinBiasSettings) -> dict[str, np.ndarray]:
    """A minimum-bias event plus one B_s⁰ → φφ decay from the first interaction's vertex."""
    underlying, vertices = _minbias_with_vertices(rng, settings)
    signal = generate_bs2phiphi_decay(rng, vertices[0])
    n_before = underlying["pdg"].size
    signal["parent_id"] = np.where(signal["parent_id"] > 0, signal["parent_id"] + n_before, 0)
    return concat_events([underlying, signal])
