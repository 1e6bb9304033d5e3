"""Planar motions on torch batches, the two pair augmentations and the geometric-invariance loss.

Planar motion ``(dx, dz, dyaw)`` as :mod:`odolab.core.geometry` defines it: in the previous frame, x right,
z forward (m), yaw positive to the left (rad). As an SE(2) element acting on (x, z):
R(dyaw) = [[cos, -sin], [sin, cos]], so composing a then b gives p = p_a + R(yaw_a) p_b,
yaw = yaw_a + yaw_b.
"""

from __future__ import annotations

import numpy as np
import torch

from odolab.api import Action

#: The action a pair becomes when its frames are swapped or the pair is mirrored (turns swap; a
#: forward step stays forward under the mirror, and has no counterpart when swapped).
OPPOSITE_TURN = {
    Action.TURN_LEFT: Action.TURN_RIGHT,
    Action.TURN_RIGHT: Action.TURN_LEFT,
    Action.MOVE_FORWARD: Action.MOVE_FORWARD,
}


def rotate(yaw: torch.Tensor, p: torch.Tensor) -> torch.Tensor:
    """R(yaw) applied to (.., 2) points (x, z)."""
    c, s = torch.cos(yaw), torch.sin(yaw)
    return torch.stack([c * p[..., 0] - s * p[..., 1], s * p[..., 0] + c * p[..., 1]], dim=-1)


def compose(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(.., 3) planar motions: a followed by b (yaw not wrapped)."""
    return torch.cat([a[..., :2] + rotate(a[..., 2], b[..., :2]), (a[..., 2] + b[..., 2])[..., None]], dim=-1)


def inverse(a: torch.Tensor) -> torch.Tensor:
    """(.., 3) planar motions inverted: compose(a, inverse(a)) = 0."""
    return torch.cat([-rotate(-a[..., 2], a[..., :2]), -a[..., 2:3]], dim=-1)


def mirror(a: torch.Tensor) -> torch.Tensor:
    """The motion seen in a left-right mirrored world: dx and dyaw negated."""
    return a * torch.tensor([-1.0, 1.0, -1.0], dtype=a.dtype, device=a.device)


def geoinv_loss(ab: torch.Tensor, ba: torch.Tensor) -> torch.Tensor:
    """Mean over the batch of (dyaw_ab + dyaw_ba)^2 + ||p_ab + R(dyaw_ab) p_ba||^2: zero exactly when
    the prediction for the swapped pair is the inverse of the prediction for the pair."""
    rot = (ab[:, 2] + ba[:, 2]) ** 2
    trans = (ab[:, :2] + rotate(ab[:, 2], ba[:, :2])).pow(2).sum(dim=1)
    return (rot + trans).mean()


def swap_action(values: np.ndarray) -> np.ndarray:
    """Action values after a frame swap or a mirror (:data:`OPPOSITE_TURN`)."""
    table = {a.value: b.value for a, b in OPPOSITE_TURN.items()}
    return np.array([table[int(v)] for v in values], np.int64)
