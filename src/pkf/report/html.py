"""The report page: a self-contained ``index.html`` with one section per figure type and tables of the numbers.

No external URL is referenced (no scripts, fonts or style sheets from elsewhere):
the CSS is inline and the plots are the PNG files beside the page, referenced by
relative name. Section ids are stable (:data:`SECTION_IDS`) so that links and tests
can rely on them.
"""

from __future__ import annotations

import html
from collections.abc import Iterable
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # plots imports matplotlib; the page only needs file names and captions
    from pkf.report.plots import Plot

__all__ = ["SECTION_IDS", "render_html"]

#: Section ids of index.html, in page order.
SECTION_IDS = ("resolution", "pulls", "chi2", "mass", "efficiency", "timing")
_TITLES = {
    "resolution": "Resolution vs momentum (paper Fig. 1)",
    "pulls": "Pulls at the first hit (paper Fig. 2)",
    "chi2": "Track χ²/ndf: real vs ghost tracks (paper Fig. 3)",
    "mass": "B<sub>s</sub><sup>0</sup> → φφ mass (paper Fig. 4)",
    "efficiency": "Reconstruction efficiency, ghost and clone rates",
    "timing": "Fit timing and speed-up",
}

_CSS = """
body { font-family: sans-serif; margin: 1.5em auto; max-width: 1400px; color: #222; padding: 0 1em; }
h1 { font-size: 1.6em; } h2 { border-bottom: 2px solid #0078ff; padding-bottom: .2em; margin-top: 2em; }
table { border-collapse: collapse; margin: .8em 0; font-size: .9em; }
th, td { border: 1px solid #bbb; padding: .25em .6em; text-align: right; }
th { background: #eef3fb; } td.l, th.l { text-align: left; }
figure { margin: 1em 0; } figure img { max-width: 100%; height: auto; border: 1px solid #ddd; }
figcaption { font-size: .9em; color: #444; }
p.note { background: #fff6e0; border-left: 4px solid #f0a000; padding: .4em .8em; }
nav a { margin-right: 1em; }
"""


def _esc(value) -> str:
    return html.escape(str(value), quote=True)


def _num(value, fmt: str = ".4g", scale: float = 1.0) -> str:
    if value is None:
        return "–"
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, int):
        return str(value)
    return format(value * scale, fmt)


def _pm(value, error, fmt: str = ".4g", scale: float = 1.0) -> str:
    if value is None:
        return "–"
    if error is None:
        return _num(value, fmt, scale)
    return f"{_num(value, fmt, scale)} ± {_num(error, '.2g', scale)}"


def _table(header: list[str], rows: Iterable[list[str]], left: int = 1) -> str:
    """An HTML table; cells are already escaped; the first ``left`` columns are left-aligned."""
    head = "".join(f'<th class="l">{h}</th>' if i < left else f"<th>{h}</th>" for i, h in enumerate(header))
    body = []
    for row in rows:
        cells = "".join(f'<td class="l">{c}</td>' if i < left else f"<td>{c}</td>" for i, c in enumerate(row))
        body.append(f"<tr>{cells}</tr>")
    return f"<table><thead><tr>{head}</tr></thead><tbody>{''.join(body)}</tbody></table>"


def _figures(plots: list[Plot]) -> str:
    return "".join(
        f'<figure><img src="{_esc(p.file)}" alt="{_esc(p.caption)}"><figcaption>{_esc(p.caption)}'
        f"</figcaption></figure>"
        for p in plots
    )


def _notes(summary: dict, section: str) -> str:
    notes = []
    for name, rep in summary["entries"].items():
        note = rep[section].get("note")
        if note:
            notes.append(f'<p class="note">{_esc(name)}: {_esc(note)}</p>')
    return "".join(notes)


