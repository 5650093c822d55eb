"""summary.json numbers against the run tables they come from (DESIGN §10–§11)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
import pyarrow.parquet as pq
import pytest
from report_helpers import entry, read_summary, write_synthetic_run

from pkf.geometry.detector import load_geometry
from pkf.io.reader import read_table
from pkf.io.schemas import PULLS, STATES
from pkf.cli import main
from pkf.pipeline.report import run_report
from pkf.params.gauss import gaussian_core
from pkf.physics.constants import MASS_BS
from pkf.report.metrics import CHI2_NDF_CUTS, P_EDGES_MEV


def _first_hit(run, schema, name, fitter):
    table = read_table(run, schema, name=name)
    mask = pc.and_(pc.equal(table.column("fitter"), fitter), pc.equal(table.column("location"), "first_hit"))
    return table.filter(mask).to_pydict()


def _rms(v):
    v = np.asarray(v)
    return float(np.sqrt(np.mean(v**2)))


def test_summary_json_is_the_returned_summary(telescope_report):
    out, summary = telescope_report
    on_disk = read_summary(out)
    assert on_disk == json.loads(json.dumps(summary))  # no NaN in this summary: identical
    assert on_disk["kind"] == "report"
    assert on_disk["entry_order"] == ["run_parametrized/parametrized", "run_reference/reference"]
    assert on_disk["reference"] == "run_reference/reference"
    assert [r["fitters"] for r in on_disk["runs"]] == [["parametrized"], ["reference"]]


@pytest.mark.parametrize("fitter", ["parametrized", "reference"])
def test_pulls_equal_pulls_table(telescope_runs, telescope_report, fitter):
    _, summary = telescope_report
    pulls = _first_hit(telescope_runs[fitter], PULLS, "pulls", fitter)
    section = entry(summary, fitter)["pulls"]
    assert section["available"] and section["location"] == "first_hit"
    for par in ("x", "y", "tx", "ty", "qop"):
        values = np.asarray(pulls[f"pull_{par}"])
        kept = values.astype(np.float32)  # the report keeps per-track pulls as float32 (memory)
        core = gaussian_core(kept)
        got = section["parameters"][par]
        assert got["n"] == values.size > 500
        assert got["mean"] == pytest.approx(core.mean, rel=1e-12, abs=1e-15)
        assert got["width"] == pytest.approx(core.sigma, rel=1e-12)
        assert got["width_error"] == pytest.approx(core.sigma_error, rel=1e-9)
        assert got["rms"] == pytest.approx(_rms(kept.astype(np.float64)), rel=1e-12)
        # float32 moves the fit by far less than its statistical error (measured: < 1e-6 of it)
        exact = gaussian_core(values)
        assert abs(got["mean"] - exact.mean) < 1e-4 * exact.mean_error
        assert abs(got["width"] - exact.sigma) < 1e-4 * exact.sigma_error
        assert got["rms"] == pytest.approx(_rms(values), rel=1e-6)
        # the telescope fit is exact: the pulls are standard normal
        assert abs(got["mean"]) < 0.2 and 0.85 < got["width"] < 1.15


@pytest.mark.parametrize("fitter", ["parametrized", "reference"])
def test_resolutions_equal_pulls_table(telescope_runs, telescope_report, fitter):
    _, summary = telescope_report
    run = telescope_runs[fitter]
    pulls = _first_hit(run, PULLS, "pulls", fitter)
    states = _first_hit(run, STATES, "states", fitter)
    p_true = np.asarray(pulls["p_true"])
    qop_of = dict(zip(zip(states["event_id"], states["track_id"]), states["qop"]))
    qop = np.array([qop_of[k] for k in zip(pulls["event_id"], pulls["track_id"])])
    values = {"x": np.asarray(pulls["res_x"]), "tx": np.asarray(pulls["res_tx"]),
              "dp_over_p": (1.0 / np.abs(qop) - p_true) / p_true}
    res = entry(summary, fitter)["resolution"]
    assert res["p_edges_mev"] == P_EDGES_MEV.tolist()
    checked = 0
    for var, v in values.items():
        got = res["variables"][var]
        # the report keeps residuals and δp/p as float32: each value within 6e-8 relative
        assert got["all"]["rms"] == pytest.approx(_rms(v), rel=1e-7)
        assert got["all"]["core_sigma"] == pytest.approx(gaussian_core(v).sigma, rel=1e-6)
        for i, (lo, hi) in enumerate(zip(P_EDGES_MEV[:-1], P_EDGES_MEV[1:])):
            in_bin = v[(p_true >= lo) & (p_true < hi)]
            assert got["bins"]["n"][i] == in_bin.size
            if in_bin.size == 0:
                assert got["bins"]["rms"][i] is None
                continue
            assert got["bins"]["rms"][i] == pytest.approx(_rms(in_bin), rel=1e-7)
            if in_bin.size >= 10:
                assert got["bins"]["core_sigma"][i] == pytest.approx(gaussian_core(in_bin).sigma, rel=1e-6)
                checked += 1
    assert checked >= 10


def test_ratio_and_speed_up_vs_reference(telescope_runs, telescope_report):
    _, summary = telescope_report
    par, ref = entry(summary, "parametrized"), entry(summary, "reference")
    assert ref["resolution"]["ratio_to_reference"] is None
    ratio = par["resolution"]["ratio_to_reference"]["dp_over_p"]["rms"]
    for r, a, b in zip(ratio, par["resolution"]["variables"]["dp_over_p"]["bins"]["rms"],
                       ref["resolution"]["variables"]["dp_over_p"]["bins"]["rms"]):
        assert (r is None) == (a is None or b is None)
        if r is not None:
            assert r == pytest.approx(a / b, rel=1e-12)
    timing = {f: json.loads((telescope_runs[f] / "run.json").read_text())["timing"]["fit"][f]
              for f in ("parametrized", "reference")}
    assert par["timing"]["tracks_per_s"] == pytest.approx(timing["parametrized"]["tracks_per_s"])
    assert par["timing"]["speed_up_vs_reference"] == pytest.approx(
        timing["parametrized"]["tracks_per_s"] / timing["reference"]["tracks_per_s"])
    assert par["timing"]["same_run_as_reference"] is False  # two runs: not the §12 protocol
    assert ref["timing"]["speed_up_vs_reference"] == 1.0


def test_efficiency_and_rates_match_run_json(bs_run, bs_report):
    _, summary = bs_report
    run_json = json.loads((bs_run / "run.json").read_text())
    pattern = summary["runs"][0]["pattern"]
    assert pattern["run_json"] == run_json["pattern"]
    recomputed = pattern["recomputed"]
    assert recomputed["reconstructible"] == run_json["pattern"]["reconstructible"] > 100
    for key in ("efficiency", "ghost_rate", "clone_rate"):
        assert recomputed[key] == pytest.approx(run_json["pattern"][key])
    eff = entry(summary, "reference")["efficiency"]
    assert eff["available"] and eff["reconstructible"] == recomputed["reconstructible"]
    assert eff["found"] <= eff["reconstructible"] and eff["efficiency"] > 0.9
    assert sum(eff["vs_p"]["reconstructible"]) <= eff["reconstructible"]
    assert sum(eff["vs_eta"]["found"]) <= eff["found"]
    assert sum(eff["vs_eta"]["reconstructible"]) > 0.5 * eff["reconstructible"]


def _reconstructible_by_hits(dataset) -> dict[str, set]:
    """Particle keys (event, particle) with ≥ 3 VELO hits, and with ≥ 3 VELO and ≥ 3 UT hits,
    counted from the dataset's files with plain pyarrow."""
    hits = pq.read_table(dataset / "hits.parquet", columns=["event_id", "hit_id", "layer"])
    mc = pq.read_table(dataset / "mc_hits.parquet", columns=["event_id", "hit_id", "particle_id"])
    joined = hits.join(mc, ["event_id", "hit_id"]).filter(pc.greater(pc.field("particle_id"), 0))
    sub = np.asarray(load_geometry("lhcb-like").layer_subdetector)[joined.column("layer").to_numpy()]
    counts: dict[tuple[int, int], list[int]] = {}
    for ev, pid, s in zip(joined.column("event_id").to_pylist(), joined.column("particle_id").to_pylist(), sub):
        counts.setdefault((ev, pid), [0, 0, 0])[int(s)] += 1
    return {"velo": {k for k, c in counts.items() if c[0] >= 3},
            "upstream": {k for k, c in counts.items() if c[0] >= 3 and c[1] >= 3}}


