"""The `pkf` command line: parse options, call the pipeline stages, print (docs/cli.md).

Exit codes: 0 success, 2 bad usage or bad input (one line on stderr), 1 internal error.
Set PKF_DEBUG=1 to see the traceback of an internal error.
"""

from __future__ import annotations

import math
import os
import signal
import sys
import threading
import traceback
from pathlib import Path

import click

import pkf
from pkf.errors import CtrlC, InputError, NotBuiltYet
from pkf.geometry import BUILTIN_GEOMETRIES
from pkf.fit.fitters import FITTER_NAMES
from pkf.fit.options import (
    GSF_OUTPUTS,
    HYPOTHESES,
    MAX_MERGE_FACTOR,
    SMOOTHERS,
    GSFOptions,
    GX2FOptions,
    KalmanOptions,
)
from pkf.pipeline.config import PATTERNS
from pkf.pipeline.reconstruct import EVENTS_PER_BATCH
from pkf.simulation.generators import GENERATORS
from pkf.simulation.species import SPECIES_NAMES


class FloatRange(click.FloatRange):
    """click's FloatRange that also refuses NaN (which no bound comparison catches)."""

    def convert(self, value, param, ctx):
        number = super().convert(value, param, ctx)
        if math.isnan(number):
            self.fail(f"{value!r} is not a number.", param, ctx)
        return number


@click.group(context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(pkf.__version__, prog_name="pkf")
def cli() -> None:
    """pkf: hit-triplet tracking and the LHCb parametrized Kalman filter.

    Units: mm, MeV, tesla, rad. See README.md for the two commands to start with.
    """


@cli.command()
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="Dataset directory to create.")
@click.option("--geometry", default="lhcb-like", show_default=True,
              help=f"Built-in geometry ({', '.join(BUILTIN_GEOMETRIES)}) or a TOML file.")
@click.option("--generator", default="minbias", show_default=True, type=click.Choice(GENERATORS))
@click.option("--events", default=100, show_default=True, type=int, help="Number of events.")
@click.option("--pileup", default=1.0, show_default=True, type=float, help="Mean pp interactions ν per event.")
@click.option("--seed", default=1, show_default=True, type=int, help="Random seed (same seed → identical files).")
@click.option("--species", default="pion", show_default=True, type=click.Choice(SPECIES_NAMES), help="Gun species.")
@click.option("--particles", default=10, show_default=True, type=int, help="Gun particles per event.")
@click.option("--p-min", default=2000.0, show_default=True, type=float, help="Gun momentum minimum [MeV].")
@click.option("--p-max", default=100000.0, show_default=True, type=float, help="Gun momentum maximum [MeV].")
@click.option("--eta-min", default=2.0, show_default=True, type=float, help="Gun pseudorapidity minimum.")
@click.option("--eta-max", default=5.0, show_default=True, type=float, help="Gun pseudorapidity maximum.")
@click.option("--overwrite", is_flag=True, help="Replace an existing non-empty --out.")
def simulate(out: Path, overwrite: bool, **options) -> None:
    """Simulate events into DATASET (hits, particles, mc_hits, meta.json)."""
    from pkf.pipeline.simulate import SimulationConfig, run_simulation

    config = SimulationConfig(**options)
    meta = run_simulation(config, out, overwrite=overwrite)
    counts = meta["counts"]
    click.echo(f"wrote {counts['events']} events, {counts['hits']} hits to {out}")


@cli.command()
@click.argument("dataset", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="Run directory to create.")
@click.option("--fitter", "fitters", multiple=True, type=click.Choice(FITTER_NAMES),
              help="Fitter(s) to run; repeat for several. Default: parametrized.")
@click.option("--pattern", default="triplet", show_default=True, type=click.Choice(PATTERNS),
              help="Pattern recognition: hit triplets, or ideal grouping by MC particle.")
