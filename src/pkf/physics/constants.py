"""Particle data: PDG codes, masses [MeV] and the B_s cτ [mm], from Scikit-HEP's `particle` package.

One place for them (the import floors of tests/test_import_floors.py: physical constants live in
`physics`): the simulation's species, the fitters' mass hypotheses, the material effects and the
report's mass reconstruction all take them from here. The values are looked up once, at import,
in the PDG table that `particle` ships (`particle.literals`, by PDG code); nothing is typed in.
`particle` 1.1.0 carries the PDG 2025 edition: against the PDG 2024 numbers pkf typed in before,
m(p) 938.27208816 → 938.27208943, m(e) 0.51099895 → 0.51099895069, m(φ) 1019.461 → 1019.46,
m(B_s) 5366.92 → 5366.93 MeV, cτ(B_s) 0.455 → 0.4541 mm (π, K, μ unchanged).

Codes are of the particle named (the negative lepton for e and μ: PDG 11 and 13).
"""

from particle import literals as _pdg

PDG_PION = int(_pdg.pi_plus.pdgid)  # π⁺, 211
PDG_KAON = int(_pdg.K_plus.pdgid)  # K⁺, 321
PDG_PROTON = int(_pdg.proton.pdgid)  # p, 2212
PDG_ELECTRON = int(_pdg.e_minus.pdgid)  # e⁻, 11
PDG_MUON = int(_pdg.mu_minus.pdgid)  # μ⁻, 13
PDG_PHI = int(_pdg.phi_1020.pdgid)  # φ(1020), 333
PDG_BS = int(_pdg.B_s_0.pdgid)  # B_s⁰, 531

MASS_PION = float(_pdg.pi_plus.mass)  # MeV
MASS_KAON = float(_pdg.K_plus.mass)
MASS_PROTON = float(_pdg.proton.mass)
MASS_ELECTRON = float(_pdg.e_minus.mass)
MASS_MUON = float(_pdg.mu_minus.mass)
MASS_PHI = float(_pdg.phi_1020.mass)
MASS_BS = float(_pdg.B_s_0.mass)
CTAU_BS = float(_pdg.B_s_0.ctau)  # mm, cτ of the B_s (docs/physics.md#simulation)

del _pdg