def _resolution(summary: dict) -> str:
    edges = summary["settings"]["p_edges_mev"]
    labels = [f"{edges[i] / 1000:g}–{edges[i + 1] / 1000:g}" for i in range(len(edges) - 1)]
    parts = []
    for var, title, scale, unit in (("dp_over_p", "δp/p", 100.0, "%"), ("x", "x", 1000.0, "µm"),
                                    ("y", "y", 1000.0, "µm"), ("tx", "t<sub>x</sub>", 1000.0, "mrad"),
                                    ("ty", "t<sub>y</sub>", 1000.0, "mrad")):
        rows = []
        for name, rep in summary["entries"].items():
            res = rep["resolution"]
            if not res["available"]:
                continue
            v = res["variables"][var]
            rows.append([f"{_esc(name)} RMS", _num(v["all"]["rms"], ".3g", scale)]
                        + [_num(x, ".3g", scale) for x in v["bins"]["rms"]])
            rows.append([f"{_esc(name)} core σ", _pm(v["all"]["core_sigma"], v["all"]["core_sigma_error"], ".3g",
                                                     scale)]
                        + [_pm(x, e, ".3g", scale) for x, e in zip(v["bins"]["core_sigma"],
                                                                    v["bins"]["core_sigma_error"])])
            ratio = res.get("ratio_to_reference")
            if ratio:
                rows.append([f"{_esc(name)} RMS / reference", ""] + [_num(x, ".3f") for x in ratio[var]["rms"]])
                rows.append([f"{_esc(name)} core σ / reference", ""]
                            + [_num(x, ".3f") for x in ratio[var]["core_sigma"]])
            rows.append([f"{_esc(name)} tracks", _num(v["all"]["n"])] + [_num(x) for x in v["bins"]["n"]])
        if rows:
            parts.append(f"<h3>{title} [{unit}]</h3>" + _table(["entry", "all p"] + [f"{lab} GeV" for lab in labels],
                                                                rows))
    return "".join(parts)


def _pulls(summary: dict) -> str:
    rows = []
    for name, rep in summary["entries"].items():
        if not rep["pulls"]["available"]:
            continue
        for par, s in rep["pulls"]["parameters"].items():
            rows.append([_esc(name), _esc(par), _pm(s["mean"], s["mean_error"], ".3f"),
                         _pm(s["width"], s["width_error"], ".3f"), _num(s["rms"], ".3f"), _num(s["n"]),
                         _num(s["n_core"]), _num(s["valid"])])
    if not rows:
        return ""
    return _table(["entry", "parameter", "mean", "width", "RMS", "tracks", "in core", "Gaussian core"], rows, left=2)


def _chi2(summary: dict) -> str:
    rows = []
    for name, rep in summary["entries"].items():
        c = rep["chi2"]
        for kind in ("real", "ghost", "all"):
            d = c.get(kind)
            if d is None:
                continue
            rows.append([_esc(name), kind, _num(d["n"]), _num(d["mean"], ".3f"), _num(d["median"], ".3f"),
                         _num(d["q90"], ".3f"), _num(d["q99"], ".3f")])
    parts = [_table(["entry", "tracks", "n", "mean", "median", "90% quantile", "99% quantile"], rows, left=2)]
    cuts = summary["settings"]["chi2_ndf_cuts"]
    scan_rows = []
    for name, rep in summary["entries"].items():
        scan = rep["chi2"]["cut_scan"]
        if scan.get("real_efficiency") is not None:
            scan_rows.append([_esc(name), "real efficiency"] + [_num(v, ".3f") for v in scan["real_efficiency"]])
        if scan.get("ghost_rejection") is not None:
            scan_rows.append([_esc(name), "ghost rejection"] + [_num(v, ".3f") for v in scan["ghost_rejection"]])
        if scan.get("all_efficiency") is not None:
            scan_rows.append([_esc(name), "track efficiency"] + [_num(v, ".3f") for v in scan["all_efficiency"]])
    if scan_rows:
        parts.append("<h3>Cut χ²/ndf &lt; c</h3>" + _table(["entry", "fraction"] + [f"{c:g}" for c in cuts],
                                                           scan_rows, left=2))
    return "".join(parts)