@click.option("--params", default=None, help="Parameter file of the parametrized fitter.")
@click.option("--geometry", default=None, metavar="NAME|FILE.toml",
              help=f"Detector of the dataset: built-in ({', '.join(BUILTIN_GEOMETRIES)}) or a TOML file. "
                   "Default: the one its meta.json records (must agree when both are given).")
@click.option("--outlier-chi2", default=9.0, show_default=True, type=float,
              help="Remove a node whose χ² exceeds this (1-D equivalent).")
@click.option("--max-outliers", default=2, show_default=True, type=int, help="At most this many removals per track.")
@click.option("--iterations", default=None, type=click.IntRange(min=1),
              help="Kalman fitters: passes; later ones linearise around the previous fit. "
                   "Default: each fitter's own (reference and parametrized 2, the others 1).")
@click.option("--smoother", default="weighted-mean", show_default=True, type=click.Choice(SMOOTHERS[:2]),
              help="Kalman fitters: combine the forward and backward filters by their weighted mean, "
                   "or run the Rauch–Tung–Striebel smoother (the same states).")
@click.option("--hypothesis", default=KalmanOptions.hypothesis, show_default=True, type=click.Choice(HYPOTHESES),
              help="Kalman fitters: the particle assumed by the material effects; electron adds the "
                   "Bethe–Heitler mean loss and its variance to q/p at every plane.")
@click.option("--gx2f-max-updates", default=GX2FOptions.max_updates, show_default=True,
              type=click.IntRange(min=1), help="GX2F: at most this many Gauss–Newton updates per fit.")
@click.option("--max-components", default=GSFOptions.max_components, show_default=True,
              type=click.IntRange(min=1), help="GSF: largest number of Gaussian-mixture components (KL merging).")
@click.option("--gsf-weight-cut", default=GSFOptions.weight_cut, show_default=True,
              type=FloatRange(min=0.0, max=1.0, max_open=True),
              help="GSF: drop mixture components below this share of the total weight.")
@click.option("--gsf-output", default=GSFOptions.output, show_default=True, type=click.Choice(GSF_OUTPUTS),
              help="GSF: the state written per node: the centre of the mixture's Gaussian core, its mode, "
                   "its heaviest component, or its mean (each with the mixture's q/p variance about it).")
@click.option("--gsf-sibling-merge", default=GSFOptions.sibling_merge, show_default=True,
              type=FloatRange(min=0.0, max=MAX_MERGE_FACTOR),
              help="GSF: after each Bethe–Heitler convolution merge the closest pairs of one component's "
                   "children first, down to this many times --max-components components (0: all pairs at once).")
@click.option("--gsf-product-merge", default=GSFOptions.product_merge, show_default=True,
              type=FloatRange(min=0.0, max=MAX_MERGE_FACTOR),
              help="GSF smoothing: merge the closest pairs of the products that share a component of the more "
                   "precise filter first, down to this many times --max-components components (0: all at once).")
@click.option("--gsf-mixture-smoothing-everywhere", is_flag=True,
              help="GSF: smooth with the product of the forward and backward mixtures at every node, not only "
                   "at the first and last (the written states); slower, the same method at every node.")
@click.option("--track-states", is_flag=True,
              help="Also write the track_states table: every node's predicted, filtered and smoothed "
                   "state, residuals and χ² (large: ~3 rows per hit and fitter).")
@click.option("--workers", default=None, type=int,
              help="Local worker processes (default: all cores; 1 runs in this process).")
@click.option("--scheduler", default=None,
              help="Address of a Dask distributed scheduler (e.g. tcp://host:8786) to run the batches on; "
                   "needs the dask extra and a filesystem shared with its workers.")
@click.option("--events-per-batch", default=EVENTS_PER_BATCH, show_default=True, type=int,
              help="Events per partition (the unit of work and of output files; bounds memory).")
@click.option("--overwrite", is_flag=True,
              help="Redo everything and replace an existing --out (default: resume an interrupted run).")
