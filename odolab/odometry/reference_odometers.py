"""Two reference odometers that bracket every real one.

* ``ground-truth``: the true motion from the frames' ``gt_pose`` (zero error; an oracle).
* ``action-prior``: the mean motion of the action taken, fitted on the train split (the paper's
  ``sys_error`` row); identity when no action is known (real data).
"""

from __future__ import annotations

from odolab.core.geometry import invert
from odolab.core.types import Action, Estimate, Frame
from odolab.odometry.action_prior import ActionPrior
from odolab.odometry.odometer import Odometer


class GroundTruthOdometer(Odometer):
    """True ``T_prev_cur`` from ``Frame.gt_pose``; needs ground truth."""

    oracle = True

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        if prev.gt_pose is None or cur.gt_pose is None:
            raise ValueError("ground-truth odometer: frames carry no gt_pose")
        return Estimate(invert(prev.gt_pose) @ cur.gt_pose)


class ActionPriorOdometer(Odometer):
    """Predicts the train-split mean motion of the action (see :mod:`odolab.odometry.action_prior`)."""

    def __init__(self, prior: ActionPrior | str | None = None) -> None:
        """``prior``: a table, the path of one written by ``python -m odolab.action_prior``, or None
        (or "") for the shipped one."""
        if isinstance(prior, str):
            prior = ActionPrior.load(prior) if prior else None
        elif prior is not None and not isinstance(prior, ActionPrior):
            raise ValueError(f"prior must be the path of an action prior file, got {prior!r}")
        self.prior = prior if prior is not None else ActionPrior.shipped()

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        return Estimate.from_planar(*self.prior.motion(action))
