"""Touring routes: an agent going from goal to goal through one large floor plan until it has
travelled a set length, under the episodes' actuation noise, collisions and sensor noise.

An episode is 1-30 m long; KITTI's relative errors need segments of 100-800 m. A route is
``RouteSpec`` -> :func:`tour` (scene, start, then goal after goal: each next goal drawn from the
route's own random stream among the navigable points whose geodesic distance from the agent lies in
``[min_leg, max_leg]``, followed by Habitat's greedy follower with the noisy actuation, exactly as an
episode's rollout; no images) -> :class:`RouteFrames` (the runner's :class:`~odolab.core.types.Sequence`,
rendering each noisy frame when asked: a 400 m route has some 2,500 frames, over 1 GB held at once).
Everything is a pure function of the spec, bit for bit. Four independent random streams
(scene/start/goals, actuation, RGB, depth) are spawned from ``(seed, split, index)`` and a tag of
their own, so a route never shares draws with the episode of the same numbers.
"""

from __future__ import annotations

import hashlib
import json
import math
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from odolab.core.geometry import camera_pose_from_agent
from odolab.core.types import Action, Frame, Intrinsics
from odolab.sim.agent import AgentState
from odolab.sim.camera import CameraSpec
from odolab.sim.environment import PointNavEnv, Sensors
from odolab.sim.episodes import SIMULATOR_VERSION, NoiseConfig
from odolab.sim.noise import ActuationNoise
from odolab.sim.scenes import MAX_EPISODE_STEPS, SPLITS, Scene, generate_scene, scene_seed

__all__ = ["Route", "RouteFrames", "RouteSpec", "route_scene", "tour"]

#: Mixed into the routes' seed sequence: routes and episodes of equal (seed, split, index) draw apart.
_ROUTE_STREAMS = 0x70_0E
#: Bump whenever a route's motion for a given spec changes (goal rule, leg rule).
ROUTE_VERSION = 1
#: Draws of a next goal before a route gives up (the largest component is then nearly all too near or far).
MAX_GOAL_DRAWS = 1000
#: Scenes drawn for a long building before a route gives up: its navigable floor must run (nearly) end to end.
MAX_SCENE_DRAWS = 20
#: The share of a long building's length its largest navigable component must span.
BUILDING_SPAN = 0.95