def test_efficiency_per_track_type(bs_run, bs_report):
    """Issue 17.2: efficiency per track type; upstream and VELO counted from the dataset here."""
    _, summary = bs_report
    eff = entry(summary, "reference")["efficiency"]
    by_type = eff["by_type"]
    assert set(by_type) == {"long", "upstream", "velo"}
    assert by_type["long"]["reconstructible"] == eff["reconstructible"]
    assert by_type["long"]["found"] <= eff["found"]  # long tracks only
    chi2 = pa.concat_tables(pq.read_table(f) for f in sorted((bs_run / "chi2").glob("*.parquet")))
    chi2 = chi2.filter(pc.and_(pc.equal(chi2.column("status"), "ok"), pc.greater(chi2.column("mc_particle_id"), 0)))
    found_by = {}
    for ev, pid, kind in zip(chi2.column("event_id").to_pylist(), chi2.column("mc_particle_id").to_pylist(),
                             chi2.column("track_type").to_pylist()):
        found_by.setdefault(kind, set()).add((ev, pid))
    dataset = Path(summary["runs"][0]["dataset"])
    reconstructible = _reconstructible_by_hits(dataset)
    expected_found = {"velo": found_by.get("long", set()) | found_by.get("upstream", set()) | found_by.get("velo", set()),
                      "upstream": found_by.get("long", set()) | found_by.get("upstream", set())}
    for kind in ("velo", "upstream"):
        assert by_type[kind]["reconstructible"] == len(reconstructible[kind]) > 0, kind
        assert by_type[kind]["found"] == len(reconstructible[kind] & expected_found[kind]), kind
        assert sum(by_type[kind]["vs_p"]["found"]) <= by_type[kind]["found"]
        assert by_type[kind]["efficiency"] == pytest.approx(by_type[kind]["found"] / by_type[kind]["reconstructible"])
    assert by_type["velo"]["reconstructible"] >= by_type["long"]["reconstructible"]


