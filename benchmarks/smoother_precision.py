"""Rounding of the Kalman core's smoothers against a 50-digit evaluation of the same fit (issue 18.1).

For tracks of `benchmarks/fit_compare.py`'s samples (``--sample minbias``: long truth tracks
of 40 minimum-bias events at ν = 7.6 with their least-squares seeds; ``pigun``), one pass,
every node active: each smoother of `pkf.fit.tracks.SMOOTHER_CODES` (but forward-only)
fits the track in float64 (`pkf.fit.kalman._fit_once`), and the same linearised model —
the float64 forward filter's Jacobians F_k, noise Q_k and offsets a_k = x_p,k − F_k·x_f,k−1,
the seed and its covariance, the measurements — is filtered and smoothed (RTS) again in
50-digit decimal arithmetic (`decimal`). Errors per node: max over the 5 parameters of
|Δx_i|/σ_i and over the covariance of |ΔC_ij|/(σ_iσ_j), σ from the 50-digit smoothed
covariance; printed as median, 99 % and max over all nodes and over node 0 (the first
hit: the state the tables carry, with the beamline state made from it). The float64 inputs
are exact decimals, so only the smoothers' and the forward filter's rounding is measured.

Measured (1,000 tracks each, main 35b62d4; errors per node as median / 99 % / max):

| sample, smoother | states, all nodes | covariances, all nodes | covariances, node 0 |
|---|---|---|---|
| minimum bias, weighted mean (default) | 1.9e-11 / 1.5e-9 / 3.0e-7 | 3.5e-12 / 2.2e-10 / 9.0e-9 | 9.0e-12 / 3.0e-10 / 1.7e-9 |
| minimum bias, RTS | 5.4e-12 / 2.6e-10 / 1.0e-6 | 4.1e-10 / 7.5e-6 / 7.2e-3 | 2.1e-6 / 1.8e-3 / 7.2e-3 |
| minimum bias, Bryson–Frazier (branch bf) | 1.7e-12 / 1.8e-10 / 1.0e-6 | 6.6e-10 / 5.8e-7 / 1.6e-5 | 5.1e-9 / 1.6e-6 / 1.6e-5 |
| π gun, weighted mean | 4.0e-11 / 2.8e-9 / 7.3e-9 | 7.8e-12 / 6.6e-10 / 1.3e-9 | 6.7e-11 / 7.8e-10 / 1.1e-9 |
| π gun, RTS | 3.8e-12 / 8.5e-11 / 2.4e-9 | 4.2e-10 / 3.9e-5 / 6.4e-3 | 1.9e-5 / 2.3e-3 / 6.4e-3 |
| π gun, Bryson–Frazier (branch bf) | 1.2e-12 / 3.0e-11 / 2.4e-10 | 8.0e-11 / 5.8e-8 / 5.0e-7 | 3.5e-10 / 1.1e-7 / 5.0e-7 |

The weighted mean (the information form: no large terms cancel) is the only one whose
covariances hold 1e-8 everywhere. RTS and the modified Bryson–Frazier smoother (Bierman
1973; tried on branch ``bf``, 2e3b01b and 7c35f6f, not merged) subtract: P_f + A·(P_s −
P_p)·Aᵀ and P_f − P_f·Λ·P_f, where the forward filter's P_f still holds the seed's loose
prior (the slopes at node 0; q/p along the whole VELO, 10 % of q/p before the UT). The
Bryson–Frazier branch took node 0 in information form from node 1 (without that: 1e-4 at
node 0 on the telescope) and still lost up to 1.6e-5 of the q/p variance here, and up to
7e-3 at the first hit of 0.75 % of the long tracks of ``pkf reconstruct`` (pattern seeds,
two passes) — for a fit 5–10 % cheaper (fit_core's loop, minimum bias: 291–298 against
313–314 ns/node, of which the smoother 95 against 119; the states, 10× closer). A sample of 40 random tracks showed its worst q/p
variance at 6e-7: the bad cases are ~1 % of tracks, so judge a smoother on hundreds.

    python benchmarks/smoother_precision.py [--sample minbias] [--tracks 1000] [--json out.json]
"""

