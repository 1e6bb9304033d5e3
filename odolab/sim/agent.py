"""The agent: a 0.18 m-radius cylinder on the scene's occupancy grid, moved by noisy actions.

Collisions do not slide (Habitat PointNav Challenge 2020): if the straight path of a step crosses
a cell where the agent does not fit, the agent stops at contact, as habitat-sim's navmesh step
without sliding does (optionally it stays where it was); against an obstacle, further blocked steps
have ~0 translation, the peak at 0 m in the paper's data. The rotation (with its noise) still
happens.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odolab.core.geometry import wrap_angle
from odolab.core.types import Action
from odolab.sim.noise import ActuationNoise, Motion
from odolab.sim.scenes import Scene


@dataclass(frozen=True)
class AgentState:
    """Planar pose on the floor: world (x, y) metres, heading ``yaw`` rad (CCW from +X)."""

    x: float
    y: float
    yaw: float


def advance(
    scene: Scene, x0: float, y0: float, x1: float, y1: float, stop_at_contact: bool = True, spacing: float = 0.01
) -> tuple[float, float, bool]:
    """Move the agent's centre from (x0, y0) towards (x1, y1) without sliding.

    If the straight path leaves the navigable area anywhere (sampled every ``spacing`` m) the step
    is a collision. With ``stop_at_contact`` (default) the agent stops where the path first leaves
    the navigable area, as habitat-sim's ``PathFinder::tryStep`` without sliding does; otherwise it
    stays at (x0, y0). Stopping at contact puts the agent against obstacles, so that turns collide
    too (through their translation noise), as in the paper's data (Table S2: 12.7 % of left turns
    collided); staying put makes turn collisions rare (2-3 % here).
    Returns the reached (x, y) and whether the step was blocked.
    """
    n = max(2, int(np.ceil(np.hypot(x1 - x0, y1 - y0) / spacing)) + 1)
    s = np.linspace(0.0, 1.0, n)
    free = scene.is_navigable(x0 + s * (x1 - x0), y0 + s * (y1 - y0))
    if free.all():
        return float(x1), float(y1), False
    last = int(np.argmin(free)) - 1  # the last free sample before the first blocked one
    if not stop_at_contact or last < 0:
        return float(x0), float(y0), True
    return float(x0 + s[last] * (x1 - x0)), float(y0 + s[last] * (y1 - y0)), True


def apply_motion(
    scene: Scene, state: AgentState, motion: Motion, stop_at_contact: bool = True
) -> tuple[AgentState, bool]:
    """Execute ``motion``; returns the new state and whether the translation was blocked
    (``stop_at_contact``: see :func:`advance`)."""
    c, s = np.cos(state.yaw), np.sin(state.yaw)
    # forward = (c, s); right = (s, -c) in world XY
    x1 = state.x + motion.forward * c + motion.right * s
    y1 = state.y + motion.forward * s - motion.right * c
    x1, y1, blocked = advance(scene, state.x, state.y, x1, y1, stop_at_contact)
    return AgentState(x1, y1, float(wrap_angle(state.yaw + motion.yaw))), blocked


def step_agent(
    scene: Scene,
    state: AgentState,
    action: Action,
    noise: ActuationNoise,
    rng: np.random.Generator,
    stop_at_contact: bool = True,
) -> tuple[AgentState, bool]:
    """Take ``action`` with a fresh actuation-noise draw; returns (new state, collided)."""
    return apply_motion(scene, state, noise.sample(action, rng), stop_at_contact)
