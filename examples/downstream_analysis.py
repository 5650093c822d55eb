"""A downstream analysis of a run: read the `states`, `pulls` and `chi2` tables with pyarrow and
plot with hist + mplhep, as a physicist would after `pkf reconstruct`.

Makes three figures in ``--out``: the q/p pull of long tracks at the first hit with a Gaussian
fit, the momentum resolution δp/p versus true momentum (Gaussian core per bin), and χ²/ndf of
real and ghost tracks. Joins are on (event_id, track_id, fitter); `docs/formats.md` lists
every column.

    python examples/downstream_analysis.py RUN --out plots [--fitter parametrized]
"""

from __future__ import annotations

import argparse
from pathlib import Path

import hist
import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import mplhep  # noqa: E402
import numpy as np  # noqa: E402
import pyarrow.compute as pc  # noqa: E402
import pyarrow.dataset as ds  # noqa: E402
from scipy.stats import norm  # noqa: E402


def read(run: Path, table: str, fitter: str):
    """One run table (a directory of Parquet partition files), the rows of one fitter."""
    data = ds.dataset(run / table, format="parquet").to_table()
    return data.filter(pc.equal(data.column("fitter"), fitter))


def as_numpy(table, name):
    return table.column(name).to_numpy(zero_copy_only=False)


def at_first_hit(table):
    return table.filter(pc.equal(table.column("location"), "first_hit"))


def join(table, rows):
    """For each row of ``rows``: its row in ``table`` with the same (event_id, track_id), and whether
    there is one (both tables of one fitter; at most one row per track in ``table``)."""
    def key(t):
        return as_numpy(t, "event_id").astype(np.int64) * (1 << 32) + as_numpy(t, "track_id")

    keys = key(table)
    order = np.argsort(keys)
    pos = np.minimum(np.searchsorted(keys[order], key(rows)), max(keys.size - 1, 0))
    found = keys[order][pos] == key(rows) if keys.size else np.zeros(rows.num_rows, dtype=bool)
    return order[pos] if keys.size else pos, found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--fitter", default="parametrized")
    args = parser.parse_args()
    args.out.mkdir(parents=True, exist_ok=True)
    plt.style.use(mplhep.style.LHCb2)

    chi2 = read(args.run, "chi2", args.fitter)
    pulls = at_first_hit(read(args.run, "pulls", args.fitter))
    states = at_first_hit(read(args.run, "states", args.fitter))
    # long tracks: those with SciFi hits (join pulls → chi2 on event and track)
    row, found = join(chi2, pulls)
    is_long = found & (as_numpy(chi2, "n_scifi")[row] > 0)
    pull_qop = as_numpy(pulls, "pull_qop")[is_long]

    h = hist.Hist(hist.axis.Regular(60, -6, 6, name="pull", label=r"pull $q/p$"))
    h.fill(pull_qop)
    core = pull_qop[np.abs(pull_qop) < 3]
    mu, sigma = norm.fit(core)
    fig, ax = plt.subplots()
    mplhep.histplot(h, ax=ax, yerr=True, histtype="errorbar", color="black", label=f"{args.fitter}, long tracks")
    grid = np.linspace(-6, 6, 300)
    ax.plot(grid, core.size * h.axes[0].widths[0] * norm.pdf(grid, mu, sigma), color="red",
            label=f"Gaussian: $\\mu$={mu:.2f}, $\\sigma$={sigma:.2f}")
    ax.legend()
    fig.savefig(args.out / "pull_qop.png", dpi=60)
    plt.close(fig)

    # δp/p = p_fit/p_true − 1 with p_fit = 1/|q/p| of the fitted first-hit state (join pulls → states)
    row, found = join(states, pulls)
    p_true = as_numpy(pulls, "p_true")
    dp_over_p = np.where(found, 1.0 / (np.abs(as_numpy(states, "qop")[row]) * p_true) - 1.0, np.nan)[is_long]
    p_true = p_true[is_long]
    edges = np.array([2, 3, 5, 10, 20, 50, 100]) * 1e3
    centres, widths = [], []
    for lo, hi in zip(edges[:-1], edges[1:]):
        sel = dp_over_p[(p_true >= lo) & (p_true < hi)]
        sel = sel[np.isfinite(sel)]
        if sel.size >= 20:
            med = np.median(sel)
            mad = 1.4826 * np.median(np.abs(sel - med))
            centres.append(np.sqrt(lo * hi) / 1e3)
            widths.append(100 * norm.fit(sel[np.abs(sel - med) < 3 * mad])[1])
    fig, ax = plt.subplots()
    ax.plot(centres, widths, "o", label=args.fitter)
    ax.set_xscale("log")
    ax.set_xlabel(r"$p_\mathrm{true}$ [GeV]")
    ax.set_ylabel(r"core $\sigma(\delta p/p)$ [%]")
    ax.set_ylim(0, 1.3 * max(widths) if widths else 1)
    ax.legend()
    fig.savefig(args.out / "dp_over_p.png", dpi=60)
    plt.close(fig)

    ok = pc.equal(chi2.column("status"), "ok")
    good = chi2.filter(ok)
    chi2_ndf, ghost = as_numpy(good, "chi2_ndf"), as_numpy(good, "is_ghost")
    fig, ax = plt.subplots()
    for label, sel, color in (("real", ~ghost, "black"), ("ghost", ghost, "red")):
        hc = hist.Hist(hist.axis.Regular(40, 0, 8, name="chi2ndf", label=r"$\chi^2/N_\mathrm{dof}$"))
        hc.fill(np.clip(chi2_ndf[sel], 0, 8 - 1e-9))
        if hc.sum() > 0:
            mplhep.histplot(hc, ax=ax, density=True, color=color, label=f"{label} ({int(sel.sum())})")
    ax.set_yscale("log")
    ax.legend()
    fig.savefig(args.out / "chi2_ndf.png", dpi=60)
    plt.close(fig)
    print(f"{args.fitter}: {pull_qop.size} long tracks, q/p pull core width {sigma:.3f}; "
          f"figures in {args.out}")


if __name__ == "__main__":
    main()