from __future__ import annotations

import argparse
import json
import sys
from decimal import Decimal, getcontext
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))

import fit_compare  # noqa: E402

getcontext().prec = 50


def decimal_array(a) -> np.ndarray:
    """float64 values as exact Decimals (object array of the same shape)."""
    a = np.asarray(a, dtype=float)
    return np.array([Decimal(float(v)) for v in a.ravel()], dtype=object).reshape(a.shape)


def decimal_inverse(a: np.ndarray) -> np.ndarray:
    """Inverse of a square Decimal matrix by Gauss–Jordan elimination with partial pivoting."""
    n = a.shape[0]
    work = np.concatenate([a.copy(), decimal_array(np.eye(n))], axis=1)
    for c in range(n):
        pivot = max(range(c, n), key=lambda r: abs(work[r, c]))
        work[[c, pivot]] = work[[pivot, c]]
        work[c] = work[c] / work[c, c]
        for r in range(n):
            if r != c:
                work[r] = work[r] - work[r, c] * work[c]
    return work[:, n:]


def exact_fit(jac, noise, pred, filt, meas, seed, seed_cov):
    """Forward filter and RTS smoother in 50 digits on the linear model x_k = a_k + F_k·x_k−1
    + w_k (a_k from the float64 forward filter: pred, filt); meas per node: (h_x, h_y, m, σ)
    tuples. Returns the smoothed states (n, 5) and covariances (n, 5, 5) as float64."""
    n = len(meas)
    f = [decimal_array(jac[k]) for k in range(n)]
    x, p = decimal_array(seed), decimal_array(seed_cov)
    xp, pp, xf, pf = [], [], [], []
    for k in range(n):
        if k:
            a_k = decimal_array(pred[k]) - f[k] @ decimal_array(filt[k - 1])
            x = a_k + f[k] @ x
            p = f[k] @ p @ f[k].T + decimal_array(noise[k])
        xp.append(x)
        pp.append(p)
        for hx, hy, m, sigma in meas[k]:
            h = decimal_array([hx, hy, 0.0, 0.0, 0.0])
            ph = p @ h
            s = decimal_array(sigma)[()] ** 2 + h @ ph
            gain = ph / s
            x = x + gain * (decimal_array(m)[()] - h @ x)
            p = p - np.outer(gain, ph)
        xf.append(x)
        pf.append(p)
    xs, ps = [None] * n, [None] * n
    xs[-1], ps[-1] = xf[-1], pf[-1]
    for k in range(n - 2, -1, -1):
        a = pf[k] @ f[k + 1].T @ decimal_inverse(pp[k + 1])
        xs[k] = xf[k] + a @ (xs[k + 1] - xp[k + 1])
        ps[k] = pf[k] + a @ (ps[k + 1] - pp[k + 1]) @ a.T
    return np.array(xs, dtype=float), np.array(ps, dtype=float)


def fit_track(fitter, ext, batch, seeds, covs, t, smoother):
    """One pass of the Kalman core on track t with `smoother`: (status, states, covariances);
    the fitter's scratch keeps the forward filter's jac, noise, pred, filt."""
    from pkf.fit.kalman import _fit_once

    lo, hi = batch.offsets[t], batch.offsets[t + 1]
    n = hi - lo
    state, cov = np.zeros((n, 5)), np.zeros((n, 5, 5))
    f = fitter
    status, _ = _fit_once(
        ext, batch.z[lo:hi], batch.n_meas[lo:hi], batch.hx[lo:hi], batch.hy[lo:hi], batch.m[lo:hi],
        batch.sigma[lo:hi], np.ones(n, dtype=np.bool_), seeds[t], covs[t], False, f.ref, f.pred, f.pred_cov,
        f.filt, f.filt_cov, f.jac, f.noise, smoother, state, cov, f.mats, f.vec5, f.perm, f.info, f.info_vec,
        f.pred_lanes, f.pred_cov_lanes, True,
    )  # fmt: skip
    return status, state, cov