def test_bs_mass_from_all_kaons(bs_report):
    """The peak is built from all kaon tracks (issue 17): it holds the truth-matched decays that
    pass the selection, plus combinations; the fit finds the B_s mass."""
    _, summary = bs_report
    mass = entry(summary, "reference")["mass"]
    assert mass["location"] == "beamline"
    assert mass["n_signal_decays"] == 30
    assert 10 <= mass["n_truth_matched"] <= 30
    assert mass["n_signal_candidates"] >= 0.7 * mass["n_truth_matched"]
    assert mass["n_candidates"] >= mass["n_signal_candidates"]
    fit = mass["fit"]
    assert fit["status"] == "ok", mass
    assert abs(fit["mean"] - MASS_BS) < 5 * fit["mean_error"] + 2.0
    assert 2.0 < fit["sigma"] < 60.0


def test_no_ghosts_is_said_not_invented(bs_report):
    _, summary = bs_report
    chi2 = entry(summary, "reference")["chi2"]
    assert chi2["has_mc"] and not chi2["has_ghosts"]
    assert chi2["ghost"] is None and chi2["cut_scan"]["ghost_rejection"] is None
    assert "no ghost" in chi2["note"]
    assert chi2["real"]["n"] == entry(summary, "reference")["tracks"]["matched"]


def test_chi2_scan_with_ghosts(tmp_path):
    run = tmp_path / "run"
    truth = write_synthetic_run(run, fitters=("parametrized", "reference"), ghost_fraction=0.3)
    summary = run_report([run], tmp_path / "report")
    for fitter, t in truth.items():
        chi2 = entry(summary, fitter)["chi2"]
        real = t["chi2_ndf"][t["ok"] & ~t["ghost"]]
        ghost = t["chi2_ndf"][t["ok"] & t["ghost"]]
        assert chi2["has_ghosts"] and chi2["note"] is None
        assert chi2["real"]["n"] == real.size and chi2["ghost"]["n"] == ghost.size
        assert chi2["ghost"]["median"] == pytest.approx(np.median(ghost))
        scan = chi2["cut_scan"]
        assert scan["cuts"] == CHI2_NDF_CUTS.tolist()
        for c, eff, rej in zip(scan["cuts"], scan["real_efficiency"], scan["ghost_rejection"]):
            assert eff == pytest.approx(np.mean(real < c))
            assert rej == pytest.approx(np.mean(ghost >= c))
        assert entry(summary, fitter)["tracks"]["failed"] == int((~t["ok"]).sum())
    # no dataset: the sections that need it say so
    assert not entry(summary, "reference")["mass"]["available"]
    assert "dataset" in entry(summary, "reference")["efficiency"]["note"]
    # one run, both fitters: the speed-up follows the §12 protocol
    timing = entry(summary, "parametrized")["timing"]
    assert timing["same_run_as_reference"] is True and timing["speed_up_vs_reference"] == pytest.approx(2.0)


