"""Resumable run directories: a persistent staging directory, a journal of finished partitions.

``pkf reconstruct --out RUN`` builds the run in the hidden sibling ``.RUN.partial/``,
renamed to ``RUN`` only when every partition is done and ``run.json`` is written, so
an interrupted run (even by SIGKILL) leaves nothing that looks complete. Each finished
partition writes its table files (atomically), then its journal entry
``_journal/PART.json`` with the partition's key (hash of its inputs and configuration)
and the SHA-256 of each file. A rerun keeps the partitions whose entry has the same
key and whose files still have the recorded hashes, and removes everything else;
``--overwrite`` starts from scratch. A rerun of a complete run of the same partitions
checks its files against run.json and refuses a damaged one, naming the file.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import secrets
import shutil
from pathlib import Path

from pkf.errors import InputError
from pkf.io.atomic import check_output_dir
from pkf.io.stream import file_sha256
from pkf.report.runs import verify_run_files

JOURNAL = "_journal"


def partial_dir(final: Path) -> Path:
    """The persistent staging directory of the run directory ``final``."""
    return final.with_name(f".{final.name}.partial")


def verify_entry(root: Path, entry: dict, key: str) -> bool:
    """Whether a journal entry (or run.json partition record) has ``key`` and intact files."""
    if not isinstance(entry, dict) or entry.get("key") != key or not isinstance(entry.get("files"), dict):
        return False
    for record in entry["files"].values():
        path = root / str(record.get("path", ""))
        if not path.is_file() or file_sha256(path) != record.get("sha256"):
            return False
    return True


def complete_run(final: Path, keys: dict[str, str]) -> dict | None:
    """run.json of an existing complete run of exactly these partitions (names and keys),
    else None.

    Raises:
        InputError: it is such a run, but a partition file is missing, changed or
            joined by an unlisted one (:func:`pkf.report.runs.verify_run_files`).
    """
    try:
        info = json.loads((final / "run.json").read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    records = info.get("partitions") if isinstance(info, dict) else None
    if not isinstance(records, list) or not all(isinstance(r, dict) for r in records):
        return None
    if {r.get("name"): r.get("key") for r in records} != keys or len(records) != len(keys):
        return None
    verify_run_files(final, info)
    return info


class RunStaging:
    """The persistent staging directory of one run, locked against a second writer.

    Use as a context manager; :meth:`finish` moves it into place.
    """

    def __init__(self, final: str | os.PathLike, overwrite: bool, inputs: tuple = ()):
        self.final = check_output_dir(final, overwrite=True, inputs=inputs)
        self.inputs = inputs
        self.overwrite = overwrite
        self.path = partial_dir(self.final)
        self._lock = None

    def __enter__(self) -> RunStaging:
        if self.overwrite and self.path.exists():
            self._acquire()
            shutil.rmtree(self.path)
            self._release()
        try:
            self.path.mkdir(exist_ok=True)
            (self.path / JOURNAL).mkdir(exist_ok=True)
        except OSError as exc:
            raise InputError(f"{self.final}: cannot create the output directory here: {exc.strerror}") from None
        self._acquire()
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        """On an error: keep the staging directory only if it holds finished partitions to resume."""
        if exc_type is not None and self.path.is_dir():
            journal = self.path / JOURNAL
            if not journal.is_dir() or not any(journal.glob("*.json")):
                shutil.rmtree(self.path, ignore_errors=True)
        self._release()

    def _acquire(self) -> None:
        self.path.mkdir(exist_ok=True)
        self._lock = open(self.path / ".lock", "a")
        try:
            fcntl.flock(self._lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError:
            self._lock.close()
            self._lock = None
            raise InputError(f"{self.final}: another `pkf reconstruct` is writing this run (lock on {self.path})") from None

    def _release(self) -> None:
        if self._lock is not None:
            self._lock.close()
            self._lock = None

    def finished(self, keys: dict[str, str]) -> dict[str, dict]:
        """Journal entries of partitions that are done and intact; removes every other file."""
        done = {}
        journal = self.path / JOURNAL
        for file in sorted(journal.iterdir()):
            name = file.name.removesuffix(".json")
            entry = None
            if file.suffix == ".json" and name in keys:
                with contextlib.suppress(OSError, ValueError):
                    entry = json.loads(file.read_text(encoding="utf-8"))
            if entry is not None and verify_entry(self.path, entry, keys[name]):
                done[name] = entry
            else:
                file.unlink()
        keep = {Path(r["path"]) for e in done.values() for r in e["files"].values()}
        for table_dir in [d for d in self.path.iterdir() if d.is_dir() and d.name != JOURNAL]:
            for file in table_dir.iterdir():
                if file.relative_to(self.path) not in keep:
                    file.unlink() if not file.is_dir() else shutil.rmtree(file)
        for file in self.path.iterdir():
            if file.is_file() and file.name != ".lock":
                file.unlink()
        return done

    def finish(self) -> Path:
        """Remove the journal and lock, and rename the staging directory to the run directory."""
        shutil.rmtree(self.path / JOURNAL, ignore_errors=True)
        with contextlib.suppress(FileNotFoundError):
            (self.path / ".lock").unlink()
        final = check_output_dir(self.final, overwrite=True, inputs=self.inputs)
        if final.exists():
            if not self.overwrite and any(final.iterdir()):
                raise InputError(f"{final}: output directory exists and is not empty (use --overwrite to replace it)")
            old = final.with_name(f".{final.name}.{os.getpid()}.{secrets.token_hex(4)}.old")
            os.replace(final, old)
            try:
                os.replace(self.path, final)
            except BaseException:
                os.replace(old, final)
                raise
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(self.path, final)
        self._release()
        return final
