"""One PointGoal navigation episode, closed loop: the environment renders, the odometer estimates,
the agent decides; the metrics use the true positions.

The odometer is asked under the runner's guards (:class:`odolab.running.runner.StepByStep`): it sees each
frame pair as the runner would show it (read-only copies, ground truth only for oracles), its
attributes are read once, ``reset`` and each step are time-limited; a failed step (invalid, raising,
timed out or not a rigid motion) is replaced by the action prior's mean motion, as in ``compare``.
"""

from __future__ import annotations

import contextlib
import time
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from odolab.core.geometry import planar_to_transform
from odolab.core.types import Action
from odolab.navigation.agent import MapPlanAgent, PolicyConfig, in_agent_frame
from odolab.navigation.metrics import EpisodeOutcome, path_length
from odolab.odometry.action_prior import ActionPrior
from odolab.odometry.odometer import Odometer
from odolab.running.runner import DEFAULT_STEP_TIMEOUT, StepByStep
from odolab.sim.episodes import EpisodeSpec, start_environment
from odolab.sim.planner import geodesic_field


@dataclass(frozen=True)
class NavigationRun:
    """What happened: the metrics' inputs, the true and believed positions (world x, y m; the
    belief mapped into the world through the true start pose), the goal (world), the actions, the
    failed steps and the first few failures' messages."""

    spec: EpisodeSpec
    outcome: EpisodeOutcome
    true_xy: np.ndarray
    believed_xy: np.ndarray
    goal: tuple[float, float]
    actions: np.ndarray
    failed_steps: int
    errors: tuple[str, ...] = ()  # the first few failures' messages (what raised or timed out, and where)


def navigate(
    spec: EpisodeSpec,
    odometer: Odometer,
    policy: PolicyConfig | None = None,
    prior: ActionPrior | None = None,
    timings: dict[str, float] | None = None,
    step_timeout: float | None = DEFAULT_STEP_TIMEOUT,
) -> NavigationRun:
    """Run one episode of ``spec`` (its scene, start, goal, noise; at most ``spec.max_steps``
    actions) with ``odometer`` as the agent's only sense of its own motion. ``timings``, when given,
    is added to: wall seconds in the ``policy`` (of which ``planning``, its fast marching), the
    ``sensors`` (moving and rendering), the ``odometer``, and the ``steps`` taken. ``step_timeout``:
    seconds the odometer's ``reset`` or one step may take (None: no limit)."""
    clock = _Clock(timings)
    prior = prior or ActionPrior.shipped()
    env, begin = start_environment(spec)
    field = geodesic_field(env.scene, *begin.goal)
    cam = spec.camera
    goal = in_agent_frame(begin.goal, begin.start.x, begin.start.y, begin.start.yaw)  # the point-goal sensor's reading
    agent = MapPlanAgent(tuple(goal), cam.intrinsics, cam.mount_height, policy)
    true_xy, believed_xy, actions = [(env.state.x, env.state.y)], [(0.0, 0.0)], []
    stopped, failed, errors = False, 0, []
    with StepByStep(odometer, "navigation", step_timeout) as asked:
        asked.reset(cam.intrinsics)
        frame = env.observe(0.0)
        seen = asked.frame(frame)  # each frame guarded once: odometers reuse per-frame work by identity
        for t in range(spec.max_steps):
            with clock("policy"):
                action = agent.act(frame.depth)
            if action is Action.STOP:
                stopped = True
                break
            with clock("sensors"):
                env.step(action)
                new = env.observe(float(t + 1))
            new_seen = asked.frame(new)
            with clock("odometer"):
                est = asked.step(seen, new_seen, action)
            if est is None:
                failed += 1
            agent.update(planar_to_transform(*prior.motion(action)) if est is None else est.transform)
            frame, seen = new, new_seen
            actions.append(action.value)
            true_xy.append((env.state.x, env.state.y))
            believed_xy.append(agent.belief[:2])
        errors = [*asked.errors, *(f"{n} step(s) {r}" for r, n in sorted(asked.reasons.items()) if r != "raised")]
    clock.add("planning", agent.plan_seconds)
    clock.add("steps", len(actions))
    true = np.array(true_xy)
    c, s = np.cos(begin.start.yaw), np.sin(begin.start.yaw)
    b = np.array(believed_xy)
    believed = np.stack([begin.start.x + c * b[:, 0] - s * b[:, 1], begin.start.y + s * b[:, 0] + c * b[:, 1]], axis=1)
    outcome = EpisodeOutcome(
        d0=begin.start_distance,
        d_end=field.at(env.state.x, env.state.y),
        path=path_length(true),
        stopped=stopped,
        steps=len(actions),
        collisions=env.collisions,
    )
    return NavigationRun(spec, outcome, true, believed, begin.goal, np.array(actions, np.int8), failed, tuple(errors))


class _Clock:
    """Adds wall seconds per part to a dict (or does nothing without one): ``with clock("policy"):``."""

    def __init__(self, totals: dict[str, float] | None) -> None:
        self.totals = totals

    def add(self, part: str, amount: float) -> None:
        if self.totals is not None:
            self.totals[part] = self.totals.get(part, 0.0) + amount

    @contextlib.contextmanager
    def __call__(self, part: str) -> Iterator[None]:
        started = time.perf_counter()
        try:
            yield
        finally:
            self.add(part, time.perf_counter() - started)
