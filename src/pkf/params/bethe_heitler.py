"""pkf's Gaussian-mixture approximation of the Bethe–Heitler bremsstrahlung distribution (docs/physics.md#the-gaussian-sum-filter-gsf-and-the-bethe-heitler-mixture).

Bethe–Heitler: the fraction z = E_f/E_i of an electron's energy kept after a path of
t radiation lengths has −ln z ~ Gamma(c, 1), c = t/ln 2, i.e. the density
f(z) = (−ln z)^(c−1)/Γ(c) on (0, 1) and the CDF F(z) = Q(c, −ln z) (upper regularised
incomplete gamma function). The Gaussian-sum filter (`pkf.fit.gsf`) needs f as a
mixture Σ_k w_k·N(z; μ_k, σ_k²) at every material plane, for any t.

Parametrisation (the shipped mixture, package data ``data/bethe_heitler.json``): K
components whose transformed parameters are polynomials of degree D in
s = 2·(ln t − ln t_min)/(ln t_max − ln t_min) − 1 ∈ [−1, 1]:

- weights: w = softmax(a(s)) (a_k: the "weight_logit" polynomials),
- means:   μ_k = 1 − d_k, ln d_k = b_k(s) ("log_distance": the distance of the
  component from "no loss" on a log scale, so components can sit anywhere from 1e−5 to
  0.9 below z = 1 and never above it),
- widths:  σ_k = d_k·exp(g_k(s)) ("log_relative_width").

Evaluation (`bethe_heitler_components`, compiled) follows the ACTS shortcuts
(docs/physics.md): t < 1e−4 no loss; t < t_min = 0.002 a single Gaussian with the exact mean 2^(−c)
and variance 3^(−c) − 4^(−c); t > t_max = 0.2 is clipped to t_max.

How good it is: the CDF of the mixture is compared with the true CDF on the z grid
0, 0.001, …, 1 (`Z_GRID`, the resolution that matters: 1e−3 in energy fraction is
four times finer than the momentum resolution). The maximum difference over t in
[t_min, t_max] is stored in the file's metadata and tested (< 0.01). A finer grid
near z = 1 cannot be met by any finite mixture when c ≪ 1: P(−ln z < ε) ≈ ε^c, so at
t = 0.002 the true CDF still rises by 0.07 between z = 1 − 1e−4 and 1 − 1e−14 — the
electrons that lose (almost) nothing — which a mixture of finitely many Gaussians
places in one narrow "no loss" component. With 6 components the best per-t fit
reaches a maximum CDF difference of 0.012–0.016 at t ≈ 0.1–0.2 (measured while
building this), hence 8 components, which give ≈ 0.006.

Regenerating the package data (a few minutes, single core)::

    python -m pkf.params.bethe_heitler --out src/pkf/params/data/bethe_heitler.json

or from Python: ``fit_bethe_heitler_mixture(out="…/bethe_heitler.json")``. The fit: per-t
fits on a log grid of t with continuation from t_max downwards (smoothed L_p norms of
the CDF difference, p = 4 → 64, i.e. towards the maximum, L-BFGS with analytic
gradients), a polynomial fit of the transformed parameters in s, and a joint
refinement of all polynomial coefficients on the same objective summed over the t grid.
"""

from __future__ import annotations

import argparse
import json
import math
from dataclasses import dataclass, field
from importlib import resources
from pathlib import Path

import numba as nb
import numpy as np

from pkf.jit import NO_REFCOUNT

FORMAT = "pkf-bethe-heitler/1"
LN2 = math.log(2.0)
#: Below this path length [X0]: no bremsstrahlung loss at all (ACTS).
NO_LOSS_BELOW = 1e-4
#: Range of t [X0] the mixture is fitted in; below t_min a single Gaussian, above clipped.
T_MIN = 0.002
T_MAX = 0.2
#: The z grid on which CDFs are compared (fit and test).
Z_GRID = np.linspace(0.0, 1.0, 1001)
_SQRT_2PI = math.sqrt(2.0 * math.pi)


