"""Bring your own data: write a dataset with plain pyarrow (no pkf code) and reconstruct it.

A physicist's converter writes the tables of docs/formats.md — here from an analytic model: pions
on exact helices through pkf's built-in ``telescope`` (10 pixel planes at z = 100 … 1000 mm,
σ = 10 µm, homogeneous 1 T along y; see docs/geometry.md), hits smeared by σ. There is no
meta.json: the detector is named with ``--geometry telescope``. The converter also keeps a
column pkf does not know (``time``), which pkf ignores with one warning line, and writes NaN truth
on noise rows, as other producers do.

    python examples/bring_your_own_data.py --out byod [--events 50]

The script checks the files with ``pkf validate``, reconstructs them (ideal pattern recognition,
since the MC truth is known) and prints the pull widths. The helices ignore multiple scattering,
so the slope pulls come out narrower than 1 (the fit expects scattering the data do not have).
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.parquet as pq
from _pkf import pkf

PLANES_Z = np.arange(100.0, 1001.0, 100.0)  # mm, the telescope's 10 pixel planes
SIGMA = 0.01  # mm
FIELD_BY = 1.0  # T
KAPPA = 0.299792458  # MeV/(T·mm)
PION_MASS = 139.57039  # MeV


def helix_hits(p, tx0, ty0, charge, x0=0.0, y0=0.0, z0=0.0):
    """Exact positions and slopes at the planes of a track from (x0, y0, z0) with momentum p [MeV] and
    slopes (tx0, ty0) in a field (0, FIELD_BY, 0): a circle in x–z of signed curvature
    ω = −q·κ·B_y/p_xz per unit arc length s, and y linear in s."""
    phi0 = np.arctan(tx0)  # direction angle in the x–z plane
    p_xz = p / np.sqrt(1.0 + (ty0 * np.cos(phi0)) ** 2)  # (dy/ds = ty·cos φ)
    dy_ds = np.sqrt(p**2 - p_xz**2) * np.sign(ty0) / p_xz
    omega = -charge * KAPPA * FIELD_BY / p_xz
    sin_phi = np.sin(phi0) + omega * (PLANES_Z - z0)
    phi = np.arcsin(sin_phi)
    s = (phi - phi0) / omega
    x = x0 + (np.cos(phi0) - np.cos(phi)) / omega
    y = y0 + dy_ds * s
    return x, y, np.tan(phi), dy_ds / np.cos(phi)


def write_dataset(out: Path, events: int, seed: int) -> None:
    """hits, particles and mc_hits with plain pyarrow, as any converter could."""
    rng = np.random.default_rng(seed)
    hits, parts, truth = [], [], []
    for event in range(events):
        hit_id = 0
        for particle in range(1, 11):
            p = rng.uniform(1000.0, 50000.0)
            tx0, ty0 = rng.uniform(-0.2, 0.2, 2)
            charge = rng.choice([-1, 1])
            x, y, tx, ty = helix_hits(p, tx0, ty0, charge)
            norm = p / np.sqrt(1 + tx0**2 + ty0**2)
            parts.append((event, particle, 211 * charge, charge, PION_MASS, 0.0, 0.0, 0.0,
                          tx0 * norm, ty0 * norm, norm, 0, 0, False))
            for k in range(PLANES_Z.size):
                u, v = x[k] + rng.normal(0, SIGMA), y[k] + rng.normal(0, SIGMA)
                hits.append((event, hit_id, k, PLANES_Z[k], u, v, SIGMA, SIGMA, rng.uniform(0, 25)))
                truth.append((event, hit_id, particle, x[k], y[k], PLANES_Z[k], tx[k], ty[k], charge / p))
                hit_id += 1
        for k in range(PLANES_Z.size):  # one noise hit per plane: no particle, so no slopes or q/p (NaN)
            u, v = rng.uniform(-500, 500, 2)
            hits.append((event, hit_id, k, PLANES_Z[k], u, v, SIGMA, SIGMA, rng.uniform(0, 25)))
            truth.append((event, hit_id, 0, u, v, PLANES_Z[k], np.nan, np.nan, np.nan))
            hit_id += 1

    def table(rows, columns):
        cols = list(zip(*rows))
        return pa.table({name: pa.array(values, type) for (name, type), values in zip(columns, cols)})

    out.mkdir(parents=True, exist_ok=True)
    pq.write_table(table(hits, [("event_id", pa.int64()), ("hit_id", pa.int64()), ("layer", pa.int16()),
                                ("z", pa.float64()), ("u", pa.float64()), ("v", pa.float64()),
                                ("sigma_u", pa.float64()), ("sigma_v", pa.float64()), ("time", pa.float64())]),
                   out / "hits.parquet")
    pq.write_table(table(parts, [("event_id", pa.int64()), ("particle_id", pa.int64()), ("pdg", pa.int32()),
                                 ("charge", pa.int8()), ("mass", pa.float64()), ("vx", pa.float64()),
                                 ("vy", pa.float64()), ("vz", pa.float64()), ("px", pa.float64()),
                                 ("py", pa.float64()), ("pz", pa.float64()), ("parent_id", pa.int64()),
                                 ("interaction", pa.int16()), ("from_signal", pa.bool_())]),
                   out / "particles.parquet")
    pq.write_table(table(truth, [("event_id", pa.int64()), ("hit_id", pa.int64()), ("particle_id", pa.int64()),
                                 ("x", pa.float64()), ("y", pa.float64()), ("z", pa.float64()),
                                 ("tx", pa.float64()), ("ty", pa.float64()), ("qop", pa.float64())]),
                   out / "mc_hits.parquet")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--events", type=int, default=50)
    parser.add_argument("--seed", type=int, default=1)
    args = parser.parse_args()
    dataset, run, report = args.out / "my_data", args.out / "run", args.out / "report"
    write_dataset(dataset, args.events, args.seed)
    pkf("validate", str(dataset), "--geometry", "telescope")
    pkf("reconstruct", str(dataset), "--out", str(run), "--geometry", "telescope", "--pattern", "truth",
        "--fitter", "parametrized", "--fitter", "reference", "--overwrite")
    pkf("report", f"{run}:mine", "--out", str(report), "--overwrite")
    summary = json.loads((report / "summary.json").read_text())
    for name in summary["entry_order"]:
        pulls = summary["entries"][name]["pulls"]["parameters"]
        print(f"{name}: pull widths " + ", ".join(f"{p} {pulls[p]['width']:.2f}" for p in pulls))


if __name__ == "__main__":
    main()
