"""Progress as plain text lines, for a log or a pipe where no progress bar shows."""

from __future__ import annotations

import sys
import time
from collections.abc import Callable
from typing import TextIO

__all__ = ["ProgressLines", "duration"]

LINE_INTERVAL = 30.0
"""Seconds between two progress lines (the first and the last are always written)."""


def duration(seconds: float) -> str:
    """``seconds`` as ``"42 s"``, ``"7 min 5 s"`` or ``"2 h 13 min"``."""
    seconds = max(0, round(seconds))
    if seconds < 60:
        return f"{seconds} s"
    if seconds < 3600:
        return f"{seconds // 60} min {seconds % 60} s"
    return f"{seconds // 3600} h {seconds % 3600 // 60} min"


class ProgressLines:
    """Writes ``"<what>: D of T runs done, L left, about E left"`` lines as runs (or other units) finish.

    Runs that ended without a result (a sweep's lost tasks) are counted apart, as ``", N lost"``: neither done
    nor left.

    Parameters
    ----------
    what : str
        The job's name, at the start of each line.
    total : int
        Runs in the whole job.
    done : int
        Runs already done before this process started (read back from a store); the time left is
        estimated from the runs this process completes: elapsed time / runs completed x runs left.
    interval : float
        Least seconds between two lines; the first completed run and the last always give a line.
    stream : text stream
        Where the lines go (default: stderr).
    clock : callable
        Seconds, monotonic (``time.monotonic``).
    unit : str
        What is counted, plural (``"runs"``; a sweep counts ``"tasks"``).

    """

    def __init__(self, what: str, total: int, *, done: int = 0, interval: float = LINE_INTERVAL,
                 stream: TextIO | None = None, clock: Callable[[], float] = time.monotonic,
                 unit: str = "runs") -> None:  # fmt: skip
        self.what, self.total, self.done, self.before, self.unit = what, total, done, done, unit
        self.lost = 0
        self.interval, self.stream, self.clock = interval, stream, clock
        self.start = clock()
        self.last: float | None = None

    def line(self) -> str:
        """The current line (no newline)."""
        left = self.total - self.done - self.lost
        stored = f" ({self.before} stored before)" if self.before else ""
        lost = f", {self.lost} lost" if self.lost else ""
        text = f"{self.what}: {self.done} of {self.total} {self.unit} done{stored}{lost}, {left} left"
        ended = self.done - self.before + self.lost  # the runs this process finished, with or without a result
        if left and ended:
            text += f", about {duration((self.clock() - self.start) / ended * left)} left"
        return text

    def advance(self, runs: int = 1, *, lost: int = 0) -> None:
        """Count ``runs`` more finished runs (and ``lost`` without a result); write a line if the interval has passed.

        The first line and the last (every run finished or lost) are written at once.
        """
        self.done += runs
        self.lost += lost
        now = self.clock()
        if self.last is None or now - self.last >= self.interval or self.done + self.lost >= self.total:
            self.last = now
            stream = self.stream if self.stream is not None else sys.stderr
            stream.write(self.line() + "\n")
            stream.flush()
