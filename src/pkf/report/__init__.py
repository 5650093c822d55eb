"""Reports of runs (docs/formats.md#summaryjson, paper Figs. 1–4): metrics, fits of distributions, plots, HTML.

Modules:

- :mod:`pkf.report.runs` — read and validate run directories, merge fitters by name.
- :mod:`pkf.report.metrics` — every number of the report (summary.json; keys documented there).
- :mod:`pkf.report.massfit` — four-kaon invariant mass and the Gaussian + linear mass fit.
- :mod:`pkf.report.plots` — PNG plots (matplotlib Agg, mplhep LHCb style; imports matplotlib).
- :mod:`pkf.report.html` — the self-contained index.html.

The Gaussian core of a distribution (iterative ±3σ unbinned fits) is :mod:`pkf.params.gauss`:
the tuning uses it too, so it lives on that lower floor (the import floors of tests/test_import_floors.py).

The stage that writes a report directory is :func:`pkf.pipeline.report.run_report`.
"""
