"""Progress bars of the commands (simulate, reconstruct, tune, report) on stderr.

A bar is drawn only on a terminal: ``progress=None`` leaves the choice to tqdm, which
disables itself when stderr is not a TTY (a pipe, a file, a batch job's log), so scripts
and CI logs get no bar. ``progress=True``/``False`` force it on or off.

Reconstruction reports progress per sub-batch of events inside a partition
(:data:`pkf.pipeline.executor.PROGRESS_HITS`), possibly from worker processes or Dask
workers, and again when the partition is finished; :class:`PartitionProgress` turns
these reports into bar updates that never count an event twice (a report that arrives
after its partition finished, or from a partition Dask retried on another worker, is capped).
"""

from __future__ import annotations

from tqdm import tqdm

__all__ = ["progress_bar", "PartitionProgress", "MIN_INTERVAL_S"]

#: Seconds between redraws of a bar (tqdm's ``mininterval``).
MIN_INTERVAL_S = 0.1


def progress_bar(total: int | None, desc: str, unit: str = "event", progress: bool | None = None,
                 initial: int = 0) -> tqdm:
    """A tqdm bar on stderr; ``progress`` None: only when stderr is a terminal."""
    return tqdm(total=total, initial=initial, unit=unit, desc=desc, mininterval=MIN_INTERVAL_S,
                disable=None if progress is None else not progress)


class PartitionProgress:
    """Events done per partition, fed to a bar.

    Args:
        bar: anything with ``update(n)`` (a tqdm bar).
        events_of: events of each partition, by partition name.
    """

    def __init__(self, bar, events_of: dict[str, int]):
        self.bar = bar
        self.events_of = events_of
        self.reported: dict[str, int] = {}

    def advance(self, name: str, events: int) -> None:
        """``events`` more events of partition ``name`` are reconstructed."""
        done = self.reported.get(name, 0)
        step = max(0, min(events, self.events_of[name] - done))
        if step:
            self.reported[name] = done + step
            self.bar.update(step)

    def finish(self, name: str) -> None:
        """Partition ``name`` is written: count whatever of it was not reported yet."""
        self.advance(name, self.events_of[name])
