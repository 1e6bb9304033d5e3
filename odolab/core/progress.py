"""A progress bar over odometry steps (tqdm), as a :class:`odolab.running.runner.RunObserver`; on a
terminal that cannot draw one (fewer than :data:`MIN_COLUMNS` columns, or ``TERM=dumb``) a plain
line at the start, at each quarter and at the end instead."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from typing import IO

from tqdm.auto import tqdm

__all__ = ["NAME_WIDTH", "StepProgressBar", "fit_name"]

#: Characters the odometer's name takes in the bar (longer names are cut, shorter ones padded).
NAME_WIDTH = 24
#: Terminals narrower than this get plain lines instead of a bar.
MIN_COLUMNS = 40


def plain_terminal(file: IO[str] | None = None) -> bool:
    """Whether ``file`` (default stderr) is a terminal that cannot draw a bar: fewer than
    :data:`MIN_COLUMNS` columns, or ``TERM=dumb``. Not a terminal (a log file): False, tqdm's lines."""
    stream = file if file is not None else sys.stderr
    try:
        if not stream.isatty():
            return False
        columns = os.get_terminal_size(stream.fileno()).columns
    except (AttributeError, OSError, ValueError):
        return False
    return columns < MIN_COLUMNS or os.environ.get("TERM") == "dumb"


def fit_name(name: str, width: int = NAME_WIDTH) -> str:
    """``name`` padded or cut (ending in "~") to exactly ``width`` characters."""
    return name.ljust(width) if len(name) <= width else name[: width - 1] + "~"


class StepProgressBar:
    """One tqdm bar over all steps of all odometers, laid out so that nothing moves when the
    odometer changes: the description, the step counter and the odometer's name have fixed
    widths, and the rate shown (after the name) is the running odometer's own, its steps over the
    time spent on them. The remaining time comes from the average rate of the whole run."""

    def __init__(
        self,
        desc: str = "odometry steps",
        disable: bool = False,
        file: IO[str] | None = None,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        self.desc, self.disable, self.file, self.clock = desc, disable, file, clock
        self.plain = not disable and plain_terminal(file)
        self._bar: tqdm | None = None
        self._plain_done, self._plain_total, self._plain_said, self._plain_start = 0, None, 0, None
        self._last = 0.0
        self._spent: dict[str, tuple[int, float]] = {}  # odometer -> (steps, seconds)

    def start(self, total_steps: int | None) -> None:
        """Open the bar; ``total_steps`` may be None (unknown)."""
        if self.plain:
            self._last, self._spent = self.clock(), {}
            self._plain_done, self._plain_total, self._plain_said, self._plain_start = 0, total_steps, 0, self._last
            self._say(f"{self.desc}: {'?' if total_steps is None else total_steps} to run")
            return
        if total_steps is None:  # no share or bar to show; the counter gets room for a million steps
            bar_format = "{desc}: {n_fmt:>7} steps [{elapsed:>5}{postfix}]"
        else:
            bar_format = (
                "{desc}: {percentage:3.0f}%|{bar}| {n_fmt:>DIGITS}/{total_fmt} [{elapsed:>5}<{remaining:>5}{postfix}]"
            ).replace("DIGITS", str(len(str(total_steps))))
        self._bar = tqdm(
            total=total_steps,
            desc=self.desc,
            unit="step",
            disable=self.disable,
            file=self.file,
            bar_format=bar_format,
            smoothing=0.0,
            dynamic_ncols=self.file is None,
            postfix=self.postfix(""),
        )
        self._last = self.clock()
        self._spent = {}

    def rate(self, odometer: str) -> float | None:
        """Steps per second of ``odometer`` measured from its own steps, None before any."""
        steps, seconds = self._spent.get(odometer, (0, 0.0))
        return steps / seconds if steps and seconds > 0 else None

    def postfix(self, odometer: str) -> str:
        """The fixed-width text after the counters: the odometer's name and its own rate."""
        rate = self.rate(odometer)
        shown = tqdm.format_sizeof(rate) if rate is not None else "?"
        return f"{fit_name(odometer)} {shown:>5} step/s"

    def advance(self, odometer: str, steps: int, seconds: float | None = None) -> None:
        """``steps`` more steps of ``odometer`` are done, in the time since the previous call or, where
        they ran elsewhere, in their own ``seconds``; 0 steps: ``odometer`` starts a sequence (the
        time before it, e.g. loading, is nobody's)."""
        now = self.clock()
        if steps:
            done, spent = self._spent.get(odometer, (0, 0.0))
            took = max(now - self._last, 0.0) if seconds is None else seconds
            self._spent[odometer] = (done + steps, spent + took)
        self._last = now
        if self.plain and steps:
            self._plain_done += steps
            quarter = 4 * self._plain_done // self._plain_total if self._plain_total else 0
            if 0 < quarter < 4 and quarter > self._plain_said:
                self._plain_said = quarter
                self._say(f"{self.desc}: {self._plain_done}/{self._plain_total} ({25 * quarter} %), {odometer}")
        if self._bar is not None:
            self._bar.set_postfix_str(self.postfix(odometer), refresh=False)
            self._bar.update(steps)

    def _say(self, line: str) -> None:
        print(line, file=self.file if self.file is not None else sys.stderr, flush=True)

    def close(self) -> None:
        """Close the bar (also after an exception)."""
        if self.plain and self._plain_start is not None:
            self._say(f"{self.desc}: {self._plain_done} done in {self.clock() - self._plain_start:.0f} s")
            self._plain_start = None
        if self._bar is not None:
            self._bar.close()
            self._bar = None
