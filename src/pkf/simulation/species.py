"""Particle species: PDG codes, masses [MeV] and charges of what pkf generates.

The codes and masses are particle data (`pkf.physics.constants`, from Scikit-HEP's `particle`)."""

from __future__ import annotations

import numpy as np

from pkf.physics.constants import (
    MASS_ELECTRON,
    MASS_KAON,
    MASS_MUON,
    MASS_PION,
    MASS_PROTON,
    PDG_ELECTRON,
    PDG_KAON,
    PDG_MUON,
    PDG_PION,
    PDG_PROTON,
)


# name -> (PDG code of the positive particle, mass [MeV], charge sign of that code).
# Electrons and muons: PDG code 11/13 is the negative lepton.
SPECIES = {
    "pion": (PDG_PION, MASS_PION, +1),
    "kaon": (PDG_KAON, MASS_KAON, +1),
    "proton": (PDG_PROTON, MASS_PROTON, +1),
    "electron": (PDG_ELECTRON, MASS_ELECTRON, -1),
    "muon": (PDG_MUON, MASS_MUON, -1),
}
SPECIES_NAMES = tuple(SPECIES)

# Minimum-bias composition of charged primaries (docs/physics.md#simulation): π 80%, K 12%, p 6%, e 1%, μ 1%.
MINBIAS_FRACTIONS = {"pion": 0.80, "kaon": 0.12, "proton": 0.06, "electron": 0.01, "muon": 0.01}


SPECIES_PDG = np.array([SPECIES[n][0] for n in SPECIES_NAMES], dtype=np.int32)
SPECIES_MASS = np.array([SPECIES[n][1] for n in SPECIES_NAMES], dtype=np.float64)
SPECIES_SIGN = np.array([SPECIES[n][2] for n in SPECIES_NAMES], dtype=np.int32)


def species_arrays(species_index: np.ndarray, charges: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """PDG codes (int32) and masses [MeV] for species indices (into SPECIES_NAMES) with
    electric charges ±1."""
    sign = SPECIES_SIGN[species_index] * np.sign(charges).astype(np.int32)
    return (SPECIES_PDG[species_index] * sign).astype(np.int32), SPECIES_MASS[species_index]
