"""Where the compiled kernels spend their CPU: `perf` samples attributed to numba functions (issue 18).

numba's machine code lives in anonymous memory, so `perf report` shows bare addresses for
it. This script keeps the object code numba loads from its cache (`keep_object_code`: a hook on
``CPUCodeLibrary._set_compiled_object``; kernels compiled without ``cache=True`` have none), reads each object's symbols (``nm``), asks the
JIT engine where each symbol landed, and writes them to ``/tmp/perf-<pid>.map``, the file
`perf` reads for JIT symbols. Functions numba inlined count towards their caller.

Stages (after a warm-up run that compiles or loads the kernels, `perf record` attaches to
this process for the timed part only, all its threads, ``--frequency`` samples/s):

- ``pattern``: `pkf.pipeline.triplet_pattern.triplet_candidates` (VELO search, forward
  extension, upstream pass) on ``--events`` lhcb-like minimum-bias events at ``--pileup``,
  ``--repeat`` times;
- ``fit``: ``--fitter``'s batch fit (``fit_batch`` of `benchmarks/fit_compare.py`, one pass, no
  outlier removal) of `benchmarks/fit_core.py`'s minimum-bias long tracks, ``--repeat`` times
  (events: the dataset's 40);
- ``gsf``: the GSF with 12 components of `benchmarks/side_by_side.py`'s lhcb-like electrons (2–50
  GeV, ``--events`` events of 10 electrons, their long truth tracks), ``--repeat`` times; the
  "ms/event" column is then ms per track;
- ``reconstruct``: `pkf reconstruct DATASET --workers 1` in this process (``--dataset``;
  everything: validation, reading, pattern, seeds, fit, tables, Parquet writing).

Prints each function's share of the samples and its CPU ms per event (share × the CPU time
of the timed part, `time.process_time`, / events), grouped by module, and writes JSON with
``--json``. Needs Linux `perf` (``perf_event_paranoid`` ≤ 2 for one's own processes) and
binutils' ``nm``.

    python benchmarks/kernel_profile.py [--stage pattern] [--events 100] [--pileup 7.6] \
        [--repeat 3] [--top 30] [--json out.json]
    python benchmarks/kernel_profile.py --stage fit [--fitter parametrized] [--repeat 20]
    python benchmarks/kernel_profile.py --stage gsf --events 60 --repeat 3
    python benchmarks/kernel_profile.py --stage reconstruct --dataset DATASET [--json out.json]
"""

from __future__ import annotations

import argparse
import gc
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

from numba.core import codegen

# ------------------------------------------------------------------------------------------
# symbols of numba's machine code
# ------------------------------------------------------------------------------------------


def keep_object_code() -> None:
    """Make numba keep the object code of every library it loads or compiles from now on
    (``_perf_object``, for `perf_map_lines`): call before the kernels are first used."""
    original = codegen.CPUCodeLibrary._set_compiled_object
    if getattr(original, "keeps_object", False):
        return

    def keep(self, value):
        self._perf_object = value
        return original(self, value)

    keep.keeps_object = True
    codegen.CPUCodeLibrary._set_compiled_object = keep


def _object_symbols(object_code: bytes) -> dict[str, int]:
    """Defined function symbols (global, local and weak) of an ELF object → size [bytes]."""
    with tempfile.NamedTemporaryFile(suffix=".o") as f:
        f.write(object_code)
        f.flush()
        listing = subprocess.run(["nm", "-S", "--defined-only", f.name], capture_output=True, text=True).stdout
    sizes = {}
    for line in listing.splitlines():
        fields = line.split()
        if len(fields) == 4 and fields[2] in "tTwW":
            sizes[fields[3]] = int(fields[1], 16)
    return sizes


def perf_map_lines() -> list[str]:
    """``START SIZE NAME`` (hex) of every function of every numba library of this process."""
    lines, seen = [], set()
    for lib in gc.get_objects():
        if not issubclass(type(lib), codegen.CPUCodeLibrary) or id(lib) in seen:  # type(): no __getattribute__
            continue
        seen.add(id(lib))
        obj = getattr(lib, "_perf_object", None) or getattr(lib, "_compiled_object", None)
        if not obj:
            continue
        engine = lib._codegen._engine._ee
        for name, size in _object_symbols(obj).items():
            address = engine.get_function_address(name)
            if address:
                lines.append(f"{address:x} {size:x} {name}\n")
    return lines


_ITANIUM_PART = re.compile(r"(\d+)")


