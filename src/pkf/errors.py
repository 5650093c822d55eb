"""Exceptions that the command line turns into a one-line message and exit code 2."""


class InputError(Exception):
    """Bad usage or bad input: the message is one line that names what is wrong.

    The CLI prints it on stderr and exits with code 2 (docs/cli.md#exit-codes-and-messages).
    """


class NotBuiltYet(Exception):
    """A stage or option of the pipeline that does not exist yet.

    The CLI says so on stderr and exits with code 1; pkf never makes numbers up.
    """


class CtrlC:
    """Whether SIGINT reached the command line's handler (`pkf.cli.main` installs it).

    Ctrl-C normally arrives as a KeyboardInterrupt, but Python swallows one raised inside a
    finalizer or a ctypes callback (numba caching a kernel: "Exception ignored … KeyboardInterrupt")
    and the run would go on to the end. Long loops call `CtrlC.check()` between groups of work.
    """

    seen = False

    @classmethod
    def handler(cls, signum, frame):
        """SIGINT handler: remember, then raise KeyboardInterrupt as Python's default does."""
        cls.seen = True
        raise KeyboardInterrupt

    @classmethod
    def check(cls) -> None:
        """Raise KeyboardInterrupt if Ctrl-C was pressed since the command started."""
        if cls.seen:
            raise KeyboardInterrupt
