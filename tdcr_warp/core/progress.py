"""The progress bar of dynamics, control and sweeps: tqdm on stderr (rates, ETA, terminal width,
throttled redraws), counting rod-units (rod-steps, rods) so that its rate is the one the
commands report, with the failed rods and a note beside it."""

from __future__ import annotations

import sys
import time


class Progress:
    """done/total units of ``rods`` rods each (the bar counts total x rods rod-units), rod-units/s,
    ETA, failed rods. ``start``: units already done before this run (resumed), left out of the
    rate."""

    active: "Progress | None" = None  # the bar on the screen (a message printed now would join its line)

    def __init__(self, total: int, rods: int, rate_unit: str = "rod-steps/s", start: int = 0):
        from tqdm import tqdm  # imported with the first bar: `import tdcr_warp` stays without it

        self.rods = rods
        self.bar = None
        Progress.active = self  # before tqdm draws: an interrupt may come while it does
        self.bar = tqdm(total=total * rods, initial=start * rods, unit=rate_unit.removesuffix("/s"),
                        unit_scale=True, dynamic_ncols=True, mininterval=0.2, smoothing=0.0, leave=True)
        self.bar.set_postfix_str("", refresh=False)
        self.shown = time.perf_counter()

    def update(self, done: int, failed: int, note: str = "") -> None:
        """``done`` units are done, ``failed`` rods have failed; ``note``: what is running."""
        delta = done * self.rods - self.bar.n
        now = time.perf_counter()
        self.bar.set_postfix_str(f"failed {failed}{note}", refresh=False)
        if delta:
            self.bar.update(delta)
        elif now - self.shown >= 0.2:  # news without progress (a chunk started, a step of it)
            self.bar.refresh()
        else:
            return
        self.shown = now

    def close(self) -> None:
        if self.bar is None:  # interrupted while tqdm drew its first line
            sys.stderr.write("\n")
        else:
            self.bar.close()
        if Progress.active is self:
            Progress.active = None

    @staticmethod
    def end_line() -> None:
        """Close an interrupted bar (its line stays, ended), so that a message starts on its own
        line and the bar is not drawn again after it."""
        if Progress.active is not None:
            Progress.active.close()
