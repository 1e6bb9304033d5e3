"""Calibrate the covariances of fusion inputs on held-out episodes, or check a calibration.

    python -m odolab.fusion.calibrate --odometers action-prior,icp,open3d-rgbd,robust-vo,planar-depth \
        --split val --episodes 20 --max-steps 100 --out odolab/data/fusion/calibration.json   # the shipped one
    python -m odolab.fusion.calibrate --check odolab/data/fusion/calibration.json --split test --episodes 20

Runs each odometer on the same episodes (generated as Ray tasks, cached like ``compare``'s),
takes its valid raw steps against the true motions and fits :mod:`odolab.fusion.calibration`;
``--check`` instead prints, per input and action, the share of bias-corrected steps inside the
calibrated 95 % ellipsoid (0.95 when the calibration carries over). Steps whose previous view's
median depth is below ``--near-depth`` (1 m) are fitted apart, as ``<action>@near`` entries
(:mod:`odolab.fusion.calibration`). ``action-prior`` must be calibrated: fusion
falls back on it. An action with fewer than 10 valid steps is left out (fusion then uses the input's
largest sigmas for it), and the summary says so. An oracle input (one reading ground truth) is
calibrated like any other, and named as one: a fused odometer using it is an oracle too.
``--out`` is replaced if it exists.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from odolab.config import SEED_RANGE, check, setting
from odolab.core.types import MOTION_ACTIONS, Action
from odolab.fusion.calibration import MAX_NEAR_DEPTH, Calibration, debiased, ellipsoid_share, view_is_near
from odolab.fusion.graph import residual, right_covariance
from odolab.running.runner import failure_reason
from odolab.sim.episodes import EpisodeSpec
from odolab.sim.scenes import MAX_EPISODE_STEPS


@dataclass(frozen=True)
class CalibrationRun:
    """What a calibration is fitted on: the first ``episodes`` of a split from ``seed``, at most
    ``max_steps`` steps each, steps whose previous view's median depth is below ``near_depth`` (m)
    fitted apart (0: none)."""

    near_depth: float = setting(
        1.0,
        range=(0.0, MAX_NEAR_DEPTH),
        doc="views whose median depth is below this many metres get their own entries (0: none)",
    )
    episodes: int = setting(20, range=(1, 10_000), doc="episodes")
    max_steps: int = setting(100, range=(1, MAX_EPISODE_STEPS), doc="steps per episode")
    seed: int = setting(0, range=SEED_RANGE, doc="episode seed")

    def __post_init__(self) -> None:
        check(self)

    def specs(self, split: str) -> list[EpisodeSpec]:
        """The episodes of ``split``."""
        return [
            EpisodeSpec(split=split, index=i, seed=self.seed, max_steps=self.max_steps) for i in range(self.episodes)
        ]


def near_views(episodes, near_depth: float) -> dict[str, np.ndarray]:
    """Per episode name: (N,) bool, whether each step's previous view is near (:func:`view_is_near`)."""
    return {
        ep.name: np.array([view_is_near(ep[k].depth, near_depth) for k in range(len(ep) - 1)], bool) for ep in episodes
    }


def steps_of(
    results, near: dict[str, np.ndarray]
) -> tuple[np.ndarray, np.ndarray, list[np.ndarray | None], np.ndarray, np.ndarray]:
    """From one odometer's :class:`~odolab.running.runner.SequenceResult` list: residuals (N, 6), action
    values (N,), own covariances (right perturbation), the raw transforms of its valid steps and
    whether each one's view was near (``near``: per sequence name, from :func:`near_views`)."""
    xi, actions, own, Ts, close = [], [], [], [], []
    for r in results:
        for k, est in enumerate(r.raw):
            if est is None or failure_reason(est) is not None or r.truth is None:
                continue
            xi.append(residual(est.transform, r.truth[k]))
            actions.append(int(r.actions[k]))
            own.append(right_covariance(est.transform, est.covariance) if est.covariance is not None else None)
            Ts.append(est.transform)
            close.append(bool(near[r.sequence][k]))
    return (
        np.array(xi).reshape(-1, 6),
        np.array(actions, np.int64),
        own,
        np.array(Ts).reshape(-1, 4, 4),
        np.array(close, bool),
    )


@dataclass(frozen=True)
class EntryCheck:
    """How one calibration entry carries over: ``share`` of the ``steps`` valid bias-corrected steps of
    ``action`` (near views or not) inside its 95 % ellipsoid; ``entry`` the entry used (None: the
    input's largest sigmas)."""

    action: Action
    near: bool
    share: float
    steps: int
    entry: str | None


def check_input(
    cal: Calibration, xi: np.ndarray, actions: np.ndarray, own: Sequence[np.ndarray | None], close: np.ndarray
) -> list[EntryCheck]:
    """One input's calibration ``cal`` checked on its steps (:func:`steps_of`), per action and view."""
    checks = []
    for a in MOTION_ACTIONS:
        for is_near in (False, True):
            rows = np.flatnonzero((actions == a.value) & (close == is_near))
            if not len(rows):
                continue
            covs = np.stack([cal.covariance(a, own[k], is_near) for k in rows])
            share = ellipsoid_share(debiased(xi[rows], cal.bias_of(a, is_near)), covs)
            checks.append(EntryCheck(a, is_near, share, len(rows), cal.label(a, is_near)))
    return checks


if __name__ == "__main__":  # python -m odolab.fusion.calibrate: the command line is odolab.cli.calibrate_fusion's
    import runpy

    runpy.run_module("odolab.cli.calibrate_fusion", run_name="__main__", alter_sys=True)