def reconstruct(dataset: Path, out: Path, fitters: tuple[str, ...], workers: int | None, scheduler: str | None,
                events_per_batch: int, overwrite: bool, **options) -> None:
    """Reconstruct DATASET into the run directory --out (chi2, states, pulls, run.json; with
    --track-states also track_states).

    The run is built in a hidden .OUT.partial directory and moved into place at the end;
    rerunning an interrupted command resumes it, skipping the finished partitions.
    """
    from pkf.pipeline.reconstruct import ReconstructionConfig, run_reconstruction

    kalman = KalmanOptions(options.pop("iterations"), options.pop("smoother"), options.pop("hypothesis"))
    gx2f = GX2FOptions(max_updates=options.pop("gx2f_max_updates"))
    gsf = GSFOptions(options.pop("max_components"), options.pop("gsf_weight_cut"), options.pop("gsf_output"),
                     options.pop("gsf_sibling_merge"), options.pop("gsf_product_merge"),
                     options.pop("gsf_mixture_smoothing_everywhere"))
    config = ReconstructionConfig(fitters=fitters or ("parametrized",), kalman=kalman, gx2f=gx2f, gsf=gsf, **options)
    run = run_reconstruction(dataset, out, config, overwrite=overwrite, workers=workers, scheduler=scheduler,
                             events_per_batch=events_per_batch, echo=lambda line: click.echo(line, err=True))
    for name, t in run["timing"]["fit"].items():
        click.echo(f"{name}: {run['counts']['tracks'][name]} tracks fitted, "
                   f"{t['tracks_per_s'] or 0:.0f} tracks/s, {t['ns_per_node'] or 0:.0f} ns/node")
    if "pattern" in run:
        pat = run["pattern"]
        click.echo(f"pattern: efficiency {pat['efficiency']}, ghost rate {pat['ghost_rate']}, "
                   f"clone rate {pat['clone_rate']}")
    click.echo(f"wrote {out}")


@cli.command()
@click.argument("dataset", type=click.Path(path_type=Path))
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="Parameter file (JSON) to write.")
@click.option("--geometry", default=None, metavar="NAME|FILE.toml",
              help=f"Detector of the dataset: built-in ({', '.join(BUILTIN_GEOMETRIES)}) or a TOML file. "
                   "Default: the one its meta.json records (must agree when both are given).")
@click.option("--overwrite", is_flag=True, help="Replace an existing --out file.")
def tune(dataset: Path, out: Path, geometry: str | None, overwrite: bool) -> None:
    """Tune the parametrized extrapolations on a simulated DATASET (paper §4)."""
    from pkf.pipeline.tune import run_tuning

    run_tuning(dataset, out, overwrite=overwrite, echo=lambda line: click.echo(line, err=True), geometry=geometry)
    click.echo(f"wrote {out}")


@cli.command()
@click.argument("dataset", type=click.Path(path_type=Path))
@click.option("--geometry", default=None, metavar="NAME|FILE.toml",
              help=f"Detector of the dataset: built-in ({', '.join(BUILTIN_GEOMETRIES)}) or a TOML file. "
                   "Default: the one its meta.json records (must agree when both are given).")
def validate(dataset: Path, geometry: str | None) -> None:
    """Check DATASET as reconstruct would, without reconstructing: one line per problem
    (the first bad row of each table), exit 2 if any."""
    from pkf.pipeline.validate import validate_dataset

    found = validate_dataset(dataset, geometry)
    for line in found.warnings:
        click.echo(f"pkf: warning: {line}", err=True)
    for line in found.problems:
        click.echo(f"pkf: error: {line}", err=True)
    if not found.valid:
        raise click.exceptions.Exit(2)
    click.echo(found.summary)


@cli.command()
@click.argument("runs", nargs=-1, required=True, metavar="RUN[:LABEL]...")
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="Report directory to create.")
@click.option("--reference", default=None, metavar="LABEL[/FITTER]",
              help="Entry that ratios and speed-ups compare with. Default: the first 'reference' fitter, "
                   "else the first entry.")
