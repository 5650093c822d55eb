"""Particle data: PDG codes, masses [MeV] and the B_s cτ [mm], from Scikit-HEP's `particle` package.

One place for them (the import floors of tests/test_import_floors.py: physical constants live in
`physics`): the simulation's species, the fitters' mass hypotheses, the material effects and the
report's mass reconstruction all take them from here. The masses and cτ are looked up once, at
import, in the PDG table that `particle` ships (by PDG code); no measured value is typed in (the
codes are the PDG identifiers of the particles named, which the tests check against `particle.literals`).
`particle` 1.1.0 carries the PDG 2025 edition: against the PDG 2024 numbers pkf typed in before,
m(p) 938.27208816 → 938.27208943, m(e) 0.51099895 → 0.51099895069, m(φ) 1019.461 → 1019.46,
m(B_s) 5366.92 → 5366.93 MeV, cτ(B_s) 0.455 → 0.4541 mm (π, K, μ unchanged).

Only the rows of these seven codes are read, from the newest ``particleYYYY.csv`` of the
package's data (the table `particle.Particle` loads by default), with `particle`'s own
conversions (mass as written; cτ = c·ħ/Γ, `particle.kinematics.width_to_lifetime`):
importing `particle` and building its table of 6,549 particles cost 0.3–0.6 s of CPU at the
start of every command, numba's import aside the largest part of it that no command uses.
Without that file (another `particle` layout) the values come from `particle` itself;
tests/physics/test_physics_constants.py checks them all against it.

Codes are of the particle named (the negative lepton for e and μ: PDG 11 and 13).
"""

import csv
import importlib.util
from pathlib import Path


def _data_file() -> Path | None:
    """The newest PDG table ``particleYYYY.csv`` that `particle` ships (found without importing it)."""
    spec = importlib.util.find_spec("particle")
    if spec is None or not spec.submodule_search_locations:
        return None
    tables = sorted(Path(next(iter(spec.submodule_search_locations)), "data").glob("particle[0-9][0-9][0-9][0-9].csv"))
    return tables[-1] if tables else None


def _table_rows(codes: tuple[int, ...]) -> dict[int, dict]:
    """The rows of ``codes`` in `particle`'s PDG table (the last row of a code wins, as there)."""
    path = _data_file()
    if path is None:
        return {}
    with open(path, encoding="utf_8") as f:
        reader = csv.DictReader(line for line in f if not line.startswith("#"))
        return {int(row["ID"]): row for row in reader if row["ID"].lstrip("-").isdigit() and int(row["ID"]) in codes}


def _from_table(codes: tuple[int, ...]) -> tuple[dict[int, float], float] | None:
    """(mass [MeV] per code, cτ of the last code [mm]) from the table, or None if a row is missing."""
    rows = _table_rows(codes)
    if any(code not in rows or float(rows[code]["Mass"]) < 0 for code in codes):
        return None
    from hepunits.constants import c_light, hbar  # particle's own constants (a dependency of it)
    from hepunits.units import MeV

    width = float(rows[codes[-1]]["Width"])
    if not width > 0:
        return None
    return {code: float(rows[code]["Mass"]) for code in codes}, c_light * (hbar / float(width / MeV))


def _from_particle(codes: tuple[int, ...]) -> tuple[dict[int, float], float]:
    """The same values from `particle` itself (its whole table)."""
    from particle import Particle

    return {code: float(Particle.from_pdgid(code).mass) for code in codes}, float(Particle.from_pdgid(codes[-1]).ctau)


PDG_PION = 211  # π⁺ (the codes are the names' PDG codes; tests check them against `particle.literals`)
PDG_KAON = 321  # K⁺
PDG_PROTON = 2212  # p
PDG_ELECTRON = 11  # e⁻
PDG_MUON = 13  # μ⁻
PDG_PHI = 333  # φ(1020)
PDG_BS = 531  # B_s⁰

_CODES = (PDG_PION, PDG_KAON, PDG_PROTON, PDG_ELECTRON, PDG_MUON, PDG_PHI, PDG_BS)  # B_s last: its cτ
_MASS, CTAU_BS = _from_table(_CODES) or _from_particle(_CODES)  # CTAU_BS: mm, cτ of the B_s (docs/physics.md#simulation)

MASS_PION = _MASS[PDG_PION]  # MeV
MASS_KAON = _MASS[PDG_KAON]
MASS_PROTON = _MASS[PDG_PROTON]
MASS_ELECTRON = _MASS[PDG_ELECTRON]
MASS_MUON = _MASS[PDG_MUON]
MASS_PHI = _MASS[PDG_PHI]
MASS_BS = _MASS[PDG_BS]
