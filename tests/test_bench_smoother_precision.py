"""`benchmarks/smoother_precision.py`'s 50-digit reference fit and its call of the Kalman core,
on telescope tracks: the weighted mean agrees with it to rounding, RTS loses digits at the
first node (the diffuse seed), and a wrong reference would show in both."""


import numpy as np
import pytest
from bench_helpers import load_benchmark, truth_sample_class


@pytest.fixture(scope="module")
def bench():
    return load_benchmark("smoother_precision")


def test_weighted_mean_matches_the_50_digit_fit_and_rts_loses_digits_at_node_0(bench):
    from pkf.fit.driver import max_nodes
    from pkf.fit.kalman import SMOOTHER_RTS, SMOOTHER_WEIGHTED_MEAN, kalman_fitter
    from pkf.geometry import load_geometry
    from pkf.params.parameter_set import shipped_parameters

    geometry = load_geometry("telescope")
    sample = truth_sample_class()(geometry, events=2, seed=3, particles=5, p_min=1000.0, p_max=50000.0, eta_min=2.0, eta_max=4.0)
    batch = sample.batch
    ext = shipped_parameters(geometry).extrapolator(geometry)
    fitter = kalman_fitter(ext, max_nodes(batch.offsets), 1)
    worst = {"weighted-mean": 0.0, "rts": 0.0}
    rts_node0 = []
    smoothers = {"rts": SMOOTHER_RTS, "weighted-mean": SMOOTHER_WEIGHTED_MEAN}
    for t in range(batch.n_tracks):
        errors = bench.smoother_errors(fitter, ext, batch, sample.seeds, sample.seed_covs, t, smoothers)
        assert errors is not None
        for name, (e_state, e_cov) in errors.items():
            worst[name] = max(worst[name], e_state.max(), e_cov.max())
        rts_node0.append(errors["rts"][1][0])
    assert batch.n_tracks >= 8
    assert worst["weighted-mean"] < 1e-7  # measured ~1e-9
    assert np.median(rts_node0) > 100 * worst["weighted-mean"]  # the seed's loose prior at node 0