def _mass(summary: dict) -> str:
    rows = []
    for name, rep in summary["entries"].items():
        m = rep["mass"]
        fit = m.get("fit")
        if fit is None:
            continue
        rows.append([_esc(name), _esc(m["location"]), _num(m.get("n_signal_decays")), _num(m.get("n_truth_matched")),
                     _num(fit["n_candidates"]), _num(m.get("n_signal_candidates")),
                     _pm(fit["mean"], fit["mean_error"], ".1f"),
                     _pm(fit["sigma"], fit["sigma_error"], ".2f"), _pm(fit["n_signal"], fit["n_signal_error"], ".1f"),
                     _pm(fit["n_background"], fit["n_background_error"], ".1f"), _esc(fit["status"])])
    if not rows:
        return ""
    html = _table(["entry", "state", "B<sub>s</sub> decays", "truth-matched", "candidates in window",
                   "of four signal kaons", "mean [MeV]", "σ [MeV]",
                   "N<sub>sig</sub>", "N<sub>bkg</sub>", "fit status"], rows, left=2)
    ratios = []
    for name, rep in summary["entries"].items():
        cmp_ = rep["mass"].get("ratio_to_reference")
        if not cmp_ or cmp_.get("fit") is None or cmp_.get("reference_fit") is None:
            continue
        ratios.append([_esc(name), _num(cmp_["n_candidates"]),
                       _pm(cmp_["fit"]["sigma"], cmp_["fit"]["sigma_error"], ".2f"),
                       _pm(cmp_["reference_fit"]["sigma"], cmp_["reference_fit"]["sigma_error"], ".2f"),
                       _pm(cmp_["sigma_ratio"], cmp_["sigma_ratio_error"], ".3f")])
    if ratios:
        html += ("<h3>σ on the common candidates (the same decays and kaons for both fitters; "
                 "error: jackknife)</h3>" + _table(["entry", "common candidates", "σ [MeV]", "σ reference [MeV]",
                                                     "σ / σ reference"], ratios, left=1))
    return html


def _efficiency(summary: dict) -> str:
    parts = []
    rows = []
    for run in summary["runs"]:
        pj = run["pattern"]["run_json"] or {}
        rc = run["pattern"]["recomputed"] or {}
        rows.append([_esc(run["path"]), _esc(run.get("pattern_recognition")), _num(pj.get("efficiency"), ".4f"),
                     _num(rc.get("efficiency"), ".4f"), _num(pj.get("ghost_rate"), ".4f"),
                     _num(rc.get("ghost_rate"), ".4f"), _num(pj.get("clone_rate"), ".4f"),
                     _num(rc.get("clone_rate"), ".4f"), _num(rc.get("reconstructible"))])
    parts.append("<h3>Pattern recognition (all candidates)</h3>" + _table(
        ["run", "pattern", "efficiency (run.json)", "efficiency (recomputed)", "ghost rate (run.json)",
         "ghost rate (recomputed)", "clone rate (run.json)", "clone rate (recomputed)", "reconstructible"], rows,
        left=2))
    rows = []
    for name, rep in summary["entries"].items():
        e = rep["efficiency"]
        if not e["available"]:
            continue
        rows.append([_esc(name), _num(e["reconstructible"]), _num(e["found"]), _num(e["efficiency"], ".4f"),
                     _num(e["ghost_rate"], ".4f"), _num(e["clone_rate"], ".4f")])
    if rows:
        parts.append("<h3>Per fitter (tracks with fit status ok)</h3>" + _table(
            ["fitter", "reconstructible", "found", "efficiency", "ghost rate", "clone rate"], rows))
        for key, edges_key, title, scale, unit in (("vs_p", "p_edges_mev", "vs p", 1e-3, " GeV"),
                                                   ("vs_eta", "eta_edges", "vs η", 1.0, "")):
            edges = summary["settings"][edges_key]
            header = ["entry"] + [f"{lo * scale:g}–{hi * scale:g}{unit}" for lo, hi in zip(edges[:-1], edges[1:])]
            brows = []
            for name, rep in summary["entries"].items():
                e = rep["efficiency"]
                if not e["available"]:
                    continue
                b = e[key]
                brows.append([_esc(name)] + [
                    f"{_num(v, '.3f')} ({k}/{n})" if v is not None else "–"
                    for v, k, n in zip(b["efficiency"], b["found"], b["reconstructible"])
                ])
            parts.append(f"<h3>Efficiency {title}</h3>" + _table(header, brows))
    return "".join(parts)


