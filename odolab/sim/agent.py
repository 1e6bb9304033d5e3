"""The agent: a 0.18 m-radius cylinder on the scene's occupancy grid, moved by noisy actions.

Collisions do not slide (Habitat PointNav Challenge 2020): if the straight path of a step crosses
a cell where the agent does not fit, its position stays where it was; the rotation (with its
noise) still happens.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from odolab.geometry import wrap_angle
from odolab.types import Action
from odolab.sim.noise import ActuationNoise, Motion
from odolab.sim.scenes import Scene


@dataclass(frozen=True)
class AgentState:
    """Planar pose on the floor: world (x, y) metres, heading ``yaw`` rad (CCW from +X)."""

    x: float
    y: float
    yaw: float


def path_is_free(scene: Scene, x0: float, y0: float, x1: float, y1: float, spacing: float = 0.02) -> bool:
    """True if every point of the segment (sampled every ``spacing`` m) is navigable."""
    n = max(2, int(np.ceil(np.hypot(x1 - x0, y1 - y0) / spacing)) + 1)
    s = np.linspace(0.0, 1.0, n)
    return bool(np.all(scene.is_navigable(x0 + s * (x1 - x0), y0 + s * (y1 - y0))))


def apply_motion(scene: Scene, state: AgentState, motion: Motion) -> tuple[AgentState, bool]:
    """Execute ``motion``; returns the new state and whether the translation was blocked."""
    c, s = np.cos(state.yaw), np.sin(state.yaw)
    # forward = (c, s); right = (s, -c) in world XY
    x1 = state.x + motion.forward * c + motion.right * s
    y1 = state.y + motion.forward * s - motion.right * c
    blocked = not path_is_free(scene, state.x, state.y, x1, y1)
    if blocked:
        x1, y1 = state.x, state.y
    return AgentState(float(x1), float(y1), float(wrap_angle(state.yaw + motion.yaw))), blocked


def step_agent(scene: Scene, state: AgentState, action: Action, noise: ActuationNoise,
               rng: np.random.Generator) -> tuple[AgentState, bool]:
    """Take ``action`` with a fresh actuation-noise draw; returns (new state, collided)."""
    return apply_motion(scene, state, noise.sample(action, rng))
