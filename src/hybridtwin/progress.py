"""Progress of a long job in its log (issue 55): how many of its items are done, the time so far and an estimate of
the time left, so that a user watching ``logs/`` knows whether to wait or to come back later.

The estimate is the mean time per item so far times the items left (items of unequal cost, as the runs of a variant's
libraries, make it rough; it says "about"). Each line goes to the job's own logger, at INFO:

    spgd_library: 5 of 22 runs (23 %) after 41 s, about 2.3 min left (run r950_m0p0 done)
"""

from __future__ import annotations

import logging
import time


def duration(seconds: float) -> str:
    """A duration as a person reads it: "41 s", "2.3 min", "1.2 h"."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 90 * 60:
        return f"{seconds / 60:.1f} min"
    return f"{seconds / 3600:.1f} h"


class Progress:
    """``total`` items of a job's work (``what``: their name, plural), counted as they are done.

    ``clock``: the time source (seconds; ``time.perf_counter`` unless a test gives its own)."""

    def __init__(self, log: logging.Logger | None, total: int, what: str, clock=time.perf_counter):
        self.log, self.total, self.what, self.clock = log, int(total), what, clock
        self.start, self.count = clock(), 0

    def left_s(self) -> float:
        """The estimate of the time left [s]: the mean time per item so far times the items left (NaN before the
        first)."""
        if self.count == 0:
            return float("nan")
        return (self.clock() - self.start) / self.count * max(self.total - self.count, 0)

    def line(self, note: str = "") -> str:
        """The progress line after the items counted so far."""
        elapsed = self.clock() - self.start
        pct = 100.0 * self.count / self.total if self.total else 100.0
        text = f"{self.count} of {self.total} {self.what} ({pct:.0f} %) after {duration(elapsed)}"
        if self.count < self.total:
            text += f", about {duration(self.left_s())} left"
        return text + (f" ({note})" if note else "")

    def done(self, n: int = 1, note: str = "") -> str:
        """Count ``n`` more items done and log the line (returned too)."""
        self.count += n
        text = self.line(note)
        if self.log is not None:
            self.log.info("%s", text)
        return text