@click.option("--overwrite", is_flag=True, help="Replace an existing non-empty --out.")
def report(runs: tuple[str, ...], out: Path, reference: str | None, overwrite: bool) -> None:
    """Resolution, pull, χ² and mass report of one or more runs, each labelled RUN:LABEL
    (default label: the run folder's name); the same fitter may appear in several runs."""
    from pkf.pipeline.report import run_report

    run_report(list(runs), out, overwrite=overwrite, reference=reference,
               echo=lambda line: click.echo(f"pkf: warning: {line}", err=True))
    click.echo(f"wrote {out / 'index.html'} and {out / 'summary.json'}")


@cli.command()
@click.option("--out", "out", required=True, type=click.Path(path_type=Path), help="Directory for everything.")
@click.option("--events", default=200, show_default=True, type=int, help="Number of B_s → φφ events.")
@click.option("--seed", default=1, show_default=True, type=int)
@click.option("--overwrite", is_flag=True, help="Replace an existing non-empty --out.")
def demo(out: Path, events: int, seed: int, overwrite: bool) -> None:
    """Simulate, reconstruct with both Kalman fitters and print the headline numbers."""
    from pkf.io.atomic import check_output_dir
    from pkf.pipeline.demo import run_demo

    check_output_dir(out, overwrite)
    if events <= 0:
        raise InputError(f"--events: must be a positive number of events, not {events}")
    run_demo(out, events, seed, overwrite, echo=click.echo)


def _interrupted_message(args: list[str]) -> str:
    """What Ctrl-C left behind, for the command that was running (docs/cli.md#exit-codes-and-messages: exit 130)."""
    command = next((a for a in args if not a.startswith("-")), "")
    if command == "reconstruct":
        return ("pkf: interrupted; finished partitions are kept in the hidden staging directory "
                "(rerun the same reconstruct command to resume)")
    return "pkf: interrupted; nothing was written (rerun the command)"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the `pkf` console script; returns the exit code.

    The command runs inside click's context directly rather than through ``cli.main``,
    which would turn Ctrl-C into ``click.Abort`` (exit 1, "aborted"); here it stays a
    KeyboardInterrupt: exit 130 with what to do next.
    """
    args = list(sys.argv[1:] if argv is None else argv)
    CtrlC.seen = False  # Ctrl-C may also reach us wrapped in other errors, or swallowed (CtrlC)
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGINT) is signal.default_int_handler:
        signal.signal(signal.SIGINT, CtrlC.handler)
    try:
        with cli.make_context("pkf", args) as ctx:
            cli.invoke(ctx)
    except click.exceptions.Exit as exc:
        return exc.exit_code
    except click.exceptions.Abort:
        click.echo("pkf: aborted", err=True)
        return 1
    except click.UsageError as exc:
        command = exc.ctx.command_path if exc.ctx else "pkf"
        click.echo(f"{command}: error: {exc.format_message()}", err=True)
        return 2
    except InputError as exc:
        click.echo(f"pkf: error: {exc}", err=True)
        return 2
    except NotBuiltYet as exc:
        click.echo(str(exc), err=True)
        return 1
    except KeyboardInterrupt:
        click.echo(_interrupted_message(args), err=True)
        return 130
    except Exception as exc:  # an internal error: one line, the traceback on request
        if CtrlC.seen:  # e.g. numba's SystemError "returned a result with an exception set"
            click.echo(_interrupted_message(args), err=True)
            return 130
        if os.environ.get("PKF_DEBUG"):
            traceback.print_exc()
        message = str(exc).splitlines()[0] if str(exc) else ""
        click.echo(f"pkf: internal error: {type(exc).__name__}: {message} (set PKF_DEBUG=1 for the traceback)", err=True)
        return 1
    return 0


def run() -> None:
    sys.exit(main())


if __name__ == "__main__":
    run()