def test_chi2_per_track_type(tmp_path):
    """Issue 17.2: χ²/ndf real vs ghost and the efficiency–rejection scan per track type, in
    summary.json (chi2.by_type) and in a figure of its own (chi2_types.png)."""
    run = tmp_path / "run"
    truth = write_synthetic_run(run, fitters=("parametrized", "reference"), n_tracks=1500, ghost_fraction=0.3,
                                track_types=("long", "upstream", "long", "velo"))
    report = tmp_path / "report"
    summary = run_report([run], report)
    for fitter, t in truth.items():
        chi2 = entry(summary, fitter)["chi2"]
        assert set(chi2["by_type"]) == {"long", "upstream", "velo"}
        for kind, section in chi2["by_type"].items():
            of_type = t["ok"] & (t["type"] == kind)
            real = t["chi2_ndf"][of_type & ~t["ghost"]]
            ghost = t["chi2_ndf"][of_type & t["ghost"]]
            assert section["real"]["n"] == real.size and section["ghost"]["n"] == ghost.size
            assert section["real"]["median"] == pytest.approx(np.median(real))
            for c, eff, rej in zip(section["cut_scan"]["cuts"], section["cut_scan"]["real_efficiency"],
                                   section["cut_scan"]["ghost_rejection"]):
                assert eff == pytest.approx(np.mean(real < c))
                assert rej == pytest.approx(np.mean(ghost >= c))
        # the types add up to the whole
        assert sum(s["real"]["n"] for s in chi2["by_type"].values()) == chi2["real"]["n"]
    assert (report / "chi2_types.png").is_file()
    assert "chi2_types.png" in (report / "index.html").read_text(encoding="utf-8")


def test_one_track_type_needs_no_figure_of_its_own(tmp_path):
    write_synthetic_run(tmp_path / "run")
    summary = run_report([tmp_path / "run"], tmp_path / "report")
    assert list(entry(summary, "parametrized")["chi2"]["by_type"]) == ["long"]
    assert not (tmp_path / "report" / "chi2_types.png").exists()


def test_run_without_mc(tmp_path):
    run = tmp_path / "run"
    write_synthetic_run(run, fitters=("reference",), has_mc=False)
    summary = run_report([run], tmp_path / "report")
    rep = entry(summary, "reference")
    assert not rep["resolution"]["available"] and "no MC" in rep["resolution"]["note"]
    assert not rep["pulls"]["available"]
    assert not rep["chi2"]["has_mc"] and rep["chi2"]["real"] is None and rep["chi2"]["all"]["n"] > 500
    assert not rep["mass"]["available"] and not rep["efficiency"]["available"]
    html = (tmp_path / "report" / "index.html").read_text()
    assert "no MC truth" in html


def test_tiny_run_has_no_fits_but_a_report(tmp_path):
    run = tmp_path / "run"
    write_synthetic_run(run, fitters=("parametrized", "reference"), n_tracks=8, ghost_fraction=0.0)
    summary = run_report([run], tmp_path / "report")
    pulls = entry(summary, "parametrized")["pulls"]["parameters"]["x"]
    assert pulls["n"] <= 8 and pulls["width"] is None and pulls["rms"] is not None
    bins = entry(summary, "parametrized")["resolution"]["variables"]["x"]["bins"]
    assert all(v is None for v in bins["core_sigma"])
    assert (tmp_path / "report" / "index.html").is_file()
    json.dumps(summary, allow_nan=False)  # undefined numbers are None, never NaN


