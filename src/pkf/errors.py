"""Exceptions that the command line turns into a one-line message and exit code 2."""


class InputError(Exception):
    """Bad usage or bad input: the message is one line that names what is wrong.

    The CLI prints it on stderr and exits with code 2 (docs/cli.md#exit-codes-and-messages).
    """


class NotBuiltYet(Exception):
    """A stage or option of the pipeline that does not exist yet.

    The CLI says so on stderr and exits with code 1; pkf never makes numbers up.
    """
