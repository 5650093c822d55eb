"""The GX2F on the VELO-only tracks of minimum bias (issue 15): Gauss–Newton's full steps
raised χ² on some of them and the fit stopped far from the minimum with status ok
(60 events ν = 7.6, seed 31: χ²/ndf mean 76.5, one track at 252,968, event 29); the
step halving of `pkf.fit.gx2f` brings the mean to 1.7 (Kalman fits: 1.0)."""

import numpy as np
import pyarrow.compute as pc
import pyarrow.dataset as ds

from pkf.cli import main


def test_gx2f_velo_only_tracks_reach_their_minimum(tmp_path):
    data, run = tmp_path / "mb", tmp_path / "run"
    assert main(["simulate", "--out", str(data), "--generator", "minbias", "--pileup", "7.6", "--events", "30",
                 "--seed", "31"]) == 0
    assert main(["reconstruct", str(data), "--out", str(run), "--fitter", "gx2f", "--workers", "1"]) == 0
    chi2 = ds.dataset(run / "chi2").to_table(
        filter=(pc.field("track_type") == "velo") & ~pc.field("is_ghost") & (pc.field("status") == "ok"))
    values = chi2["chi2_ndf"].to_numpy()
    assert values.size > 1000
    assert np.mean(values) < 3.0
    assert np.max(values) < 1000.0