def test_same_fitter_in_two_labelled_runs(telescope_runs, tmp_path, capsys):
    """`pkf report A:default B:tuned` with the same fitter in both (issue 17): both entries, the
    first is the reference, and the ratio of identical runs is exactly 1 in every p bin."""
    run = telescope_runs["parametrized"]
    out = tmp_path / "report"
    assert main(["report", f"{run}:default", f"{run}:tuned", "--out", str(out)]) == 0
    summary = read_summary(out)
    assert summary["entry_order"] == ["default/parametrized", "tuned/parametrized"]
    assert summary["reference"] == "default/parametrized" and summary["warnings"] == []
    tuned = summary["entries"]["tuned/parametrized"]
    default = summary["entries"]["default/parametrized"]
    assert tuned["label"] == "tuned" and tuned["fitter"] == "parametrized"
    ratios = tuned["resolution"]["ratio_to_reference"]["dp_over_p"]["core_sigma"]
    filled = [r for r in ratios if r is not None]
    assert len(filled) >= 3 and all(r == pytest.approx(1.0, abs=1e-12) for r in filled)
    assert default["resolution"]["ratio_to_reference"] is None
    assert (out / "resolution.png").is_file()
    assert sorted(p.name for p in out.glob("pulls_*.png")) == ["pulls_default_parametrized.png",
                                                                "pulls_tuned_parametrized.png"]


def test_reference_option_and_dataset_warning(telescope_runs, bs_run, tmp_path, capsys):
    """--reference picks the entry; runs of different datasets give one warning line with both hashes."""
    out = tmp_path / "report"
    args = ["report", f"{telescope_runs['reference']}:tele", f"{bs_run}:bs", "--out", str(out), "--reference", "bs"]
    assert main(args) == 0
    err = capsys.readouterr().err
    summary = read_summary(out)
    assert summary["reference"] == "bs/reference"
    hashes = [r["dataset_hash"] for r in summary["runs"]]
    assert len(set(hashes)) == 2 and all(hashes)
    assert err.count("pkf: warning: ") == 1 and all(h in err for h in hashes), err
    assert summary["entries"]["tele/reference"]["timing"]["speed_up_vs_reference"] is not None


def test_resolution_figure_shows_every_core_width(telescope_runs):
    """Issue 17: the δp/p core width of every p bin lies inside the plotted range (the log axis
    sized to the RMS used to hide them), and the ratio panel is bounded to the ratios."""
    import matplotlib.pyplot as plt

    from pkf.pipeline.report import load_truths
    from pkf.report.metrics import compute_report
    from pkf.report.plots import resolution_figure
    from pkf.report.runs import load_runs

    runs = load_runs([telescope_runs["parametrized"], telescope_runs["reference"]])
    data = compute_report(runs, load_truths(runs))
    fig = resolution_figure(data)
    try:
        core_ax, ratio_ax = fig.axes[0], fig.axes[3]  # δp/p column: core, ratio (3 × 3 grid, row-major)
        lo, hi = core_ax.get_ylim()
        assert core_ax.get_yscale() == "linear"
        cores = [100 * v for e in data.summary["entries"].values()
                 for v in e["resolution"]["variables"]["dp_over_p"]["bins"]["core_sigma"] if v is not None]
        assert len(cores) >= 4 and all(lo <= c <= hi for c in cores), (lo, hi, cores)
        assert hi < 1.5 * max(cores)  # sized to the cores, not to the RMS
        ratios = [v for e in data.summary["entries"].values() if e["resolution"]["ratio_to_reference"]
                  for v in e["resolution"]["ratio_to_reference"]["dp_over_p"]["core_sigma"] if v is not None]
        rlo, rhi = ratio_ax.get_ylim()
        assert ratios and all(rlo <= r <= rhi for r in ratios)
        assert rhi - rlo < 2.0 * (max(ratios + [1.0]) - min(ratios + [1.0])) + 0.05
    finally:
        plt.close(fig)


def test_pull_validity_needs_a_gaussian_core():
    """Issue 17: a double-peaked pull distribution gets a fitted 'width' but valid = False
    (the GSF's q/p on lhcb-like electrons looked like this), a Gaussian one valid = True."""
    from pkf.report.metrics import pull_summary

    rng = np.random.default_rng(7)
    gaussian = pull_summary(rng.normal(0.1, 1.05, 5000))
    assert gaussian["valid"] and gaussian["fit_converged"] and abs(gaussian["width"] - 1.05) < 0.05
    two_peaks = np.r_[rng.normal(-12, 3, 60), rng.normal(10, 4, 60)]
    bad = pull_summary(two_peaks)
    assert bad["width"] is not None and not bad["valid"], bad
    flat = pull_summary(rng.uniform(-5, 5, 3000))
    assert not flat["valid"], flat
    # small Gaussian samples stay valid in ≥ 98 % of trials (the 1 % critical value + allowance)
    ok = [pull_summary(rng.normal(0, 1, 120))["valid"] for _ in range(50)]
    assert np.mean(ok) >= 0.98
