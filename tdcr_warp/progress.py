"""A one-line progress bar on stderr, shared by dynamics, control and sweeps."""

from __future__ import annotations

import sys
import time


class Progress:
    """A one-line progress bar on stderr: done/total units, rod-units/s, ETA, failed rods.
    ``start``: units already done before this run (resumed), left out of the rate."""

    line_open = False  # whether a bar's line on stderr is unfinished (a message would follow on it)

    def __init__(self, total: int, rods: int, unit: str = "steps", rate_unit: str = "rod-steps/s", start: int = 0):
        self.total, self.rods, self.t0, self.start = total, rods, time.perf_counter(), start
        self.unit, self.rate_unit = unit, rate_unit
        self.shown = -1.0

    def update(self, done: int, failed: int, note: str = "") -> None:
        now = time.perf_counter()
        if done < self.total and now - self.shown < 0.2:
            return
        self.shown = now
        el = now - self.t0
        rate = (done - self.start) * self.rods / el if el > 0 else 0.0
        eta = el / (done - self.start) * (self.total - done) if done > self.start else 0.0
        filled = int(30 * done / self.total)
        Progress.line_open = True
        sys.stderr.write(f"\r[{'#' * filled}{'.' * (30 - filled)}] {done}/{self.total} {self.unit}{note} "
                         f"{rate:,.0f} {self.rate_unit} ETA {eta:5.1f} s failed {failed}")
        sys.stderr.flush()

    def close(self) -> None:
        sys.stderr.write("\n")
        Progress.line_open = False

    @staticmethod
    def end_line() -> None:
        """End the line of a bar left unfinished (by an interrupt), so that a message starts on its own."""
        if Progress.line_open:
            sys.stderr.write("\n")
            Progress.line_open = False
