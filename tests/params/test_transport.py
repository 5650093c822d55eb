"""The parametrized transport's home (`pkf.params.transport`): codes and registration."""

import subprocess
import sys

from pkf.fit import extrapolator
from pkf.params import transport, ut_to_scifi


def test_transport_codes_are_the_track_status_codes():
    """The fitters report what the transport returns: the numbers must be the same."""
    assert transport.TRANSPORT_OK == extrapolator.STATUS_OK == ut_to_scifi.STATUS_OK
    assert transport.TRANSPORT_FAILED == extrapolator.STATUS_EXTRAPOLATION_FAILED == ut_to_scifi.STATUS_INVALID_TABLE
    assert transport.TRANSPORT_BELOW_P_MIN == extrapolator.STATUS_BELOW_P_MIN == ut_to_scifi.STATUS_BELOW_P_MIN


def test_kalman_core_knows_the_parametrized_step_without_importing_it():
    """A fresh process that imports only the Kalman core has the parametrized step registered
    (it used to be registered as a side effect of importing `pkf.fit.parametrized`)."""
    code = ("import pkf.fit.kalman\n"
            "from pkf.fit.extrapolator import _STEP_FUNCTIONS\n"
            "from pkf.params.transport import ParametrizedExtrapolator, parametrized_step\n"
            "assert _STEP_FUNCTIONS[ParametrizedExtrapolator] is parametrized_step\n")
    subprocess.run([sys.executable, "-c", code], check=True)
