"""Physical constants of particles: masses [MeV] (PDG 2024) and the B_s lifetime [mm].

One place for them (the import floors of tests/test_import_floors.py: physical constants live in `physics`): the simulation's
species, the fitters' mass hypotheses and the material effects all take them from here.
"""

MASS_PION = 139.57039
MASS_KAON = 493.677
MASS_PROTON = 938.27208816
MASS_ELECTRON = 0.51099895
MASS_MUON = 105.6583755
MASS_PHI = 1019.461
MASS_BS = 5366.92
CTAU_BS = 0.455  # mm, cτ of the B_s (docs/physics.md#simulation)