def smoother_errors(fitter, ext, batch, seeds, covs, t, smoothers: dict) -> dict | None:
    """Track t fitted by each of `smoothers` (name → code) and by `exact_fit` on the same
    linearised model: name → (state error, covariance error) per node, max over the
    parameters of |Δx_i|/σ_i and over the covariance of |ΔC_ij|/(σ_iσ_j), σ from the
    50-digit smoothed covariance. None if a fit failed."""
    fits = {name: fit_track(fitter, ext, batch, seeds, covs, t, code) for name, code in smoothers.items()}
    if any(status != 0 for status, _, _ in fits.values()):
        return None
    lo, hi = batch.offsets[t], batch.offsets[t + 1]
    meas = [
        [(batch.hx[k, j], batch.hy[k, j], batch.m[k, j], batch.sigma[k, j]) for j in range(batch.n_meas[k])]
        for k in range(lo, hi)
    ]
    # the fitter's scratch holds the forward filter of the last fit: the same for every smoother
    x_ref, c_ref = exact_fit(fitter.jac, fitter.noise, fitter.pred, fitter.filt, meas, seeds[t], covs[t])
    sigma = np.sqrt(np.einsum("nii->ni", c_ref))
    return {
        name: (
            np.max(np.abs(state - x_ref) / sigma, axis=1),
            np.max(np.abs(cov - c_ref) / (sigma[:, :, None] * sigma[:, None, :]), axis=(1, 2)),
        )
        for name, (_, state, cov) in fits.items()
    }


def summary(errors: list[np.ndarray]) -> dict:
    values = np.concatenate(errors) if errors else np.zeros(1)
    return {"median": float(np.median(values)), "q99": float(np.quantile(values, 0.99)), "max": float(values.max())}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sample", choices=tuple(fit_compare.SAMPLES), default="minbias")
    parser.add_argument("--tracks", type=int, default=1000, help="tracks drawn at random (seed 1)")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()

    from pkf.fit.driver import max_nodes
    from pkf.fit.kalman import kalman_fitter
    from pkf.fit.tracks import SMOOTHER_CODES
    from pkf.geometry import load_geometry

    batch, data = fit_compare.load_sample(args.sample)
    seeds, covs = data["seeds"], data["seed_covs"]
    ext, _ = fit_compare._fit_function("parametrized", load_geometry("lhcb-like"))
    smoothers = {name: code for name, code in SMOOTHER_CODES.items() if name != "forward-only"}
    fitter = kalman_fitter(ext, max_nodes(batch.offsets), 1)
    tracks = np.random.default_rng(1).choice(batch.n_tracks, min(args.tracks, batch.n_tracks), replace=False)
    errors = {name: {"state": [], "cov": [], "state_node0": [], "cov_node0": []} for name in smoothers}
    for t in tracks:
        track_errors = smoother_errors(fitter, ext, batch, seeds, covs, t, smoothers)
        if track_errors is None:
            continue
        for name, (e_state, e_cov) in track_errors.items():
            for key, value in (
                ("state", e_state),
                ("cov", e_cov),
                ("state_node0", e_state[:1]),
                ("cov_node0", e_cov[:1]),
            ):
                errors[name][key].append(value)
    result = {"sample": args.sample, "tracks": int(len(errors[next(iter(errors))]["state_node0"])), "smoothers": {}}
    print(f"{args.sample}: {result['tracks']} tracks, one pass; error per node against 50 digits (median / 99 % / max)")
    for name, errs in errors.items():
        result["smoothers"][name] = {key: summary(value) for key, value in errs.items()}
        row = result["smoothers"][name]
        cells = [f"{key} {row[key]['median']:.1e} / {row[key]['q99']:.1e} / {row[key]['max']:.1e}" for key in row]
        print(f"  {name:15s} " + "; ".join(cells))
    if args.json:
        args.json.write_text(json.dumps(result, indent=1))


if __name__ == "__main__":
    main()
