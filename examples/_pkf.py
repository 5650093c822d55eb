"""Run the `pkf` command line from an example script (the installed console script, or this
Python's `python -m pkf.cli` when the script is not on PATH)."""

from __future__ import annotations

import shutil
import subprocess
import sys


def pkf(*args: str) -> None:
    """Run one `pkf` command; stop the example with its message if it fails."""
    exe = shutil.which("pkf")
    command = [exe] if exe else [sys.executable, "-m", "pkf.cli"]
    print("$ pkf " + " ".join(args), flush=True)
    result = subprocess.run([*command, *args])
    if result.returncode != 0:
        sys.exit(f"pkf {args[0]} failed with exit code {result.returncode}")
