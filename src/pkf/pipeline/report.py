"""The `pkf report` stage: run directories → REPORT/ with summary.json, index.html and PNG plots (DESIGN §11).

Inputs are validated and every number is computed before anything is written;
the report directory is then built in a hidden staging directory and renamed into
place (:func:`pkf.io.atomic.staged_output_dir`), so bad input or a crash leaves no
partial report. The summary.json keys are documented in :mod:`pkf.report.metrics`.
"""

from __future__ import annotations

from pathlib import Path

from pkf.io.atomic import atomic_write_json, check_output_apart, check_output_dir, staged_output_dir
from pkf.report.html import render_html
from pkf.report.metrics import compute_report
from pkf.report.runs import load_runs, parse_run_spec

__all__ = ["run_report", "REPORT_FILES"]

#: Files every report holds (plus the PNG plots that have data).
REPORT_FILES = ("index.html", "summary.json")


def run_report(run_specs: list, out: Path, overwrite: bool = False, reference: str | None = None,
               echo=None) -> dict:
    """Write the report of the runs ``run_specs`` into the directory ``out``; return the summary.

    Args:
        run_specs: run directories of `pkf reconstruct`, each a path, ``"RUN:LABEL"`` or a
            (path, label) pair (:func:`pkf.report.runs.parse_run_spec`); the same fitter may
            appear in several runs, whose labels must differ.
        out: report directory to create (``index.html``, ``summary.json``, PNG plots).
        overwrite: replace an existing non-empty ``out``.
        reference: ``LABEL/FITTER`` or ``LABEL`` of the entry that ratios compare with
            (default: the first ``reference`` fitter, else the first entry).
        echo: called with each warning line (e.g. runs from different datasets), if given.

    Returns:
        the summary (the contents of summary.json, before NaN → null).

    Raises:
        InputError: bad or incomplete run directory, two runs with one label, an unknown
            reference, a malformed dataset, or an ``out`` that cannot be written (one
            line; nothing is written).
    """
    run_dirs = [parse_run_spec(spec)[0] for spec in run_specs]
    check_output_dir(out, overwrite, inputs=run_dirs)
    runs = load_runs(run_specs)
    inputs = [*run_dirs, *(run.dataset_path for run in runs)]
    check_output_apart(out, inputs)
    data = compute_report(runs, reference)
    for line in data.summary["warnings"]:
        if echo:
            echo(line)

    from pkf.report.plots import make_plots  # matplotlib is imported only when a report is made

    with staged_output_dir(out, overwrite, inputs) as staging:
        plots = make_plots(data, staging)
        (staging / "index.html").write_text(render_html(data.summary, plots), encoding="utf-8")
        atomic_write_json(data.summary, staging / "summary.json")
    return data.summary