def readable_name(symbol: str) -> str:
    """``pkf.seeding.forward.scifi.scifi_search`` from numba's mangled ``_ZN3pkf7seeding…B4v…E…``;
    ``cpython.``/``cfunc.`` wrappers keep a prefix; other symbols as they are."""
    prefix = ""
    if symbol.startswith("cfunc."):
        prefix, symbol = "cfunc:", symbol[len("cfunc.") :]
    if not symbol.startswith("_ZN"):
        return prefix + symbol
    parts, i = [], 3
    while i < len(symbol) and symbol[i].isdigit():
        m = _ITANIUM_PART.match(symbol, i)
        n = int(m.group(1))
        start = m.end()
        parts.append(symbol[start : start + n].replace("_3c", "<").replace("_3e", ">").replace("_2e", "."))
        i = start + n
    if parts and parts[0] == "cpython":
        prefix, parts = prefix + "cpython:", parts[1:]
    return prefix + ".".join(parts)


# ------------------------------------------------------------------------------------------
# perf
# ------------------------------------------------------------------------------------------


class PerfRecord:
    """`perf record` attached to this process while the ``with`` block runs."""

    def __init__(self, data: Path, frequency: int, event: str | None = None):
        self.data, self.frequency, self.event = data, frequency, event

    def __enter__(self):
        what = ["-e", self.event, "-c", "1"] if self.event else ["-F", str(self.frequency)]
        self.proc = subprocess.Popen(
            ["perf", "record", "-q", *what, "-p", str(os.getpid()), "-o", str(self.data)],
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        time.sleep(0.5)  # attached before the work starts
        if self.proc.poll() is not None:
            sys.exit(f"kernel_profile.py: perf record failed: {self.proc.stderr.read().decode().strip()[:300]}")
        self.cpu0 = time.process_time()
        return self

    def __exit__(self, *exc):
        self.cpu_s = time.process_time() - self.cpu0
        self.proc.send_signal(signal.SIGINT)
        self.proc.wait()
        with open(f"/tmp/perf-{os.getpid()}.map", "w") as f:  # read by perf report, below
            f.writelines(perf_map_lines())


def sample_shares(data: Path) -> dict[str, float]:
    """perf's share [%] of the samples per symbol (readable names, summed)."""
    out = subprocess.run(
        ["perf", "report", "-i", str(data), "--no-children", "--sort", "sym", "--stdio", "-q"],
        capture_output=True,
        text=True,
    ).stdout
    shares: dict[str, float] = defaultdict(float)
    for line in out.splitlines():
        m = re.match(r"\s*([\d.]+)%\s+\[(.)\]\s+(\S+)", line)
        if m:
            name = m.group(3)
            key = (
                "[kernel]"
                if m.group(2) == "k"
                else ("[JIT, no symbol]" if name.startswith("0x") else readable_name(name))
            )
            shares[key] += float(m.group(1))
    return dict(shares)


# ------------------------------------------------------------------------------------------
# stages
# ------------------------------------------------------------------------------------------


def pattern_stage(args):
    """(work, events): triplet_candidates on simulated minimum-bias events."""
    from pkf.geometry import load_geometry
    from pkf.params.parameter_set import shipped_parameters
    from pkf.pipeline.simulate import SimulationConfig, simulate_batch
    from pkf.pipeline.triplet_pattern import triplet_candidates

    geometry = load_geometry("lhcb-like")
    ext = shipped_parameters(geometry).extrapolator(geometry)
    config = SimulationConfig(generator="minbias", events=args.events, pileup=args.pileup, seed=args.seed)
    hits = simulate_batch(geometry, config, 0, args.events)[0]
    h = {c: hits.column(c).to_numpy(zero_copy_only=False) for c in hits.column_names}
    call = (geometry, ext, h["event_id"], h["layer"], h["u"], h["v"], h["z"], h["sigma_u"], h["sigma_v"])
    triplet_candidates(*call)  # warm-up

    def work():
        for _ in range(args.repeat):
            triplet_candidates(*call)

    return work, args.events * args.repeat


def fit_stage(args):
    """(work, events): one fitter's batch fit of fit_core.py's minimum-bias sample."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    import fit_compare

    from pkf.fit.options import FitOptions
    from pkf.geometry import load_geometry

    batch, d = fit_compare.load_sample("minbias")  # fit_core.py --sample minbias's
    ext, fit = fit_compare._fit_function(args.fitter, load_geometry("lhcb-like"))
    options = FitOptions(max_outliers=0)
    fit(ext, batch, options, d["seeds"], d["seed_covs"])  # warm-up

    def work():
        for _ in range(args.repeat):
            fit(ext, batch, options, d["seeds"], d["seed_covs"])

    return work, 40 * args.repeat


def reconstruct_stage(args):
    """(work, events): `pkf reconstruct DATASET --workers 1` into a scratch directory."""
    from pkf.pipeline.config import ReconstructionConfig
    from pkf.pipeline.reconstruct import run_reconstruction

    if args.dataset is None:
        sys.exit("kernel_profile.py: --stage reconstruct needs --dataset")
    out = Path(tempfile.mkdtemp(prefix="kernel_profile_")) / "run"
    info = {}

    def work():
        info.update(run_reconstruction(args.dataset, out, ReconstructionConfig(), overwrite=True, progress=False))

    def events():
        return info["counts"]["events"]

    return work, events


def gsf_stage(args):
    """(work, tracks): the GSF (12 components) of side_by_side.py's lhcb-like electrons (2–50 GeV,
    ``--events`` events of 10), the acceptance sample of issue 18.2; per "event" read per track."""
    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from side_by_side import gsf_workload

    import pkf

    build, n_tracks, _, _ = gsf_workload(args)
    fit = build(pkf)
    fit()  # warm-up

    def work():
        for _ in range(args.repeat):
            fit()

    return work, n_tracks * args.repeat


STAGES = {"pattern": pattern_stage, "fit": fit_stage, "gsf": gsf_stage, "reconstruct": reconstruct_stage}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--stage", choices=tuple(STAGES), default="pattern")
    parser.add_argument("--fitter", default="parametrized", help="--stage fit: parametrized, reference, gx2f, gsf")
    parser.add_argument("--events", type=int, default=100)
    parser.add_argument("--pileup", type=float, default=7.6)
    parser.add_argument("--seed", type=int, default=77)
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--dataset", type=Path, default=None)
    parser.add_argument("--frequency", type=int, default=2000, help="perf samples per second")
    parser.add_argument(
        "--event",
        default=None,
        help="count a software event instead of sampling CPU time, every occurrence (e.g. "
        "page-faults: which functions touch new memory); ms/event is then not a time",
    )
    parser.add_argument("--top", type=int, default=30, help="functions printed")
    parser.add_argument("--json", type=Path, default=None)
    args = parser.parse_args()
    for tool in ("perf", "nm"):
        if shutil.which(tool) is None:
            sys.exit(f"kernel_profile.py: needs `{tool}` on PATH")
    keep_object_code()  # before pkf's kernels load (the stages import pkf)

    work, events = STAGES[args.stage](args)
    with tempfile.TemporaryDirectory() as tmp:
        data = Path(tmp) / "perf.data"
        with PerfRecord(data, args.frequency, args.event) as rec:
            work()
        shares = sample_shares(data)
    n_events = events() if callable(events) else events
    ms_per_event = {name: share / 100 * rec.cpu_s * 1e3 / n_events for name, share in shares.items()}
    ranked = sorted(shares, key=shares.get, reverse=True)
    print(
        f"stage {args.stage}: {n_events} events, {rec.cpu_s:.2f} s CPU "
        f"({1e3 * rec.cpu_s / n_events:.2f} ms/event); perf samples by function"
    )
    print(f"{'share':>7} {'ms/event':>9}  function")
    for name in ranked[: args.top]:
        print(f"{shares[name]:6.2f}% {ms_per_event[name]:9.3f}  {name}")
    modules: dict[str, float] = defaultdict(float)
    for name, share in shares.items():
        modules[name.rsplit(".", 1)[0] if name.startswith("pkf.") else "(not pkf's kernels)"] += share
    print("\nby module")
    for name in sorted(modules, key=modules.get, reverse=True):
        print(f"{modules[name]:6.2f}% {modules[name] / 100 * rec.cpu_s * 1e3 / n_events:9.3f}  {name}")
    if args.json:
        args.json.write_text(
            json.dumps(
                {
                    "stage": args.stage,
                    "events": n_events,
                    "cpu_s": rec.cpu_s,
                    "setup": vars(args) | {"json": str(args.json), "dataset": str(args.dataset)},
                    "share_percent": shares,
                    "ms_per_event": ms_per_event,
                    "module_share_percent": modules,
                },
                indent=2,
            )
            + "\n"
        )


if __name__ == "__main__":
    main()
