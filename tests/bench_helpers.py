"""Loading a script of `benchmarks/` as a module, for the tests of its pieces."""

import importlib.util
import sys
from pathlib import Path

BENCHMARKS = Path(__file__).resolve().parents[1] / "benchmarks"


def load_benchmark(name: str):
    """`benchmarks/<name>.py` as a module (the directory on sys.path first, for the helpers
    it imports, such as `fit_compare`)."""
    if str(BENCHMARKS) not in sys.path:
        sys.path.insert(0, str(BENCHMARKS))
    spec = importlib.util.spec_from_file_location(name, BENCHMARKS / f"{name}.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def truth_sample_class():
    """`tests/fit/fit_helpers.TruthSample` (that directory on sys.path first), for the tests
    that run a benchmark's pieces on simulated tracks."""
    fit_tests = str(Path(__file__).resolve().parent / "fit")
    if fit_tests not in sys.path:
        sys.path.insert(0, fit_tests)
    from fit_helpers import TruthSample

    return TruthSample


def forget_twin(monkeypatch):
    """Unload the ``pkf_base_<digest>`` packages (`benchmarks/twin.py`) a previous test imported,
    all their modules (restored after the test), so that the next `load_twin` imports a fresh
    copy."""
    import sys

    for name in [m for m in sys.modules if m.startswith("pkf_base_")]:
        monkeypatch.delitem(sys.modules, name)
