"""pkf: track reconstruction with hit triplets and the LHCb parametrized Kalman filter.

Units everywhere: mm, MeV (c = 1), tesla, rad (DESIGN §2).
"""

from importlib.metadata import PackageNotFoundError, version

try:
    __version__ = version("pkf")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

__all__ = ["__version__"]
