"""B_s⁰ → φφ invariant mass: four-kaon masses from fitted states, and the Gaussian + linear peak fit (paper Fig. 4).

Fit model (docs/physics.md#matching-and-metrics, as in the paper): a Gaussian signal and a first-order
polynomial background in a mass window [lo, hi] (MeV), both normalised to the
window, fitted by an *extended unbinned* maximum likelihood with iminuit
(:class:`iminuit.cost.ExtendedUnbinnedNLL`): no binning choice enters the result,
and the signal and background yields come with errors. The background density is
``(1 + slope·(m − m_c)/h) / (hi − lo)`` with ``m_c``, ``h`` the window centre and
half-width and ``slope ∈ [−1, 1]`` (non-negative over the window).
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from iminuit import Minuit
from iminuit.cost import ExtendedUnbinnedNLL
from scipy.stats import norm

from pkf.physics.constants import MASS_BS, MASS_KAON

__all__ = [
    "KAON_MASS",
    "BS_MASS",
    "MassFit",
    "fit_mass_peak",
    "four_momenta",
    "invariant_mass",
    "MIN_CANDIDATES",
]

#: PDG masses [MeV] (`pkf.physics.constants`).
KAON_MASS = MASS_KAON
BS_MASS = MASS_BS
#: Fewer candidates in the window than this: no fit (the numbers would mean nothing).
MIN_CANDIDATES = 10


def four_momenta(qop, tx, ty, mass: float = KAON_MASS) -> np.ndarray:
    """(E, px, py, pz) [MeV] of tracks with state (tx, ty, qop): p = 1/|qop|, direction ∝ (tx, ty, 1).

    Shape (n, 4); the tracks fly forward (pz > 0), as every LHCb-like track does.
    """
    qop, tx, ty = (np.asarray(a, dtype=float) for a in (qop, tx, ty))
    p = 1.0 / np.abs(qop)
    pz = p / np.sqrt(1.0 + tx**2 + ty**2)
    px, py = tx * pz, ty * pz
    energy = np.sqrt(p**2 + mass**2)
    return np.stack([energy, px, py, pz], axis=-1)


def invariant_mass(momenta: np.ndarray) -> np.ndarray:
    """Invariant mass [MeV] of the sum over axis −2 of four-momenta of shape (..., k, 4)."""
    total = np.asarray(momenta, dtype=float).sum(axis=-2)
    m2 = total[..., 0] ** 2 - np.sum(total[..., 1:] ** 2, axis=-1)
    return np.sqrt(np.maximum(m2, 0.0))


@dataclass(frozen=True)
class MassFit:
    """Result of :func:`fit_mass_peak`. Masses and widths in MeV; yields are counts.

    ``status`` is ``"ok"`` for a valid minimum with an accurate covariance, otherwise
    why not (``"too few candidates (…)"``, ``"fit not valid"``, ``"covariance not accurate"``);
    numbers are NaN when no fit was made.
    """

    mean: float
    mean_error: float
    sigma: float
    sigma_error: float
    n_signal: float
    n_signal_error: float
    n_background: float
    n_background_error: float
    slope: float
    n_candidates: int
    window: tuple[float, float]
    valid: bool
    status: str

    def as_dict(self) -> dict:
        out = asdict(self)
        out["window"] = list(self.window)
        return out

    def density(self, m) -> np.ndarray:
        """Fitted signal + background density [candidates/MeV] at masses ``m`` (for plots)."""
        return self.signal_density(m) + self.background_density(m)

    def signal_density(self, m) -> np.ndarray:
        lo, hi = self.window
        m = np.asarray(m, dtype=float)
        return self.n_signal * _gauss_in_window(m, self.mean, self.sigma, lo, hi)

    def background_density(self, m) -> np.ndarray:
        lo, hi = self.window
        m = np.asarray(m, dtype=float)
        return self.n_background * _line_in_window(m, self.slope, lo, hi)


def _gauss_in_window(m, mu, sigma, lo, hi):
    return norm.pdf(m, mu, sigma) / (norm.cdf(hi, mu, sigma) - norm.cdf(lo, mu, sigma))


def _line_in_window(m, slope, lo, hi):
    centre, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    return (1.0 + slope * (m - centre) / half) / (hi - lo)


def _no_fit(n: int, window, status: str) -> MassFit:
    nan = float("nan")
    return MassFit(nan, nan, nan, nan, nan, nan, nan, nan, nan, n, (float(window[0]), float(window[1])), False, status)


def fit_mass_peak(masses, window: tuple[float, float] = (BS_MASS - 250.0, BS_MASS + 250.0)) -> MassFit:
    """Fit a Gaussian + linear background to the masses inside ``window`` (extended unbinned ML).

    Args:
        masses: candidate masses [MeV]; values outside the window (and NaN) are ignored.
        window: (lo, hi) fit range [MeV].

    Returns:
        the :class:`MassFit`; with fewer than :data:`MIN_CANDIDATES` candidates in the
        window no fit is made and ``status`` says so.
    """
    lo, hi = float(window[0]), float(window[1])
    m = np.asarray(masses, dtype=float)
    m = m[np.isfinite(m) & (m > lo) & (m < hi)]
    n = int(m.size)
    if n < MIN_CANDIDATES:
        return _no_fit(n, (lo, hi), f"too few candidates ({n} < {MIN_CANDIDATES} in the window)")

    def model(x, n_sig, n_bkg, mu, sigma, slope):
        return n_sig + n_bkg, n_sig * _gauss_in_window(x, mu, sigma, lo, hi) + n_bkg * _line_in_window(
            x, slope, lo, hi
        )

    median = float(np.median(m))
    mad = float(1.4826 * np.median(np.abs(m - median)))
    sigma0 = min(max(mad, 1.0), 0.25 * (hi - lo))
    core = np.abs(m - median) < 3 * sigma0
    n_sig0 = max(float(core.sum()), 1.0)
    n_bkg0 = max(n - n_sig0, 0.1 * n)
    fit = Minuit(ExtendedUnbinnedNLL(m, model), n_sig=n_sig0, n_bkg=n_bkg0, mu=median, sigma=sigma0, slope=0.0)
    fit.limits["n_sig"] = (0.0, 2.0 * n + 10)
    fit.limits["n_bkg"] = (0.0, 2.0 * n + 10)
    fit.limits["mu"] = (lo, hi)
    fit.limits["sigma"] = (0.01, 0.5 * (hi - lo))
    fit.limits["slope"] = (-1.0, 1.0)
    fit.migrad()
    if fit.valid:
        fit.hesse()
    valid = bool(fit.valid)
    accurate = bool(fit.fmin is not None and fit.fmin.has_accurate_covar)
    status = "ok" if valid and accurate else ("fit not valid" if not valid else "covariance not accurate")
    v, e = fit.values, fit.errors
    return MassFit(
        mean=float(v["mu"]), mean_error=float(e["mu"]), sigma=float(v["sigma"]), sigma_error=float(e["sigma"]),
        n_signal=float(v["n_sig"]), n_signal_error=float(e["n_sig"]),
        n_background=float(v["n_bkg"]), n_background_error=float(e["n_bkg"]),
        slope=float(v["slope"]), n_candidates=n, window=(lo, hi), valid=valid, status=status,
    )
