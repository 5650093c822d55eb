"""Track status codes of every fitter (the `status` column of the chi2 table says them in words)."""

from __future__ import annotations

STATUS_OK = 0
STATUS_TOO_FEW_HITS = 1
STATUS_EXTRAPOLATION_FAILED = 2
STATUS_NOT_POSITIVE_DEFINITE = 3
STATUS_BELOW_P_MIN = 4
STATUS_NO_SEED = 5
STATUS_NOT_CONVERGED = 6

STATUS_NAMES = (
    "ok",
    "too few hits",
    "extrapolation failed",
    "covariance not positive definite",
    "momentum below the parametrization's p_min",
    "no seed estimate",
    "did not converge",
)