def _timing(summary: dict) -> str:
    rows = []
    for name, rep in summary["entries"].items():
        t = rep["timing"]
        if not t["available"]:
            continue
        same = t.get("same_run_as_reference")
        rows.append([_esc(name), _esc(summary["runs"][rep["run"]]["path"]), _num(t["tracks"]),
                     _num(t["wall_s"], ".4g"), _num(t["cpu_s"], ".4g"), _num(t["tracks_per_s"], ".4g"),
                     _num(t["ns_per_node"], ".4g"), _num(t["speed_up_vs_reference"], ".3f"),
                     _num(t["ns_per_node_ratio"], ".3f"), "–" if same is None else _num(same)])
    if not rows:
        return ""
    text = ("<p>From run.json <code>timing.fit</code>, measured after JIT warm-up: tracks/s = tracks ÷ CPU "
            "seconds of the fit kernels summed over workers (so it does not depend on <code>--workers</code>). "
            "Speed-up = tracks/s of the entry ÷ tracks/s of the reference entry; a fair ratio comes from one run "
            "on the same tracks (column “same run”).</p>")
    return text + _table(["entry", "run", "tracks", "wall [s]", "CPU [s]", "tracks/s", "ns/node",
                          "speed-up vs reference", "ns/node ratio", "same run"], rows, left=2)


def render_html(summary: dict, plots: dict[str, list[Plot]]) -> str:
    """The index.html text of a report: sections :data:`SECTION_IDS` with figures and tables."""
    tables = {"resolution": _resolution, "pulls": _pulls, "chi2": _chi2, "mass": _mass,
              "efficiency": _efficiency, "timing": _timing}
    runs_rows = [[_esc(r["label"]), _esc(r["path"]), _esc(", ".join(r["fitters"])), _num(r["events"]),
                  _esc(r.get("geometry")), _esc(r.get("pattern_recognition")), _esc(r["dataset"]),
                  _esc(r.get("dataset_hash")), _esc(r["dataset_status"])]
                 for r in summary["runs"]]
    warnings = "".join(f'<p class="note">{_esc(w)}</p>' for w in summary.get("warnings", []))
    body = [
        "<h1>pkf report</h1>",
        f"<p>pkf {_esc(summary['pkf_version'])}; entries are LABEL/FITTER; reference entry: "
        f"{_esc(summary['reference'] or 'none (no ratios or speed-ups)')}. Every number is also in "
        '<a href="summary.json">summary.json</a>.</p>',
        "<nav>" + "".join(f'<a href="#{s}">{s}</a>' for s in SECTION_IDS) + "</nav>",
        warnings,
        _table(["label", "run", "fitters", "events", "geometry", "pattern", "dataset", "dataset hash",
                "dataset status"], runs_rows, left=9),
    ]
    for section in SECTION_IDS:
        content = _figures(plots.get(section, [])) + _notes(summary, section) + tables[section](summary)
        if not content:
            content = '<p class="note">nothing to show</p>'
        body.append(f'<section id="{section}"><h2>{_TITLES[section]}</h2>{content}</section>')
    return (
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\">"
        "<meta name=\"viewport\" content=\"width=device-width, initial-scale=1\">"
        f"<title>pkf report</title><style>{_CSS}</style></head>\n<body>\n" + "\n".join(body) + "\n</body></html>\n"
    )
