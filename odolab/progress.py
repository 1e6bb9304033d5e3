"""A progress bar over odometry steps (tqdm), as a :class:`odolab.runner.RunObserver`."""
from __future__ import annotations

from tqdm.auto import tqdm

__all__ = ["StepProgressBar"]


class StepProgressBar:
    """One tqdm bar over all steps of all odometers; the postfix names the odometer running."""

    def __init__(self, desc: str = "odometry steps", disable: bool = False) -> None:
        self.desc, self.disable = desc, disable
        self._bar: tqdm | None = None

    def start(self, total_steps: int | None) -> None:
        self._bar = tqdm(total=total_steps, desc=self.desc, unit="step", disable=self.disable)

    def advance(self, odometer: str, steps: int) -> None:
        if self._bar is not None:
            self._bar.set_postfix_str(odometer, refresh=False)
            self._bar.update(steps)

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None