@dataclass(frozen=True)
class RouteSpec:
    """Everything that determines a touring route. ``index`` numbers routes within (split, seed).

    ``length`` (m): the true path length (the camera's, as KITTI's devkit sums it) at which the
    route ends, at the first step reaching it; ``scene_scale``: the floor plan's linear scale
    (:func:`~odolab.sim.scenes.generate_scene`); ``min_leg``, ``max_leg`` (m): the geodesic
    distance from the agent to each next goal; a leg ends within ``goal_radius`` (m) of its goal, or
    after ``max_leg_steps`` actions (then the next goal is drawn from where the agent stands);
    ``max_steps``: actions at most, a route that has not travelled ``length`` by then is an error.
    ``building`` (m): 0 tours one floor plan (goals anywhere); above 0 the route crosses a long
    building of that length (:func:`~odolab.sim.scenes.generate_scene`'s ``length``, the plan's width
    times ``scene_scale``) from its first end, each next goal ahead of the agent along it, so that
    the route goes somewhere: its segments end far from where they start.
    """

    split: str = "test"
    index: int = 0
    seed: int = 0
    length: float = 400.0
    scene_scale: float = 2.5
    min_leg: float = 5.0
    max_leg: float = 40.0
    goal_radius: float = 0.36
    max_leg_steps: int = MAX_EPISODE_STEPS
    max_steps: int = 20_000
    stop_at_contact: bool = True
    noise: NoiseConfig = field(default_factory=NoiseConfig)
    camera: CameraSpec = field(default_factory=CameraSpec)
    building: float = 0.0

    def __post_init__(self) -> None:
        def refuse(name: str, expected: str) -> None:
            raise ValueError(f"{name}: expected {expected}, got {getattr(self, name)!r}")

        if self.split not in SPLITS:
            refuse("split", f"one of {', '.join(SPLITS)}")
        for name in ("index", "seed", "max_leg_steps", "max_steps"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int) or value < (1 if name.startswith("max") else 0):
                refuse(name, "a whole number >= " + ("1" if name.startswith("max") else "0"))
        for name in ("length", "scene_scale", "min_leg", "max_leg", "goal_radius", "building"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                refuse(name, "a finite number")
        if not self.length > 0:
            refuse("length", "a positive number of metres")
        if not 1.0 <= self.scene_scale <= 10.0:
            refuse("scene_scale", "a number in [1, 10]")
        if not 0 < self.goal_radius < self.min_leg:
            refuse("goal_radius", f"a positive number of metres below min_leg ({self.min_leg:g})")
        if not self.min_leg < self.max_leg:
            refuse("max_leg", f"a number of metres above min_leg ({self.min_leg:g})")
        if self.building != 0 and not (
            20.0 <= self.building <= 2000.0 and self.building >= max(self.length, 4 * self.min_leg)
        ):
            refuse(
                "building",
                f"0 (a floor plan) or a length in [20, 2000] m of at least the route's length ({self.length:g}) "
                f"and 4 x min_leg ({4 * self.min_leg:g})",
            )

    @classmethod
    def from_dict(cls, values: dict[str, Any]) -> RouteSpec:
        """The spec of :func:`dataclasses.asdict` ``values`` (nested ``noise`` and ``camera`` tables)."""
        values = dict(values)
        noise = NoiseConfig(**values.pop("noise", {}))
        camera = CameraSpec(**values.pop("camera", {}))
        return cls(**values, noise=noise, camera=camera)

    def to_dict(self) -> dict[str, Any]:
        """The spec as plain data (:func:`dataclasses.asdict`; :meth:`from_dict` reads it back), with
        ``building`` left out while 0: a floor plan's route is described, and keyed, as before
        buildings existed."""
        spec = asdict(self)
        if not self.building:
            del spec["building"]
        return spec

    @property
    def name(self) -> str:
        """A short label for reports and file names, e.g. ``test-s0-r003``."""
        return f"{self.split}-s{self.seed}-r{self.index:03d}"

    def key(self) -> str:
        """Stable short hash of the spec and of the simulator's version (what its frames depend on)."""
        from odolab.sim.redwood import table_digest

        blob = {"route": ROUTE_VERSION, "sim": SIMULATOR_VERSION, "redwood": table_digest(), **self.to_dict()}
        return hashlib.sha256(json.dumps(blob, sort_keys=True).encode()).hexdigest()[:16]

    def streams(self) -> list[np.random.Generator]:
        """Independent generators for [scene/start/goals, actuation, rgb, depth]."""
        ss = np.random.SeedSequence([int(self.seed), SPLITS.index(self.split), int(self.index), _ROUTE_STREAMS])
        return [np.random.default_rng(s) for s in ss.spawn(4)]


@dataclass(frozen=True)
class Route:
    """The motion of a touring route, without images.

    ``states`` (T + 1) true agent poses (world x, y m, yaw rad); ``actions`` (T,); ``collisions``
    (T,) True where the step's translation was blocked; ``goals`` (world x, y m) in the order they
    were followed, the last one unfinished when the length ran out; ``reached`` how many the agent
    came within the goal radius of; ``length`` (m) the path travelled (camera positions).
    """

    scene_seed: int
    scene_scale: float
    states: list[AgentState]
    actions: list[Action]
    collisions: list[bool]
    goals: list[tuple[float, float]]
    reached: int
    length: float

    def camera_poses(self, mount_height: float) -> np.ndarray:
        """``T_world_cam`` (T + 1, 4, 4) of the states, camera at ``mount_height`` m."""
        return np.stack([camera_pose_from_agent(s.x, s.y, s.yaw, mount_height) for s in self.states])


def _next_goal(
    scene: Scene, cells: np.ndarray, here: AgentState, rng: np.random.Generator, spec: RouteSpec
) -> tuple[float, float]:
    """A navigable cell centre of the largest component (``cells``) whose geodesic distance from
    ``here`` lies in ``[min_leg, max_leg]``: world (x, y) m. In a long building (``spec.building``) only
    cells ahead of the agent along it (x from ``min_leg / 2`` to ``max_leg`` m beyond its own) are drawn."""
    from odolab.sim.planner import geodesic_field

    field_here = geodesic_field(scene, here.x, here.y)
    if spec.building:
        x = scene.cell_to_world(cells[:, 0], cells[:, 1])[0]
        cells = cells[(x >= here.x + spec.min_leg / 2) & (x <= here.x + spec.max_leg)]
        if not len(cells):
            raise RuntimeError(
                f"route {spec.name}: no goal ahead of ({here.x:.2f}, {here.y:.2f}) m: the building "
                f"({spec.building:g} m) is too short for the route's length ({spec.length:g} m)"
            )
    for _ in range(MAX_GOAL_DRAWS):
        gx, gy = (float(v) for v in scene.cell_to_world(*cells[rng.integers(len(cells))]))
        if spec.min_leg <= field_here.at(gx, gy) <= spec.max_leg:
            return gx, gy
    raise RuntimeError(
        f"route {spec.name}: no goal {spec.min_leg:g}-{spec.max_leg:g} m from ({here.x:.2f}, {here.y:.2f}) m "
        f"in scene {scene.seed} (scale {scene.scale:g}) after {MAX_GOAL_DRAWS} draws"
    )


def route_scene(spec: RouteSpec, seed: int) -> Scene:
    """The scene of seed ``seed`` as ``spec`` has it: a long building (``spec.building`` m) or a floor
    plan ``spec.scene_scale`` times an episode's; the route's motion and its frames use this one."""
    return generate_scene(seed, scale=spec.scene_scale, length=spec.building or None)


def tour(spec: RouteSpec) -> Route:
    """The route of ``spec``: scene and start from its first stream, then goal after goal, each
    followed by Habitat's greedy follower with the noisy actuation (its look-ahead drawing from the
    actuation stream, as an episode's rollout does), until the camera has travelled ``spec.length`` m."""
    from odolab.sim.planner import ShortestPathFollower, geodesic_field, largest_component

    rng, act_rng, _, _ = spec.streams()
    for _ in range(MAX_SCENE_DRAWS):  # a floor plan takes the first draw; a building one that runs end to end
        seed = scene_seed(spec.split, int(rng.integers(1 << 31)))
        scene = route_scene(spec, seed)
        cells = np.argwhere(largest_component(scene))
        x = scene.cell_to_world(cells[:, 0], cells[:, 1])[0]
        if not spec.building or np.ptp(x) >= BUILDING_SPAN * spec.building:
            break
    else:
        raise RuntimeError(f"route {spec.name}: no building of {MAX_SCENE_DRAWS} drawn runs end to end")
    starts = cells if not spec.building else cells[x <= x.min() + spec.min_leg]  # a building: from its first end
    sx, sy = (float(v) for v in scene.cell_to_world(*starts[rng.integers(len(starts))]))
    env = PointNavEnv(
        scene,
        AgentState(sx, sy, float(rng.uniform(-np.pi, np.pi))),
        ActuationNoise(spec.noise.controller, spec.noise.actuation),
        act_rng,
        None,
        spec.stop_at_contact,
    )
    states, actions, collisions, goals = [env.state], [], [], []
    travelled, reached = 0.0, 0
    while travelled < spec.length:
        if len(goals) >= spec.max_steps:  # a guard: a leg takes an action at least (min_leg > goal_radius)
            raise RuntimeError(f"route {spec.name}: {len(goals)} goals drawn, {travelled:.1f} m travelled")
        goal = _next_goal(scene, cells, env.state, rng, spec)
        goals.append(goal)
        follower = ShortestPathFollower(
            geodesic_field(scene, *goal),
            goal_radius=spec.goal_radius,
            noise=env.actuation,
            rng=env.act_rng,
            stop_at_contact=spec.stop_at_contact,
        )
        for _ in range(spec.max_leg_steps):
            action = follower.next_action(env.state)
            if action == Action.STOP:
                reached += 1
                break
            before = env.state
            collisions.append(env.step(action))
            states.append(env.state)
            actions.append(action)
            travelled += math.hypot(env.state.x - before.x, env.state.y - before.y)
            if travelled >= spec.length:
                break
            if len(actions) >= spec.max_steps:
                raise RuntimeError(
                    f"route {spec.name}: {travelled:.1f} m travelled in max_steps = {spec.max_steps} actions, "
                    f"short of its length {spec.length:g} m"
                )
    return Route(seed, float(spec.scene_scale), states, actions, collisions, goals, reached, travelled)


class RouteFrames:
    """A route as the runner's :class:`~odolab.core.types.Sequence` of T + 1 noisy frames and T actions.

    Frames are rendered when asked for, in order, from the spec's RGB and depth streams, and only
    the last one is kept: walking forward renders each frame once; asking for an earlier frame
    renders again from the first (the same frames, bit for bit). ``timestamp`` of frame i is i s;
    ``gt_pose`` is ``T_world_cam``.
    """

    def __init__(self, spec: RouteSpec, route: Route) -> None:
        self.spec, self.route = spec, route
        self.intrinsics: Intrinsics = spec.camera.intrinsics
        self._poses = route.camera_poses(spec.camera.mount_height)
        self._scene: Scene | None = None
        self._sensors: Sensors | None = None
        self._next = 0
        self._last: tuple[int, Frame] | None = None

    @property
    def name(self) -> str:
        return self.spec.name

    @property
    def collisions(self) -> np.ndarray:
        return np.array(self.route.collisions, bool)

    def __len__(self) -> int:
        return len(self._poses)

    def __getitem__(self, i: int) -> Frame:
        if not 0 <= i < len(self):
            raise IndexError(f"{self.name}: frame {i} of {len(self)}")
        if self._last is not None and self._last[0] == i:
            return self._last[1]
        if self._sensors is None or i < self._next:  # the noise streams are drawn in order: start again
            if self._scene is None:
                self._scene = route_scene(self.spec, self.route.scene_seed)
            _, _, rgb_rng, depth_rng = self.spec.streams()
            noise, camera = self.spec.noise, self.spec.camera
            self._sensors = Sensors(self._scene, camera, noise.rgb, noise.depth, rgb_rng, depth_rng)
            self._next = 0
        while self._next <= i:
            reading = self._sensors.read(self._poses[self._next])
            self._next += 1
        frame = Frame(
            reading.rgb, reading.depth, timestamp=float(i), gt_pose=self._poses[i], clean_depth=reading.clean_depth
        )
        self._last = (i, frame)
        return frame

    def action(self, i: int) -> Action:
        return self.route.actions[i]

    def gt_pose(self, i: int) -> np.ndarray:
        return self._poses[i]
