"""Every track type fitted by every fitter on minimum bias through the triplet pattern (issue 15).

A small sample (3 events at ν = 7.6, ~700 candidates, ~150 of them VELO-only);
`benchmarks/fit_quality.py` measures the same on 60 events. Before issue 15 the chi2 table
had no ``track_type``, the parametrized fitter refused 9 % of the real long tracks (p below its
table's p_min), and the reference fitter failed 38 % and the GX2F 66 % of the real VELO-only tracks ("extrapolation failed": seeds with the least-squares q/p of a VELO track,
±1/(100 MeV) of noise, stopped in the material).
"""

import numpy as np
import pytest

from pkf.cli import main
from pkf.io.reader import read_table
from pkf.io.schemas import CHI2, PULLS, STATES

FITTERS = ("parametrized", "reference", "gx2f", "gsf")


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    base = tmp_path_factory.mktemp("types")
    data = base / "minbias"
    assert main(["simulate", "--out", str(data), "--events", "3", "--pileup", "7.6", "--seed", "31"]) == 0
    out = base / "run"
    args = ["reconstruct", str(data), "--out", str(out), "--workers", "1"]
    for fitter in FITTERS:
        args += ["--fitter", fitter]
    assert main(args) == 0
    return out


def _columns(table):
    return {c: table.column(c).to_numpy(zero_copy_only=False) for c in table.column_names}


def test_track_type_column_follows_the_candidate_hits(run):
    table = read_table(run, CHI2, name="chi2")
    assert table.column_names[:4] == ["event_id", "track_id", "fitter", "track_type"]
    chi2 = _columns(table)
    types = chi2["track_type"]
    assert set(types) <= {"long", "upstream", "velo"}
    assert {"long", "velo"} <= set(types)
    # a track keeps its type for every fitter, and the type follows its hits
    long_by_hits = chi2["n_scifi"] > 0
    assert np.all(types[long_by_hits] == "long")
    velo_by_hits = (chi2["n_scifi"] == 0) & (chi2["n_ut"] == 0) & (chi2["n_outliers"] == 0)
    assert np.all(types[velo_by_hits] == "velo")


def test_every_fitter_fits_real_tracks_of_every_type(run):
    chi2 = _columns(read_table(run, CHI2, name="chi2"))
    real = ~chi2["is_ghost"]
    for fitter in FITTERS:
        for track_type in ("long", "upstream", "velo"):  # real ones on this sample: 449, 49, 59
            sel = real & (chi2["fitter"] == fitter) & (chi2["track_type"] == track_type)
            assert sel.sum() > 40, (fitter, track_type, sel.sum())
            ok = chi2["status"][sel] == "ok"
            assert ok.mean() >= 0.995, (fitter, track_type, ok.mean(), set(chi2["status"][sel][~ok]))


def test_velo_only_qop_is_the_scattering_momentum_with_honest_chi2(run):
    """VELO-only tracks: |q/p| is the momentum the seed measured from the tracks' own multiple
    scattering (`pkf.fit.seed.velo_momentum_estimate`), which follows the true momentum, with
    about the prior's error, for every fitter; the χ²/ndf of real tracks has mean 1 ± 0.1.
    With the fixed assumption pT = 200 MeV (before) ln p_fit and ln p_true correlated by 0.71
    (2,197 real VELO-only tracks of 60 events) and χ²/ndf had mean 1.19–1.20 (Kalman fitters),
    2.1 (GX2F) and 3.2 (GSF): 1.6 below 1.5 GeV, 0.45–0.65 at 1.5–10 GeV."""
    chi2 = _columns(read_table(run, CHI2, name="chi2"))
    states = _columns(read_table(run, STATES, name="states"))
    pulls = _columns(read_table(run, PULLS, name="pulls"))
    key = lambda e, t: e * (1 << 32) + t  # noqa: E731
    for fitter in FITTERS:
        sel = ((chi2["fitter"] == fitter) & (chi2["track_type"] == "velo") & (chi2["status"] == "ok")
               & ~chi2["is_ghost"])
        assert sel.sum() > 40, (fitter, sel.sum())
        mean = np.mean(chi2["chi2_ndf"][sel])
        assert 0.88 < mean < 1.1, (fitter, mean)
        velo_keys = key(chi2["event_id"][sel], chi2["track_id"][sel])
        rows = ((pulls["fitter"] == fitter) & (pulls["location"] == "first_hit")
                & np.isin(key(pulls["event_id"], pulls["track_id"]), velo_keys))
        srows = ((states["fitter"] == fitter) & (states["location"] == "first_hit")
                 & np.isin(key(states["event_id"], states["track_id"]), velo_keys))
        order = np.argsort(key(states["event_id"][srows], states["track_id"][srows]))
        pos = np.searchsorted(key(states["event_id"][srows], states["track_id"][srows])[order],
                              key(pulls["event_id"][rows], pulls["track_id"][rows]))
        qop = states["qop"][srows][order][pos]
        sigma = np.sqrt(states["c44"][srows][order][pos])
        p_fit = 1.0 / np.abs(qop)
        p_true = pulls["p_true"][rows]
        assert np.corrcoef(np.log(p_fit), np.log(p_true))[0, 1] > 0.6, fitter
        assert 0.6 < np.median(p_fit / p_true) < 1.4, fitter
        if fitter != "gsf":  # the GSF writes its mode component's covariance (issue 15, deliverable 4)
            # σ(q/p)² = σ(1/p)² + 2/p² (the VELO does not measure the sign, `velo_momentum_prior`)
            assert 1.3 < np.median(sigma * p_fit) < 2.0, (fitter, np.median(sigma * p_fit))


