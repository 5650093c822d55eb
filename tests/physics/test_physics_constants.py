"""Particle data of pkf.physics.constants: taken from Scikit-HEP's `particle` (PDG table), not typed in."""

import pytest
from particle import Particle

from pkf.physics import constants as c
from pkf.simulation.species import SPECIES, SPECIES_MASS, SPECIES_PDG

# (code constant, mass constant, PDG code of the particle named) — the codes written out here are
# the test's independent statement of which particle each constant names.
PARTICLES = [
    ("PDG_PION", "MASS_PION", 211),
    ("PDG_KAON", "MASS_KAON", 321),
    ("PDG_PROTON", "MASS_PROTON", 2212),
    ("PDG_ELECTRON", "MASS_ELECTRON", 11),
    ("PDG_MUON", "MASS_MUON", 13),
    ("PDG_PHI", "MASS_PHI", 333),
    ("PDG_BS", "MASS_BS", 531),
]


@pytest.mark.parametrize(("code_name", "mass_name", "pdgid"), PARTICLES)
def test_codes_and_masses_are_the_pdg_table_of_particle(code_name, mass_name, pdgid):
    assert getattr(c, code_name) == pdgid
    assert isinstance(getattr(c, code_name), int)
    # exactly the table's value [MeV], as a plain float (numba and numpy take it as a constant)
    assert type(getattr(c, mass_name)) is float
    assert getattr(c, mass_name) == Particle.from_pdgid(pdgid).mass


def test_bs_lifetime_is_the_pdg_value_in_mm():
    assert c.CTAU_BS == Particle.from_pdgid(531).ctau
    assert 0.4 < c.CTAU_BS < 0.5  # mm: the B_s flies ~0.45 mm (cτ), not metres or µm


def test_species_use_the_same_codes_and_masses():
    assert [SPECIES[n][0] for n in SPECIES] == list(SPECIES_PDG)
    assert list(SPECIES_PDG) == [211, 321, 2212, 11, 13]
    for (name, (pdgid, mass, sign)), table_mass in zip(SPECIES.items(), SPECIES_MASS):
        assert mass == table_mass == Particle.from_pdgid(pdgid).mass, name
        assert sign == int(Particle.from_pdgid(pdgid).charge), name


def test_codes_are_those_of_the_named_particles():
    from particle import literals

    names = {"PDG_PION": "pi_plus", "PDG_KAON": "K_plus", "PDG_PROTON": "proton", "PDG_ELECTRON": "e_minus",
             "PDG_MUON": "mu_minus", "PDG_PHI": "phi_1020", "PDG_BS": "B_s_0"}
    for constant, literal in names.items():
        assert getattr(c, constant) == int(getattr(literals, literal).pdgid), constant


def test_the_table_rows_read_without_particle_are_its_values():
    """The values come from particle's CSV rows (importing `particle` costs 0.3-0.6 s per command);
    the fallback through `particle` itself gives the same numbers."""
    codes = tuple(code for _, _, code in PARTICLES)
    from_rows = c._from_table(codes)
    assert from_rows is not None
    assert from_rows == c._from_particle(codes)
