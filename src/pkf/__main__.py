"""The `pkf` console script and `python -m pkf`: the command line of `pkf.cli`, with Ctrl-C
during start-up (importing numba, scipy and the kernels, compiling them on a first run) answered
like Ctrl-C anywhere else: one line, exit 130, no traceback (docs/cli.md#exit-codes-and-messages)."""

import signal
import sys

_INTERRUPTED = "pkf: interrupted; nothing was written (rerun the command)\n"


def main() -> int:
    """Import the command line and run it; returns the exit code."""
    seen = []

    def on_sigint(signum, frame):
        seen.append(signum)
        signal.default_int_handler(signum, frame)

    previous = signal.getsignal(signal.SIGINT)
    if previous is signal.default_int_handler:  # not where SIGINT is ignored (a background job)
        signal.signal(signal.SIGINT, on_sigint)
    try:
        from pkf.cli import main as cli_main
    except BaseException as exc:
        # numba may turn the KeyboardInterrupt into another error while it compiles or caches a kernel
        if isinstance(exc, KeyboardInterrupt) or seen:
            sys.stderr.write(_INTERRUPTED)
            return 130
        raise
    finally:
        signal.signal(signal.SIGINT, previous)
    if seen:  # a library imported on the way caught the KeyboardInterrupt (a bare except) and went on
        sys.stderr.write(_INTERRUPTED)
        return 130
    return cli_main()


if __name__ == "__main__":
    sys.exit(main())
