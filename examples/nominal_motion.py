"""A complete third-party odometer: it trusts the commanded motion (no noise, no collisions).

Run it side by side with the built-ins, from the repository root:

    python -m odolab.compare --odometers action-prior,examples.nominal_motion:NominalMotion
"""

import numpy as np

from odolab.api import Action, Estimate, Frame, Odometer


class NominalMotion(Odometer):
    """Predicts the commanded motion: 0.25 m forward or a 30 degree turn; without an action (real
    data) it says it cannot tell, and the runner uses its fallback and counts a failure."""

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        if action == Action.MOVE_FORWARD:
            return Estimate.from_planar(0.0, 0.25, 0.0)
        if action in (Action.TURN_LEFT, Action.TURN_RIGHT):
            sign = 1.0 if action == Action.TURN_LEFT else -1.0
            return Estimate.from_planar(0.0, 0.0, sign * np.radians(30.0))
        return Estimate(np.eye(4), valid=False)
