"""Report plots (paper Figs. 1–4, docs/formats.md#summaryjson): PNG files drawn with matplotlib (Agg) in the mplhep LHCb style.

:func:`make_plots` writes every plot of a :class:`~pkf.report.metrics.ReportData`
into a directory and returns, per report section, the list of :class:`Plot` it
wrote (file name relative to that directory and a caption). Histograms are filled
with ``hist`` and drawn with ``mplhep.histplot``. The style is applied with a
context manager (no global matplotlib state is changed), and every figure is
closed after saving.

Files: ``resolution.png`` (δp/p, x, tx vs p per fitter with the ratio to the
reference), ``pulls_<fitter>.png`` (five pull histograms with the Gaussian core
fits), ``chi2.png`` (χ²/ndf real vs ghost per fitter + efficiency / rejection),
``mass.png`` (B_s mass peak with fit per entry), ``timing.png`` (tracks/s and speed-up per
entry), ``efficiency.png`` (efficiency
vs p and η). A plot whose data are missing is not written; the HTML says why.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import matplotlib

matplotlib.use("Agg")

import hist  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import mplhep  # noqa: E402
import numpy as np  # noqa: E402
from scipy.stats import norm  # noqa: E402

from pkf.report.metrics import (  # noqa: E402
    CHI2_NDF_CUTS,
    ETA_EDGES,
    MASS_WINDOW_MEV,
    P_EDGES_MEV,
    TRACK_TYPES,
    ReportData,
)

__all__ = ["Plot", "make_plots", "plot_file_name", "resolution_figure", "DPI"]

#: Resolution of the PNG files [dots per inch] (LHCb2 style figures are 12 × 9 inch).
DPI = 50
_STYLE = mplhep.style.LHCb2
_MARKERS = ("o", "s", "^", "D", "v", "P")
#: Resolution panels of Fig. 1: variable, axis label, scale to display units.
_RESOLUTION_PANELS = (
    ("dp_over_p", r"$\sigma(\delta p/p)$ [%]", 100.0),
    ("x", r"$\sigma(x)$ [$\mu$m]", 1000.0),
    ("tx", r"$\sigma(t_x)$ [mrad]", 1000.0),
)
_PULL_LABELS = {"x": "$x$", "y": "$y$", "tx": "$t_x$", "ty": "$t_y$", "qop": "$q/p$"}
_MASS_BIN_MEV = 10.0
#: Ratio panels show ratios within [1/limit, limit], sized to them; others are counted in the panel.
_RATIO_LIMIT = 3.0


@dataclass(frozen=True)
class Plot:
    """A written PNG: ``file`` relative to the report directory, and its caption."""

    file: str
    caption: str


def plot_file_name(stem: str, fitter: str, taken: set[str]) -> str:
    """A safe, unique PNG name ``<stem>_<fitter>.png`` (fitter names come from the data)."""
    safe = re.sub(r"[^A-Za-z0-9_.-]+", "_", fitter).strip("._") or "fitter"
    name = f"{stem}_{safe}.png"
    k = 2
    while name in taken:
        name = f"{stem}_{safe}_{k}.png"
        k += 1
    taken.add(name)
    return name


def _save(fig, path: Path) -> None:
    fig.savefig(path, dpi=DPI, format="png", bbox_inches="tight")
    plt.close(fig)


def _colors(names: list[str]) -> dict[str, str]:
    cycle = _STYLE["axes.prop_cycle"].by_key()["color"]
    return {name: cycle[i % len(cycle)] for i, name in enumerate(names)}


def _fmt(value, spec: str = ".3f") -> str:
    return "n/a" if value is None else format(value, spec)


def _no_data(ax, text: str) -> None:
    ax.text(0.5, 0.5, text, transform=ax.transAxes, ha="center", va="center", fontsize=20, wrap=True)
    ax.set_xticks([])
    ax.set_yticks([])


# ----------------------------------------------------------------------------- Fig. 1


def _values(values: list, scale: float = 1.0) -> np.ndarray:
    """A summary list (None where undefined) as floats (NaN where undefined), times ``scale``."""
    return np.array([np.nan if v is None else v * scale for v in values], dtype=float)


def _bounded_ylim(ax, values: np.ndarray, floor: float | None = None, pad: float = 0.15) -> None:
    """Y range sized to the finite ``values`` with ``pad`` of their span (or of their size) around them."""
    finite = values[np.isfinite(values)]
    if finite.size == 0:
        return
    lo, hi = float(finite.min()), float(finite.max())
    span = (hi - lo) or abs(hi) or 1.0
    lo, hi = lo - pad * span, hi + pad * span
    ax.set_ylim(max(lo, floor) if floor is not None else lo, hi)


def resolution_figure(data: ReportData):
    """Fig. 1 as a matplotlib figure (None without resolution data): per variable (columns δp/p,
    x, tx), the Gaussian core σ vs p on a linear axis sized to the cores (the paper's quantity),
    its ratio to the reference entry bounded to the ratios, and the RMS in its own panel (log axis
    when it spans more than a factor 20: it carries the tails)."""
    summary = data.summary
    names = [n for n in data.entry_order if summary["entries"][n]["resolution"]["available"]]
    if not names:
        return None
    reference = summary["reference"]
    colors = _colors(data.entry_order)
    edges = P_EDGES_MEV / 1000.0
    centres, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * (edges[1:] - edges[:-1])
    fig, axes = plt.subplots(3, 3, figsize=(33, 20), sharex="col",
                             gridspec_kw={"height_ratios": [3, 1.2, 2], "hspace": 0.08})
    for col, (var, label, scale) in enumerate(_RESOLUTION_PANELS):
        ax, rax, rms_ax = axes[0, col], axes[1, col], axes[2, col]
        cores, ratios, rmss = [], [], []
        for i, name in enumerate(names):
            res = summary["entries"][name]["resolution"]
            bins = res["variables"][var]["bins"]
            marker, color = _MARKERS[i % len(_MARKERS)], colors[name]
            core = _values(bins["core_sigma"], scale)
            core_err = _values(bins["core_sigma_error"], scale)
            rms = _values(bins["rms"], scale)
            cores.append(core)
            rmss.append(rms)
            ax.errorbar(centres, core, xerr=half, yerr=np.nan_to_num(core_err), fmt=marker, color=color,
                        label=name)
            rms_ax.errorbar(centres, rms, xerr=half, fmt=marker, color=color, mfc="none", label=name)
            ratio = res.get("ratio_to_reference")
            if ratio is not None:
                r_core = _values(ratio[var]["core_sigma"])
                ratios.append(r_core)
                rax.errorbar(centres, r_core, xerr=half, fmt=marker, color=color)
        _bounded_ylim(ax, np.concatenate(cores), floor=0.0)
        ax.set_ylabel(f"core {label}")
        ax.legend(fontsize=16, loc="upper right")
        rax.axhline(1.0, color="grey", lw=1.5, ls="--")
        if ratios:
            all_ratios = np.concatenate(ratios)
            shown = all_ratios[(all_ratios > 1 / _RATIO_LIMIT) & (all_ratios < _RATIO_LIMIT)]
            _bounded_ylim(rax, np.r_[shown, 1.0], pad=0.25)
            outside = int(np.sum(np.isfinite(all_ratios))) - shown.size
            if outside:
                rax.text(0.02, 0.9, f"{outside} ratio(s) beyond ×{_RATIO_LIMIT:g} not shown", fontsize=14,
                         transform=rax.transAxes, va="top")
        else:
            rax.text(0.5, 0.5, f"reference entry: {reference}", transform=rax.transAxes, ha="center",
                     va="center", fontsize=16)
        rax.set_ylabel(f"core / {reference.split('/')[-1]}", fontsize=18)
        all_rms = np.concatenate(rmss)
        positive = all_rms[np.isfinite(all_rms) & (all_rms > 0)]
        if positive.size and positive.max() / positive.min() > 20:
            rms_ax.set_yscale("log")
            rms_ax.set_ylim(positive.min() / 2, positive.max() * 2)
        else:
            _bounded_ylim(rms_ax, all_rms, floor=0.0)
        rms_ax.set_ylabel(f"RMS {label}", fontsize=20)
        rms_ax.set_xlabel(r"$p_\mathrm{true}$ [GeV]")
        rms_ax.set_xscale("log")
        rms_ax.set_xlim(edges[0], edges[-1])
    return fig


def _plot_resolution(data: ReportData, out: Path) -> list[Plot]:
    fig = resolution_figure(data)
    if fig is None:
        return []
    _save(fig, out / "resolution.png")
    reference = data.summary["reference"]
    caption = (f"Resolution at the first hit vs true momentum per entry: Gaussian core σ of δp/p, x and tx "
               f"(top, linear), its ratio to the reference entry {reference} (middle), and the RMS, which "
               "carries the tails (bottom).")
    return [Plot("resolution.png", caption)]


# ----------------------------------------------------------------------------- Fig. 2


def _plot_pulls(data: ReportData, out: Path, taken: set[str]) -> list[Plot]:
    plots = []
    for name in data.entry_order:
        section = data.summary["entries"][name]["pulls"]
        if not section["available"]:
            continue
        arrays = data.arrays[name]
        fig, axes = plt.subplots(2, 3, figsize=(33, 20))
        for ax, par in zip(axes.flat, ("qop", "x", "tx", "y", "ty")):
            h = arrays.pulls[par]  # pkf.report.metrics.pull_histogram
            mplhep.histplot(h, ax=ax, yerr=True, histtype="errorbar", color="black", label=f"{name}")
            stats = section["parameters"][par]
            text = [f"RMS = {_fmt(stats['rms'])}"]
            if not stats["valid"]:
                text = ["no Gaussian core" + (f" (KS distance {stats['core_distance']:.3f})"
                                              if stats.get("core_distance") is not None else "")] + text
            elif stats["width"] is not None and stats["mean"] is not None:
                width = h.axes[0].widths[0]
                # the core fit is normalised to its ±3σ window, which holds n_core pulls
                scale = stats["n_core"] / (norm.cdf(3) - norm.cdf(-3)) * width
                grid = np.linspace(-5, 5, 400)
                ax.plot(grid, scale * norm.pdf(grid, stats["mean"], stats["width"]), color="#FF3333",
                        label="Gaussian fit")
                text = [f"mean = {_fmt(stats['mean'])} $\\pm$ {_fmt(stats['mean_error'])}",
                        f"width = {_fmt(stats['width'])} $\\pm$ {_fmt(stats['width_error'])}"] + text
            text.append(f"outside $\\pm$5: {arrays.pulls_outside[par]}")
            ax.text(0.03, 0.97, "\n".join(text), transform=ax.transAxes, va="top", ha="left", fontsize=18)
            ax.set_xlabel(f"pull {_PULL_LABELS[par]}")
            ax.set_ylabel("tracks / 0.2")
            ax.set_ylim(0, 1.3 * max(float(h.values().max()), 1.0))
            ax.legend(fontsize=18, loc="upper right")
        axes.flat[-1].axis("off")
        axes.flat[-1].text(0.0, 0.6, f"{name}\npulls at the first hit\nlong tracks\n(fit − true)/σ", fontsize=26,
                           transform=axes.flat[-1].transAxes, va="center")
        file = plot_file_name("pulls", name, taken)
        _save(fig, out / file)
        plots.append(Plot(file, f"Pulls of {name} at the first hit, long tracks (other track types: table "
                                f"and summary.json pulls.by_type), with the Gaussian core fit (iterative ±3σ, "
                                f"unbinned) where a Gaussian describes the core; mean, width and RMS in the legend."))
    return plots


# ----------------------------------------------------------------------------- Fig. 3


def _plot_chi2(data: ReportData, out: Path) -> list[Plot]:
    names = data.entry_order
    if not names:
        return []
    colors = _colors(names)
    n = len(names) + 1
    fig, axes = plt.subplots(1, n, figsize=(11 * n, 9))
    bins = np.linspace(0, 10, 51)
    any_ghosts = False
    for ax, name in zip(axes, names):
        arrays = data.arrays[name]
        section = data.summary["entries"][name]["chi2"]
        series = ([("real", arrays.chi2_ndf_real, "black"), ("ghost", arrays.chi2_ndf_ghost, "#FF3333")]
                  if section["has_mc"] else [("all tracks", arrays.chi2_ndf_all, "black")])
        drawn = False
        for label, h, color in series:
            if h is None:
                continue
            mplhep.histplot(h, ax=ax, density=True, yerr=False, color=color, label=f"{label} ({int(h.sum())})")
            drawn = True
        any_ghosts |= bool(section["has_ghosts"])
        if not drawn:
            _no_data(ax, f"{name}: no fitted track")
            continue
        ax.set_yscale("log")
        ax.set_ylim(None, ax.get_ylim()[1] * 5)
        ax.set_xlim(bins[0], bins[-1])
        ax.set_xlabel(r"$\chi^2_\mathrm{track}/N_\mathrm{dof}$")
        ax.set_ylabel("normalised")
        ax.set_title(name, fontsize=26)
        ax.legend(fontsize=18, loc="upper right")
        if section["has_mc"] and not section["has_ghosts"]:
            ax.text(0.97, 0.6, "no ghost tracks", transform=ax.transAxes, ha="right", fontsize=20, color="#FF3333")
    ax = axes[-1]
    cuts = np.asarray(CHI2_NDF_CUTS)
    for i, name in enumerate(names):
        scan = data.summary["entries"][name]["chi2"]["cut_scan"]
        marker = _MARKERS[i % len(_MARKERS)]
        eff = scan.get("real_efficiency") or scan.get("all_efficiency")
        if eff is None:
            continue
        eff = np.array([np.nan if v is None else v for v in eff])
        if any_ghosts and scan["ghost_rejection"] is not None:
            rej = np.array([np.nan if v is None else v for v in scan["ghost_rejection"]])
            ax.plot(eff, rej, marker=marker, color=colors[name], label=name, markersize=10, lw=2)
        elif not any_ghosts:
            ax.plot(cuts, eff, marker=marker, color=colors[name], label=name, markersize=10, lw=2)
    if any_ghosts:
        ax.set_xlabel("real track efficiency")
        ax.set_ylabel("ghost rejection")
        ax.set_xlim(0, 1.02)
        ax.set_ylim(0, 1.02)
    else:
        ax.set_xlabel(r"cut on $\chi^2/N_\mathrm{dof}$")
        ax.set_ylabel("track efficiency")
        ax.set_ylim(0, 1.05)
        ax.text(0.95, 0.1, "no ghost tracks:\nrejection undefined", transform=ax.transAxes, ha="right",
                fontsize=20)
    ax.legend(fontsize=18, loc="lower left")
    _save(fig, out / "chi2.png")
    caption = ("χ²/ndf of real (black) and ghost (red) tracks per fitter, normalised (overflow in the last bin); "
               "right: real-track efficiency vs ghost rejection for upper cuts on χ²/ndf "
               f"({cuts[0]:g} to {cuts[-1]:g}).")
    return [Plot("chi2.png", caption)]


# ----------------------------------------------------------------------------- Fig. 4


def _plot_mass(data: ReportData, out: Path) -> list[Plot]:
    names = [n for n in data.entry_order if data.arrays[n].masses.size]
    if not names:
        return []
    colors = _colors(data.entry_order)
    lo, hi = MASS_WINDOW_MEV
    nbins = int(round((hi - lo) / _MASS_BIN_MEV))
    fig, axes = plt.subplots(1, len(names), figsize=(12 * len(names), 9), squeeze=False)
    for ax, name in zip(axes[0], names):
        arrays = data.arrays[name]
        h = hist.Hist(hist.axis.Regular(nbins, lo, hi, name="mass"))
        h.fill(arrays.masses)
        mplhep.histplot(h, ax=ax, yerr=True, histtype="errorbar", color="black", label=f"{name} candidates")
        fit = arrays.mass_fit
        if fit is not None and np.isfinite(fit.sigma):
            grid = np.linspace(lo, hi, 500)
            ax.plot(grid, fit.density(grid) * _MASS_BIN_MEV, color=colors[name],
                    label=f"fit: $\\sigma$ = {fit.sigma:.1f} $\\pm$ {fit.sigma_error:.1f} MeV")
            ax.plot(grid, fit.background_density(grid) * _MASS_BIN_MEV, color=colors[name], ls="--",
                    label="background")
            ax.text(0.03, 0.97, f"$\\mu$ = {fit.mean:.1f} $\\pm$ {fit.mean_error:.1f} MeV\n"
                                f"$N_\\mathrm{{sig}}$ = {fit.n_signal:.0f}\nstatus: {fit.status}",
                    transform=ax.transAxes, va="top", fontsize=18)
        elif fit is not None:
            ax.text(0.03, 0.97, f"no fit: {fit.status}", transform=ax.transAxes, va="top", fontsize=18)
        ax.set_xlim(lo, hi)
        ax.set_ylim(0, 1.35 * max(float(h.values().max()), 1.0))
        ax.set_xlabel(r"$m(K^+K^-K^+K^-)$ [MeV]")
        ax.set_ylabel(f"candidates / {_MASS_BIN_MEV:g} MeV")
        ax.legend(fontsize=18, loc="upper right")
    _save(fig, out / "mass.png")
    caption = ("B_s⁰ → φφ invariant mass from all kaon tracks of each event (kaon identification from MC "
               "truth; K⁺K⁻ in the φ window, four kaons within a few mm in z; beamline states) per entry, "
               "with the Gaussian + linear background fit (extended unbinned maximum likelihood).")
    return [Plot("mass.png", caption)]


def _plot_chi2_types(data: ReportData, out: Path) -> list[Plot]:
    """χ²/ndf of real and ghost tracks per entry (rows) and track type (columns), and per type the
    real-track efficiency vs ghost rejection of every entry (last column)."""
    names = [n for n in data.entry_order if data.arrays[n].chi2_ndf_by_type]
    kinds = [k for k in TRACK_TYPES if any(k in data.arrays[n].chi2_ndf_by_type for n in names)]
    if not names or len(kinds) < 2:  # one type only: chi2.png shows it
        return []
    colors = _colors(names)
    fig, axes = plt.subplots(len(names) + 1, len(kinds), figsize=(11 * len(kinds), 8 * (len(names) + 1)),
                             squeeze=False, gridspec_kw={"hspace": 0.35})
    for row, name in enumerate(names):
        by_type = data.arrays[name].chi2_ndf_by_type
        has_mc = data.summary["entries"][name]["chi2"]["has_mc"]
        for col, kind in enumerate(kinds):
            ax = axes[row, col]
            real, ghost = by_type.get(kind, (None, None))
            series = [("real", real, "black"), ("ghost", ghost, "#FF3333")] if has_mc else [("all", real, "black")]
            drawn = False
            for label, h, color in series:
                if h is not None:
                    mplhep.histplot(h, ax=ax, density=True, yerr=False, color=color,
                                    label=f"{label} ({int(h.sum())})")
                    drawn = True
            ax.set_title(f"{name}: {kind}", fontsize=24)
            if not drawn:
                _no_data(ax, f"no {kind} track")
                continue
            ax.set_yscale("log")
            ax.set_ylim(None, ax.get_ylim()[1] * 5)
            ax.set_xlim(0, 10)
            ax.set_xlabel(r"$\chi^2_\mathrm{track}/N_\mathrm{dof}$")
            ax.set_ylabel("normalised")
            ax.legend(fontsize=16, loc="upper right")
    for col, kind in enumerate(kinds):
        ax = axes[-1, col]
        drawn = False
        for i, name in enumerate(names):
            section = data.summary["entries"][name]["chi2"]["by_type"].get(kind)
            scan = (section or {}).get("cut_scan") or {}
            if scan.get("real_efficiency") is None or scan.get("ghost_rejection") is None:
                continue
            eff = np.array([np.nan if v is None else v for v in scan["real_efficiency"]])
            rej = np.array([np.nan if v is None else v for v in scan["ghost_rejection"]])
            ax.plot(eff, rej, marker=_MARKERS[i % len(_MARKERS)], color=colors[name], label=name,
                    markersize=10, lw=2)
            drawn = True
        ax.set_title(f"{kind}: efficiency vs ghost rejection", fontsize=24)
        if not drawn:
            _no_data(ax, f"no {kind} ghost or real tracks to compare")
            continue
        ax.set_xlabel("real track efficiency")
        ax.set_ylabel("ghost rejection")
        ax.set_xlim(0, 1.02)
        ax.set_ylim(0, 1.02)
        ax.legend(fontsize=16, loc="lower left")
    _save(fig, out / "chi2_types.png")
    caption = ("χ²/ndf of real (black) and ghost (red) tracks per entry and track type (long: VELO+UT+SciFi, "
               "upstream: VELO+UT, velo: VELO only), normalised, overflow in the last bin; bottom row: per type, "
               "real-track efficiency vs ghost rejection for upper cuts on χ²/ndf.")
    return [Plot("chi2_types.png", caption)]


# ----------------------------------------------------------------------------- efficiency


def _plot_efficiency(data: ReportData, out: Path) -> list[Plot]:
    names = [n for n in data.entry_order if data.summary["entries"][n]["efficiency"]["available"]]
    if not names:
        return []
    colors = _colors(data.entry_order)
    fig, axes = plt.subplots(1, 2, figsize=(24, 9))
    for ax, key, edges, label in ((axes[0], "vs_p", P_EDGES_MEV / 1000.0, r"$p$ [GeV]"),
                                  (axes[1], "vs_eta", ETA_EDGES, r"$\eta$")):
        centres, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * (edges[1:] - edges[:-1])
        for i, name in enumerate(names):
            section = data.summary["entries"][name]["efficiency"][key]
            eff = np.array([np.nan if v is None else v for v in section["efficiency"]])
            lo = np.array([0.0 if v is None else v for v in section["error_low"]])
            hi = np.array([0.0 if v is None else v for v in section["error_high"]])
            ax.errorbar(centres, eff, xerr=half, yerr=[lo, hi], fmt=_MARKERS[i % len(_MARKERS)],
                        color=colors[name], label=name)
        ax.set_xlabel(label)
        ax.set_ylabel("efficiency")
        ax.set_ylim(0, 1.1)
        ax.set_xlim(edges[0], edges[-1])
        ax.legend(fontsize=18, loc="lower right")
    axes[0].set_xscale("log")
    _save(fig, out / "efficiency.png")
    caption = ("Efficiency for reconstructible long particles (fitted track with status ok matched to the particle) "
               "vs true momentum and pseudorapidity, Clopper–Pearson 68% errors.")
    return [Plot("efficiency.png", caption)]


def _plot_efficiency_types(data: ReportData, out: Path) -> list[Plot]:
    """Efficiency vs p and η per track type (rows), every entry in each panel."""
    names = [n for n in data.entry_order if data.summary["entries"][n]["efficiency"].get("by_type")]
    kinds = [k for k in TRACK_TYPES if any(k in data.summary["entries"][n]["efficiency"]["by_type"] for n in names)]
    if not names or len(kinds) < 2:  # long only: efficiency.png shows it
        return []
    colors = _colors(data.entry_order)
    fig, axes = plt.subplots(len(kinds), 2, figsize=(24, 9 * len(kinds)), squeeze=False, gridspec_kw={"hspace": 0.3})
    for row, kind in enumerate(kinds):
        for ax, key, edges, label in ((axes[row, 0], "vs_p", P_EDGES_MEV / 1000.0, r"$p$ [GeV]"),
                                      (axes[row, 1], "vs_eta", ETA_EDGES, r"$\eta$")):
            centres, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * (edges[1:] - edges[:-1])
            for i, name in enumerate(names):
                section = data.summary["entries"][name]["efficiency"]["by_type"].get(kind)
                if section is None:
                    continue
                bins = section[key]
                eff = np.array([np.nan if v is None else v for v in bins["efficiency"]])
                lo = np.array([0.0 if v is None else v for v in bins["error_low"]])
                hi = np.array([0.0 if v is None else v for v in bins["error_high"]])
                ax.errorbar(centres, eff, xerr=half, yerr=[lo, hi], fmt=_MARKERS[i % len(_MARKERS)],
                            color=colors[name], label=f"{name} ({section['efficiency']:.3f})")
            ax.set_title(f"{kind} tracks", fontsize=24)
            ax.set_xlabel(label)
            ax.set_ylabel("efficiency")
            ax.set_ylim(0, 1.1)
            ax.set_xlim(edges[0], edges[-1])
            ax.legend(fontsize=16, loc="lower right")
        axes[row, 0].set_xscale("log")
    _save(fig, out / "efficiency_types.png")
    caption = ("Efficiency per track type vs true momentum and pseudorapidity, Clopper–Pearson 68% errors: "
               "long (≥ 3 VELO hits, x and stereo hits in every SciFi station) found by a long track; upstream "
               "(≥ 3 VELO and ≥ 3 UT hits) found by an upstream or long track; velo (≥ 3 VELO hits) found by any "
               "track (all fitted with status ok). The legend gives the integrated efficiency.")
    return [Plot("efficiency_types.png", caption)]


def _plot_timing(data: ReportData, out: Path) -> list[Plot]:
    """Fit speed per entry: tracks per CPU second of the fit kernels and the speed-up over the
    reference entry."""
    names = [n for n in data.entry_order if data.summary["entries"][n]["timing"]["available"]
             and data.summary["entries"][n]["timing"]["tracks_per_s"]]
    if not names:
        return []
    colors = _colors(data.entry_order)
    timing = [data.summary["entries"][n]["timing"] for n in names]
    rate = np.array([t["tracks_per_s"] for t in timing], dtype=float)
    speed_up = np.array([np.nan if t["speed_up_vs_reference"] is None else t["speed_up_vs_reference"]
                         for t in timing], dtype=float)
    fig, axes = plt.subplots(1, 2, figsize=(26, max(6, 1.2 * len(names) + 3)), gridspec_kw={"wspace": 0.45})
    y = np.arange(len(names))
    for ax, values, label in ((axes[0], rate, "tracks / CPU second of the fit"),
                              (axes[1], speed_up, f"speed-up over {data.summary['reference']}")):
        ax.barh(y, np.nan_to_num(values), color=[colors[n] for n in names])
        for yi, v in zip(y, values):
            if np.isfinite(v):
                ax.text(v, yi, f" {v:,.0f}" if v >= 100 else f" {v:.2f}", va="center", fontsize=18)
        ax.set_yticks(y, names, fontsize=18)
        ax.invert_yaxis()
        ax.set_xlabel(label)
    axes[0].set_xlim(0, 1.3 * np.nanmax(rate))
    finite = speed_up[np.isfinite(speed_up)]
    axes[1].set_xlim(0, 1.25 * max(finite.max() if finite.size else 1.0, 1.0))
    axes[1].axvline(1.0, color="grey", ls="--", lw=1.5)
    _save(fig, out / "timing.png")
    caption = ("Fit speed per entry (run.json timing.fit, after JIT warm-up): tracks per CPU second of the fit "
               "kernels summed over workers, and the speed-up over the reference entry (fair within one run).")
    return [Plot("timing.png", caption)]


def make_plots(data: ReportData, out: Path) -> dict[str, list[Plot]]:
    """Write every plot of the report into ``out``; per section id, the plots written."""
    out = Path(out)
    taken = {"resolution.png", "chi2.png", "chi2_types.png", "mass.png", "efficiency.png", "efficiency_types.png",
             "timing.png"}
    with plt.style.context(_STYLE):
        return {
            "resolution": _plot_resolution(data, out),
            "pulls": _plot_pulls(data, out, taken),
            "chi2": _plot_chi2(data, out) + _plot_chi2_types(data, out),
            "mass": _plot_mass(data, out),
            "efficiency": _plot_efficiency(data, out) + _plot_efficiency_types(data, out),
            "timing": _plot_timing(data, out),
        }