def test_upstream_tracks_of_the_triplet_pattern_have_honest_chi2(run):
    """Real upstream (VELO + UT) tracks of the triplet pattern: χ²/ndf mean 1.00 ± 0.15 for
    every fitter. Before their UT search ran after the long tracks took their UT hits
    (`pkf.seeding.forward.upstream`), 7 % of them held the four UT hits of another particle's
    long track, with χ²/ndf ≈ 11: on 60 events at ν = 7.6 the mean was 1.53 (reference) and
    1.36 (parametrized), now 1.02 and 0.98."""
    chi2 = _columns(read_table(run, CHI2, name="chi2"))
    for fitter in FITTERS:
        sel = ((chi2["fitter"] == fitter) & (chi2["track_type"] == "upstream") & ~chi2["is_ghost"]
               & (chi2["status"] == "ok"))
        assert sel.sum() > 40, (fitter, sel.sum())
        assert 0.85 < np.mean(chi2["chi2_ndf"][sel]) < 1.15, (fitter, np.mean(chi2["chi2_ndf"][sel]))


@pytest.fixture(scope="module")
def truth_run(tmp_path_factory):
    """Ideal pattern recognition: the upstream (VELO + UT) tracks the triplet pattern does not
    make (yet) are there."""
    base = tmp_path_factory.mktemp("types_truth")
    data = base / "minbias"
    assert main(["simulate", "--out", str(data), "--events", "5", "--pileup", "7.6", "--seed", "31"]) == 0
    out = base / "run"
    assert main(["reconstruct", str(data), "--out", str(out), "--workers", "1", "--pattern", "truth",
                 "--fitter", "parametrized", "--fitter", "reference"]) == 0
    return out


def test_upstream_qop_error_is_the_hits_not_a_narrow_prior(truth_run):
    """Upstream tracks measure q/p to ~15 % from the field before the UT; with a 10 % seed prior
    centred on the hits' own estimate their q/p pull core was 2.0 (both Kalman fitters)."""
    from pkf.io.schemas import PULLS
    from pkf.params.gauss import gaussian_core

    chi2 = _columns(read_table(truth_run, CHI2, name="chi2"))
    pulls = _columns(read_table(truth_run, PULLS, name="pulls"))
    key = lambda e, t: e * (1 << 32) + t  # noqa: E731
    for fitter in ("parametrized", "reference"):
        sel = (chi2["fitter"] == fitter) & (chi2["track_type"] == "upstream") & (chi2["status"] == "ok")
        assert sel.sum() > 100
        rows = ((pulls["fitter"] == fitter) & (pulls["location"] == "first_hit")
                & np.isin(key(pulls["event_id"], pulls["track_id"]), key(chi2["event_id"][sel], chi2["track_id"][sel])))
        width = gaussian_core(pulls["pull_qop"][rows]).sigma
        assert 0.8 < width < 1.25, (fitter, width)
        assert 0.85 < np.mean(chi2["chi2_ndf"][sel]) < 1.2, fitter


def test_every_written_state_is_finite_with_a_positive_definite_covariance(run):
    """Issue 15: no NaN/inf in any written state or covariance, every covariance positive
    definite, for every fitter, location and track type (`benchmarks/covariance_health.py`
    checks the same on a run of any size). Judged on the correlation matrix: positions [mm]
    and q/p [1/MeV] differ by ~10⁸ in scale."""
    from pkf.io.schemas import STATE_COLUMNS, unpack_covariance

    table = read_table(run, STATES, name="states")
    state = np.column_stack([table.column(c).to_numpy() for c in STATE_COLUMNS])
    cov = unpack_covariance(table)
    assert np.isfinite(state).all() and np.isfinite(cov).all()
    diag = np.diagonal(cov, axis1=1, axis2=2)
    assert (diag > 0).all()
    scale = 1.0 / np.sqrt(diag)
    corr = cov * scale[:, :, None] * scale[:, None, :]
    np.linalg.cholesky(corr)  # raises LinAlgError on any matrix that is not positive definite
    assert set(table.column("fitter").to_pylist()) == set(FITTERS)
    assert table.num_rows > 2000