@dataclass(frozen=True)
class BetheHeitlerMixture:
    """Polynomial coefficients of the mixture: coefficients (3, K, D+1) for (weight
    logit, log distance, log relative width), lowest order first; t range [X0]."""

    coefficients: np.ndarray
    t_min: float = T_MIN
    t_max: float = T_MAX
    metadata: dict = field(default_factory=dict)

    @property
    def n_components(self) -> int:
        return int(self.coefficients.shape[1])

    def components(self, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(weights, means, variances) of the mixture in z at path length t [X0]
        (with the shortcuts below t_min: an empty mixture means no loss)."""
        k = self.n_components
        w = np.empty(k)
        mu = np.empty(k)
        var = np.empty(k)
        n = bethe_heitler_components(self.coefficients, self.t_min, self.t_max, float(t), w, mu, var)
        return w[:n].copy(), mu[:n].copy(), var[:n].copy()

    def cdf(self, z, t: float) -> np.ndarray:
        """CDF of the mixture at z (array) for path length t [X0]."""
        from scipy.special import ndtr

        w, mu, var = self.components(t)
        z = np.asarray(z, dtype=float)
        if w.size == 0:
            return np.where(z >= 1.0, 1.0, 0.0)
        sig = np.sqrt(np.maximum(var, 1e-300))
        return (w * ndtr((z[..., None] - mu) / sig)).sum(-1)

    def to_json_dict(self) -> dict:
        c = self.coefficients
        return {
            "format": FORMAT,
            "n_components": self.n_components,
            "degree": int(c.shape[2] - 1),
            "t_min": self.t_min,
            "t_max": self.t_max,
            "no_loss_below": NO_LOSS_BELOW,
            "variable": "s = 2*(ln t - ln t_min)/(ln t_max - ln t_min) - 1, coefficients lowest order first",
            "weight_logit": c[0].tolist(),
            "log_distance": c[1].tolist(),
            "log_relative_width": c[2].tolist(),
            "metadata": self.metadata,
        }

    @classmethod
    def from_json_dict(cls, data: dict, source: str = "bethe_heitler.json") -> BetheHeitlerMixture:
        if data.get("format") != FORMAT:
            raise ValueError(f"{source}: not a {FORMAT} file")
        coefficients = np.array([data["weight_logit"], data["log_distance"], data["log_relative_width"]],
                                dtype=np.float64)
        if coefficients.ndim != 3 or not np.all(np.isfinite(coefficients)):
            raise ValueError(f"{source}: malformed coefficient arrays")
        return cls(np.ascontiguousarray(coefficients), float(data["t_min"]), float(data["t_max"]),
                   data.get("metadata", {}))


def load_bethe_heitler_mixture(path: str | Path | None = None) -> BetheHeitlerMixture:
    """The mixture in `path`, or the one shipped with pkf (package data)."""
    if path is None:
        text = resources.files("pkf.params").joinpath("data", "bethe_heitler.json").read_text()
        source = "shipped bethe_heitler.json"
    else:
        text = Path(path).read_text()
        source = str(path)
    return BetheHeitlerMixture.from_json_dict(json.loads(text), source=source)


# ----------------------------------------------------------------------------------
# Compiled evaluation (used inside the GSF)
# ----------------------------------------------------------------------------------


@nb.njit(cache=True, **NO_REFCOUNT)
def bethe_heitler_components(coefficients, t_min, t_max, t, out_weight, out_mean, out_var):
    """Mixture of z = E_f/E_i after t radiation lengths: writes weights, means and
    variances into the output arrays (length ≥ K) and returns the number of components
    (0: no loss, t < 1e−4; 1: the single-Gaussian shortcut, t < t_min)."""
    return bethe_heitler_components_logs(coefficients, t_min, t_max, math.log(t_min), math.log(t_max), t,
                                         out_weight, out_mean, out_var)


@nb.njit(cache=True, **NO_REFCOUNT)
def bethe_heitler_components_logs(coefficients, t_min, t_max, log_t_min, log_t_max, t, out_weight, out_mean,
                                  out_var):
    """`bethe_heitler_components` with ln t_min and ln t_max given (a caller evaluating many
    t, as the GSF at a plane for every component, takes them once; bitwise the same)."""
    if not t >= NO_LOSS_BELOW:
        return 0
    if t < t_min:
        c = t / LN2
        out_weight[0] = 1.0
        out_mean[0] = 2.0 ** (-c)
        out_var[0] = max(3.0 ** (-c) - 4.0 ** (-c), 0.0)
        return 1
    tc = min(t, t_max)
    s = 2.0 * (math.log(tc) - log_t_min) / (log_t_max - log_t_min) - 1.0
    k_max = coefficients.shape[1]
    degree = coefficients.shape[2] - 1
    largest = -1e300
    for k in range(k_max):
        a = coefficients[0, k, degree]
        b = coefficients[1, k, degree]
        g = coefficients[2, k, degree]
        for j in range(degree - 1, -1, -1):
            a = a * s + coefficients[0, k, j]
            b = b * s + coefficients[1, k, j]
            g = g * s + coefficients[2, k, j]
        out_weight[k] = a
        largest = max(largest, a)
        d = math.exp(b)
        out_mean[k] = 1.0 - d
        sig = d * math.exp(g)
        out_var[k] = sig * sig
    total = 0.0
    for k in range(k_max):
        out_weight[k] = math.exp(out_weight[k] - largest)
        total += out_weight[k]
    for k in range(k_max):
        out_weight[k] /= total
    return k_max


# ----------------------------------------------------------------------------------
# The true distribution and the fit (offline; numpy/scipy)
# ----------------------------------------------------------------------------------


def bethe_heitler_cdf(z, t: float) -> np.ndarray:
    """True Bethe–Heitler CDF P(E_f/E_i ≤ z) after t radiation lengths (z array in [0, 1])."""
    from scipy.special import gammaincc

    z = np.asarray(z, dtype=float)
    u = -np.log(np.clip(z, 1e-300, 1.0))
    return np.where(z >= 1.0, 1.0, gammaincc(t / LN2, u))


def max_cdf_difference(mixture: BetheHeitlerMixture, t_values, z=Z_GRID) -> np.ndarray:
    """max_z |F_mixture(z) − F_BH(z)| for each t in t_values (on the grid z)."""
    return np.array([np.abs(mixture.cdf(z, t) - bethe_heitler_cdf(z, t)).max() for t in t_values])


def _scaled_log_t(t, t_min, t_max):
    return 2.0 * (np.log(t) - np.log(t_min)) / (np.log(t_max) - np.log(t_min)) - 1.0


def _mixture_terms(a, b, g, z):
    """Weights, CDF columns and the pieces of their derivatives for logits a, log
    distances b and log relative widths g (arrays (..., K)) on the grid z."""
    from scipy.special import ndtr

    e = np.exp(a - a.max(-1, keepdims=True))
    w = e / e.sum(-1, keepdims=True)
    d = np.exp(b)
    mu = 1.0 - d
    sig = d * np.exp(g)
    x = (z[:, None] - mu[..., None, :]) / sig[..., None, :]
    return w, d, sig, x, ndtr(x), np.exp(-0.5 * x * x) / _SQRT_2PI


def _lp_objective(a, b, g, target, p, mean_target, mean_weight):
    """‖G − F‖_p over the grid (per t) plus mean_weight·(E_mix[z] − E[z])², with
    gradients with respect to a, b, g. Shapes: a, b, g (T, K); target (T, Z)."""
    w, d, sig, x, cdf, pdf = _mixture_terms(a, b, g, Z_GRID)
    r = np.einsum("tzk,tk->tz", cdf, w) - target
    ar = np.abs(r) + 1e-300
    total = np.sum(ar**p, axis=1)
    value = total ** (1.0 / p)
    dr = (total ** (1.0 / p - 1.0))[:, None] * ar ** (p - 1) * np.sign(r)  # ∂value/∂r
    gw = np.einsum("tz,tzk->tk", dr, cdf)
    dmu = -np.einsum("tz,tzk->tk", dr, pdf / sig[:, None, :]) * w
    dsig = -np.einsum("tz,tzk->tk", dr, pdf * x / sig[:, None, :]) * w
    # mean of the mixture and its penalty
    mean = np.sum(w * (1.0 - d), axis=1)
    dm = 2.0 * mean_weight * (mean - mean_target)
    value = value + mean_weight * (mean - mean_target) ** 2
    gw = gw + dm[:, None] * (1.0 - d)
    ga = w * (gw - np.sum(gw * w, axis=1, keepdims=True))
    gb = -d * dmu + sig * dsig - dm[:, None] * w * d
    gg = sig * dsig
    return value, ga, gb, gg


def _fit_single(t, start, k, powers=(4, 8, 16, 32, 64), mean_weight=10.0):
    """Minimise the L_p CDF distance at one t from start (3K vector a, b, g)."""
    from scipy.optimize import minimize

    target = bethe_heitler_cdf(Z_GRID, t)[None]
    mean_target = np.array([2.0 ** (-t / LN2)])
    q = start.copy()
    for p in powers:
        def fun(v, p=p):
            val, ga, gb, gg = _lp_objective(v[:k][None], v[k:2 * k][None], v[2 * k:][None], target, p,
                                            mean_target, mean_weight)
            return float(val[0]), np.concatenate([ga[0], gb[0], gg[0]])

        q = minimize(fun, q, jac=True, method="L-BFGS-B", options={"maxiter": 5000, "maxcor": 30}).x
    return q


def _initial_components(k):
    """Components log-spaced in distance from z = 1 (3e−5 … 0.5), equal weights, σ = 0.4·d."""
    return np.concatenate([np.zeros(k), np.log(np.geomspace(3e-5, 0.5, k)), np.full(k, math.log(0.4))])


def _mixture_from_polynomials(coefficients, t_min, t_max, metadata=None):
    return BetheHeitlerMixture(np.ascontiguousarray(coefficients), t_min, t_max, metadata or {})


def fit_bethe_heitler_mixture(n_components: int = 8, t_min: float = T_MIN, t_max: float = T_MAX,
                              degree: int = 5, n_t: int = 25, out: str | Path | None = None,
                              restarts: int = 4, seed: int = 1, verbose: bool = False) -> BetheHeitlerMixture:
    """Fit pkf's Gaussian-mixture approximation of the Bethe–Heitler distribution.

    n_components K, polynomial degree in s = scaled ln t, n_t fit points of t log-spaced
    in [t_min, t_max]. Writes the JSON package-data file to `out` if given (see the
    module docstring for the command line). Returns the mixture; its metadata hold the
    maximum CDF difference on a dense t grid.
    """
    from scipy.optimize import minimize

    import pkf
    from pkf.io.atomic import atomic_write_json

    k = n_components
    rng = np.random.default_rng(seed)
    t_fit = np.geomspace(t_max, t_min, n_t)
    # 1. per-t fits with continuation from t_max down
    best = None
    for trial in range(restarts):
        start = _initial_components(k) + (rng.normal(0.0, 0.3, 3 * k) if trial else 0.0)
        q = _fit_single(t_fit[0], start, k)
        err = np.abs(_cdf_of(q, k, t_fit[0]) - bethe_heitler_cdf(Z_GRID, t_fit[0])).max()
        if best is None or err < best[0]:
            best = (err, q)
    params = [best[1]]
    for t in t_fit[1:]:
        params.append(_fit_single(t, params[-1], k))
    params = np.array(params)  # (T, 3K)
    if verbose:
        for t, q in zip(t_fit, params):
            print(f"t={t:.4f} per-t max |ΔF| = {np.abs(_cdf_of(q, k, t) - bethe_heitler_cdf(Z_GRID, t)).max():.4f}")
    # 2. polynomials in s of the transformed parameters (weight logits centred: softmax gauge)
    s = _scaled_log_t(t_fit, t_min, t_max)
    vander = np.vander(s, degree + 1, increasing=True)  # (T, D+1)
    a = params[:, :k] - params[:, :k].mean(axis=1, keepdims=True)
    blocks = [a, params[:, k:2 * k], params[:, 2 * k:]]
    coefficients = np.stack([np.linalg.lstsq(vander, blk, rcond=None)[0].T for blk in blocks])  # (3, K, D+1)
    # 3. joint refinement of every coefficient on the summed L_p objective
    targets = np.array([bethe_heitler_cdf(Z_GRID, t) for t in t_fit])
    mean_targets = 2.0 ** (-t_fit / LN2)
    shape = coefficients.shape
    for p in (16, 32, 64):
        def fun(v, p=p):
            c = v.reshape(shape)
            a_, b_, g_ = (vander @ c[i].T for i in range(3))
            val, ga, gb, gg = _lp_objective(a_, b_, g_, targets, p, mean_targets, 10.0)
            grad = np.stack([(vander.T @ gx).T for gx in (ga, gb, gg)])
            return float(val.sum()), grad.ravel()

        coefficients = minimize(fun, coefficients.ravel(), jac=True, method="L-BFGS-B",
                                options={"maxiter": 3000, "maxcor": 30}).x.reshape(shape)
    mixture = _mixture_from_polynomials(coefficients, t_min, t_max)
    t_check = np.geomspace(t_min, t_max, 200)
    diff = max_cdf_difference(mixture, t_check)
    mean_err = np.array([np.sum(w * m) - 2.0 ** (-t / LN2) for t in t_check
                         for w, m, _ in [mixture.components(t)]])
    metadata = {
        "max_cdf_difference": float(diff.max()),
        "t_of_max_cdf_difference": float(t_check[int(np.argmax(diff))]),
        "max_abs_mean_error": float(np.abs(mean_err).max()),
        "z_grid": "0, 0.001, ..., 1",
        "t_check": "200 values log-spaced in [t_min, t_max]",
        "fit": {"n_t": n_t, "restarts": restarts, "seed": seed, "objective": "L_p norm of the CDF difference, p -> 64, plus 10*(mean error)^2"},
        "pkf_version": pkf.__version__,
    }
    mixture = _mixture_from_polynomials(coefficients, t_min, t_max, metadata)
    if verbose:
        print(f"max CDF difference {diff.max():.4f} at t = {metadata['t_of_max_cdf_difference']:.4f}; "
              f"max |mean error| {metadata['max_abs_mean_error']:.2e}")
    if out is not None:
        atomic_write_json(mixture.to_json_dict(), out)
    return mixture


def _cdf_of(q, k, t):
    w, _, _, _, cdf, _ = _mixture_terms(q[:k][None], q[k:2 * k][None], q[2 * k:][None], Z_GRID)
    return np.einsum("tzk,tk->tz", cdf, w)[0]


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description="Fit pkf's Bethe–Heitler Gaussian mixture (package data).")
    parser.add_argument("--out", required=True, help="JSON file to write")
    parser.add_argument("--components", type=int, default=8)
    parser.add_argument("--degree", type=int, default=5)
    args = parser.parse_args(argv)
    fit_bethe_heitler_mixture(args.components, degree=args.degree, out=args.out, verbose=True)


if __name__ == "__main__":
    main()
