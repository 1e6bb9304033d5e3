"""Episodes: an agent following the shortest path to a goal under noise, with its RGB-D frames.

``EpisodeSpec`` -> (``rollout``: scene, start, goal, noisy motion) -> (``render``: noisy frames)
-> ``Episode``. Everything is a pure function of the spec: same spec, same episode, bit for bit.
Three independent random streams (scene/start/goal, actuation, sensors) are spawned from
``(seed, split, index)``, so changing the sensor noise leaves the path unchanged.

Episodes are cached as ``.npz`` files (atomic writes, loaded without pickle) by
:class:`EpisodeCache`; :func:`load_episodes` generates the missing ones as parallel tasks.
"""

from __future__ import annotations

import errno
import hashlib
import json
import os
import re
import sys
import zipfile
import zlib
from collections.abc import Callable, Iterator
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from odolab.config import SEED_RANGE, check, setting
from odolab.core.errors import InputError
from odolab.core.geometry import camera_pose_from_agent
from odolab.core.parallel import Execution, fan_out
from odolab.core.types import Action, Frame, Intrinsics
from odolab.io.atomic import atomic_open, remove_stale_temporaries
from odolab.sim.agent import AgentState
from odolab.sim.camera import CameraSpec
from odolab.sim.environment import PointNavEnv, Sensors
from odolab.sim.free_scenes import FAMILIES, family_scene
from odolab.sim.mesh_scenes import SceneFiles
from odolab.sim.noise import ActuationNoise
from odolab.sim.scenes import MIN_GOAL_DISTANCE, SPLITS, scene_seed

_SPLIT_CODE = {name: i for i, name in enumerate(SPLITS)}
FORMAT_VERSION = 2  # the .npz layout (2: clean_depth_mm added)
#: Bump whenever the simulator's output for a given spec changes (scenes, rendering, noise, motion,
#: follower): it is part of every cache key, so stale cached episodes are never reused.
SIMULATOR_VERSION = 4
#: What reading a damaged cache file raises (truncated zip, bad CRC, bad header, short read; an
#: ``info`` that is not a JSON object, or is nested too deeply to read).
_DAMAGE = (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error, RecursionError, AttributeError)


@dataclass(frozen=True)
class NoiseConfig:
    """Noise multipliers (0 = noiseless): RGB (sigma 0.1 x rgb), Redwood depth, PyRobot actuation."""

    rgb: float = setting(1.0, range=(0.0, 10.0), doc="RGB noise multiplier (sigma 0.1 x rgb; 0: none)")
    depth: float = setting(1.0, range=(0.0, 10.0), doc="Redwood depth noise multiplier (0: none)")
    actuation: float = setting(0.5, range=(0.0, 10.0), doc="PyRobot actuation noise multiplier (the challenge: 0.5)")
    controller: Literal["ilqr", "proportional", "movebase"] = setting(
        "proportional", doc="PyRobot controller whose actuation noise is drawn"
    )

    def __post_init__(self) -> None:
        check(self, "noise: ")


@dataclass(frozen=True)
class EpisodeSpec:
    """Everything that determines an episode. ``index`` numbers episodes within (split, seed)."""

    split: str = setting("test", doc=f"the scene pool: one of {', '.join(SPLITS)}")
    index: int = setting(0, range=(0, 2**31 - 1), doc="the episode's number within (split, seed)")
    seed: int = setting(0, range=SEED_RANGE, doc="the episodes' seed")
    max_steps: int = setting(100, range=(1, 100_000), doc="actions at most")
    min_goal_distance: float = setting(
        MIN_GOAL_DISTANCE, range=(0.0, 1000.0), doc="m, geodesic (habitat-lab's generator: 1-30 m)"
    )
    max_goal_distance: float = setting(30.0, range=(0.0, 1000.0), doc="m, geodesic")
    min_geodesic_ratio: float = setting(
        1.1, range=(1.0, 100.0), doc="geodesic / euclidean below this is mostly rejected (as habitat-lab)"
    )
    goal_radius: float = setting(
        0.36, range=(0.0, 10.0), doc="m: the follower calls STOP within this geodesic distance (PointNav success)"
    )
    stop_at_contact: bool = setting(True, doc="blocked steps stop at contact (habitat-sim) or, if False, stay put")
    noise: NoiseConfig = setting(default_factory=NoiseConfig, doc="noise multipliers")
    camera: CameraSpec = setting(default_factory=CameraSpec, doc="the camera")
    scenes: SceneFiles | None = setting(None, doc="mesh files (odolab.sim.mesh_scenes); None: procedural scenes")
    family: str = setting(
        "boxes", doc=f"procedural scene family: one of {', '.join(FAMILIES)} (odolab.sim.free_scenes)"
    )

    def __post_init__(self) -> None:
        if self.split not in SPLITS:
            raise ValueError(f"unknown split {self.split!r}; expected one of {', '.join(SPLITS)}")
        if self.family not in FAMILIES:
            raise ValueError(f"family: expected one of {', '.join(FAMILIES)}, got {self.family!r:.40}")
        if self.scenes is not None and self.family != "boxes":
            raise ValueError(f"family {self.family!r} is a procedural scene family; mesh scenes have none")
        check(self)
        if self.min_goal_distance > self.max_goal_distance:
            raise ValueError(
                f"min_goal_distance must be at most max_goal_distance ({self.max_goal_distance:g}), got {self.min_goal_distance:g}"
            )

    def record(self) -> dict:
        """The spec as plain data, what keys and saved results hold: its fields, with mesh ``scenes``
        as their digests and reading settings (not their paths), and without them for the procedural
        scenes; ``family`` only when not ``boxes`` (so the boxes' records are what they were before
        mesh scenes and families)."""
        fields = asdict(self)
        if self.family == "boxes":
            del fields["family"]
        if self.scenes is None:
            del fields["scenes"]
        else:
            fields["scenes"] = self.scenes.identity()
        return fields

    def key(self) -> str:
        """Stable short hash of the spec (the cache file name)."""
        from odolab.sim.redwood import table_digest

        blob = json.dumps(
            {"v": FORMAT_VERSION, "sim": SIMULATOR_VERSION, "redwood": table_digest(), **self.record()}, sort_keys=True
        )
        return hashlib.sha256(blob.encode()).hexdigest()[:16]

    def streams(self) -> list[np.random.Generator]:
        """Independent generators for [scene/start/goal, actuation, rgb, depth]."""
        ss = np.random.SeedSequence([int(self.seed), _SPLIT_CODE[self.split], int(self.index)])
        return [np.random.default_rng(s) for s in ss.spawn(4)]


@dataclass(frozen=True)
class Rollout:
    """The motion of an episode, without images.

    ``states`` (T + 1) agent poses; ``actions`` (T,) the action taken after each state except the
    last; ``collisions`` (T,) True where the step's translation was blocked.
    """

    scene_seed: int
    goal: tuple[float, float]
    start_distance: float  # geodesic, m
    euclidean_distance: float  # m, start to goal
    states: list[AgentState]
    actions: list[Action]
    collisions: list[bool]
    reached_goal: bool

    def camera_poses(self, mount_height: float) -> np.ndarray:
        """``T_world_cam`` (T + 1, 4, 4) of the states, camera at ``mount_height`` m."""
        return np.stack([camera_pose_from_agent(s.x, s.y, s.yaw, mount_height) for s in self.states])


def straight_episode_keep_rate(ratio: float) -> float:
    """habitat-lab's chance of keeping an episode whose geodesic / euclidean ratio is below the
    threshold: ``20 (ratio - 0.98)^2`` (0.008 at 1.0, 0.144 at 1.1)."""
    return 20.0 * (ratio - 0.98) ** 2


def sample_start_goal(
    spec: EpisodeSpec, scene, rng: np.random.Generator, max_tries: int = 200, name: str | None = None
):
    """A start and goal as habitat-lab's PointNav generator picks them: a navigable start on the
    largest island, up to 10 navigable goals tried per start; a goal is kept when its geodesic
    distance is within [min, max] and, if geodesic / euclidean < ``min_geodesic_ratio``, only with
    probability :func:`straight_episode_keep_rate`. Returns (start xy, goal xy, geodesic m);
    :class:`NoEpisodeError` naming the scene (``name``, e.g. its mesh file; else its seed) where
    ``max_tries`` starts find no goal."""
    from odolab.sim.planner import geodesic_field, largest_component

    cells = np.argwhere(largest_component(scene))
    for _attempt in range(max_tries):
        sx, sy = (float(v) for v in scene.cell_to_world(*cells[rng.integers(len(cells))]))
        field = geodesic_field(scene, sx, sy)
        for _target in range(10):
            gx, gy = (float(v) for v in scene.cell_to_world(*cells[rng.integers(len(cells))]))
            geo = field.at(gx, gy)
            euclid = float(np.hypot(gx - sx, gy - sy))
            if not (spec.min_goal_distance <= geo <= spec.max_goal_distance) or euclid <= 0:
                continue
            ratio = geo / euclid
            if ratio < spec.min_geodesic_ratio and rng.random() > straight_episode_keep_rate(ratio):
                continue
            return (sx, sy), (gx, gy), geo
    raise NoEpisodeError(
        f"no start and goal {spec.min_goal_distance:g}-{spec.max_goal_distance:g} m apart (geodesic) found on its "
        f"largest navigable floor in {max_tries} random starts; a larger floor is needed",
        joiner=": ",
        subject=name or f"scene {scene.seed}",
    )


class NoEpisodeError(InputError):
    """A scene where no episode's start and goal could be drawn (``subject``: the scene, or its
    mesh file); a command says it in one line."""

    def __reduce__(self):
        """Pickled (back from a Ray task) as made: its problem, joiner and subject."""
        return (type(self), (self.problem, self.joiner, self.subject))


@dataclass(frozen=True)
class EpisodeStart:
    """Where an episode begins: its scene, the agent's start state, the goal (world x, y m) and
    the geodesic and straight-line distances between them (m)."""

    scene_seed: int
    start: AgentState
    goal: tuple[float, float]
    start_distance: float
    euclidean_distance: float


def scene_of(spec: EpisodeSpec, seed: int):
    """The scene an episode of ``spec`` runs in: the procedural scene of ``seed`` in the spec's
    family, or, with mesh ``scenes``, the file ``seed`` picks
    (:meth:`odolab.sim.mesh_scenes.SceneFiles.scene`)."""
    return family_scene(seed, spec.family) if spec.scenes is None else spec.scenes.scene(seed)


def start_environment(spec: EpisodeSpec, sensors: bool = True) -> tuple[PointNavEnv, EpisodeStart]:
    """The environment of an episode at its start: scene, start and goal sampled from the spec's
    first stream, actuation noise from the second, sensors (if ``sensors``) from the third and
    fourth. Driven as :func:`rollout` drives it (its follower's look-ahead draws from the actuation
    stream too), it sees the stored episode's frames exactly; another policy gets other noise draws
    from the same laws."""
    rng, act_rng, rgb_rng, depth_rng = spec.streams()
    draw = int(rng.integers(1 << 31))
    seed = draw if spec.scenes is not None else scene_seed(spec.split, draw)
    scene = scene_of(spec, seed)
    name = None if spec.scenes is None else spec.scenes.file(seed)  # a mesh scene: named by its file
    (sx, sy), (gx, gy), geo = sample_start_goal(spec, scene, rng, name=name)
    start = AgentState(sx, sy, float(rng.uniform(-np.pi, np.pi)))
    seeing = Sensors(scene, spec.camera, spec.noise.rgb, spec.noise.depth, rgb_rng, depth_rng) if sensors else None
    env = PointNavEnv(
        scene, start, ActuationNoise(spec.noise.controller, spec.noise.actuation), act_rng, seeing, spec.stop_at_contact
    )
    return env, EpisodeStart(seed, start, (gx, gy), geo, float(np.hypot(gx - sx, gy - sy)))


def rollout(spec: EpisodeSpec) -> Rollout:
    """Sample scene, start and goal, and follow the shortest path under actuation noise."""
    from odolab.sim.planner import ShortestPathFollower, geodesic_field

    env, begin = start_environment(spec, sensors=False)
    follower = ShortestPathFollower(
        geodesic_field(env.scene, *begin.goal),
        goal_radius=spec.goal_radius,
        noise=env.actuation,
        rng=env.act_rng,
        stop_at_contact=spec.stop_at_contact,
    )
    states, actions, collisions = [env.state], [], []
    reached = False
    for _ in range(spec.max_steps):
        action = follower.next_action(env.state)
        if action == Action.STOP:
            reached = True
            break
        collisions.append(env.step(action))
        states.append(env.state)
        actions.append(action)
    return Rollout(
        begin.scene_seed,
        begin.goal,
        begin.start_distance,
        begin.euclidean_distance,
        states,
        actions,
        collisions,
        reached,
    )


@dataclass(frozen=True)
class Episode:
    """A rendered episode; a :class:`~odolab.core.types.Sequence` of T + 1 frames and T actions.

    ``rgb`` (T+1, H, W, 3) uint8; ``depth`` (T+1, H, W) float32 m (0 = no reading);
    ``poses`` (T+1, 4, 4) ``T_world_cam``; ``actions`` (T,) int8 :class:`Action` values;
    ``collisions`` (T,) bool; ``info``: scene seed, goal, start distance, reached_goal;
    ``clean_depth_mm`` (T+1, H, W) uint16: the simulator's noiseless depth in millimetres (0 = no
    reading), handed to oracles as ``Frame.clean_depth`` (m), or None.
    """

    spec: EpisodeSpec
    rgb: np.ndarray
    depth: np.ndarray
    poses: np.ndarray
    actions: np.ndarray
    collisions: np.ndarray
    info: dict
    clean_depth_mm: np.ndarray | None = None

    @property
    def intrinsics(self) -> Intrinsics:
        return self.spec.camera.intrinsics

    @property
    def name(self) -> str:
        return f"{self.spec.split}-s{self.spec.seed}-e{self.spec.index:03d}"

    def __len__(self) -> int:
        return len(self.rgb)

    def __getitem__(self, i: int) -> Frame:
        clean = None if self.clean_depth_mm is None else self.clean_depth_mm[i] * np.float32(0.001)
        return Frame(self.rgb[i], self.depth[i], timestamp=float(i), gt_pose=self.poses[i], clean_depth=clean)

    def action(self, i: int) -> Action:
        return Action(int(self.actions[i]))

    def gt_pose(self, i: int) -> np.ndarray:
        return self.poses[i]


def render_frames(
    spec: EpisodeSpec, motion: Rollout
) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]]:
    """``(clean rgb, clean depth, noisy rgb, noisy depth)`` of each state of ``motion``, in order,
    with the sensor noise of ``spec`` drawn from its own streams (so any consumer sees the same frames)."""
    _, _, rgb_rng, depth_rng = spec.streams()
    cam = spec.camera
    sensors = Sensors(scene_of(spec, motion.scene_seed), cam, spec.noise.rgb, spec.noise.depth, rgb_rng, depth_rng)
    for pose in motion.camera_poses(cam.mount_height):
        r = sensors.read(pose)
        yield r.clean_rgb, r.clean_depth, r.rgb, r.depth


def render_episode(spec: EpisodeSpec, motion: Rollout | None = None) -> Episode:
    """Render the (noisy) frames of an episode; ``motion`` defaults to ``rollout(spec)``."""
    motion = motion or rollout(spec)
    cam = spec.camera
    n = len(motion.states)
    rgb = np.empty((n, cam.height, cam.width, 3), np.uint8)
    depth = np.empty((n, cam.height, cam.width), np.float32)
    clean_mm = np.empty((n, cam.height, cam.width), np.uint16)
    for i, (_, clean_depth, noisy_rgb, noisy_depth) in enumerate(render_frames(spec, motion)):
        rgb[i], depth[i] = noisy_rgb, noisy_depth
        clean_mm[i] = np.round(clean_depth * 1000.0).clip(0, 65535)
    info = {
        "scene_seed": motion.scene_seed,
        "goal": list(motion.goal),
        "start_distance": motion.start_distance,
        "euclidean_distance": motion.euclidean_distance,
        "reached_goal": motion.reached_goal,
    }
    return Episode(
        spec,
        rgb,
        depth,
        motion.camera_poses(cam.mount_height),
        np.array([a.value for a in motion.actions], np.int8),
        np.array(motion.collisions, bool),
        info,
        clean_mm,
    )


#: The temporary files of :meth:`EpisodeCache.put` (``.<spec key>.npz.<random>.tmp``): a killed
#: write leaves one, which a later write removes once no live writer holds it.
CACHE_TEMPORARY = re.compile(r"\.[0-9a-f]{16}\.npz\.[A-Za-z0-9_]+\.tmp")


def _on_stderr(line: str) -> None:
    print(line, file=sys.stderr)


#: Write errors of the whole cache, not of one entry: said without the entry's name, so that the
#: processes that each meet it (Ray tasks) say the same line, which the driver says once.
_WHOLE_CACHE = frozenset({errno.ENOSPC, errno.EROFS, errno.EACCES, errno.EPERM, errno.EDQUOT})


class EpisodeCache:
    """Episodes on disk under ``root``, one ``<spec key>.npz`` each (atomic writes, no pickle).

    A damaged entry (truncated, bad CRC, unreadable) is named in one line on stderr, deleted and
    reported missing, so it is regenerated; it never ends a run. Only regular files are read, and
    only regular files inside ``root`` are written: a symbolic link in an entry's place is replaced,
    never written through. A write that fails (a full disk, a read-only cache) is said once in one
    line on stderr and the episode is kept in memory instead, so the run goes on with its results;
    a read-only cache that holds every episode is simply read. The first write removes the
    temporary files that killed writers left (:data:`CACHE_TEMPORARY`).
    """

    def __init__(self, root: str | os.PathLike, say: Callable[[str], None] | None = None) -> None:
        """``say``: where its one-line notices go (default: standard error)."""
        self.root = Path(root)
        self._say = say or _on_stderr
        self._unwritten: dict[str, Episode] = {}  # spec key -> episode that could not be written
        self._write_failed = False
        self._swept = False

    def path(self, spec: EpisodeSpec) -> Path:
        return self.root / f"{spec.key()}.npz"

    def _discard(self, path: Path, exc: BaseException) -> None:
        """Name a damaged entry on stderr and delete it."""
        self._say(f"odolab: episode cache entry {path} is damaged ({type(exc).__name__}: {exc}); regenerating it")
        try:
            path.unlink(missing_ok=True)
        except OSError:  # e.g. a folder in its place, or a read-only cache: put() will then say so
            pass

    def _readable(self, spec: EpisodeSpec) -> Path | None:
        """The entry of ``spec`` if it is a regular file (links followed); None when missing, or a
        folder, pipe or device (never opened: a pipe would block the read)."""
        p = self.path(spec)
        return p if p.is_file() else None

    def get(self, spec: EpisodeSpec) -> Episode | None:
        """The cached episode of ``spec``, or None (missing, or damaged: then discarded)."""
        if spec.key() in self._unwritten:
            return self._unwritten[spec.key()]
        p = self._readable(spec)
        if p is None:
            return None
        try:
            with np.load(p, allow_pickle=False) as z:
                info = json.loads(str(z["info"]))
                if info.pop("spec_key", None) != spec.key():
                    return None
                clean = z["clean_depth_mm"] if "clean_depth_mm" in z.files else None
                return Episode(spec, z["rgb"], z["depth"], z["poses"], z["actions"], z["collisions"], info, clean)
        except _DAMAGE as exc:
            self._discard(p, exc)
            return None

    def has(self, spec: EpisodeSpec) -> bool:
        """True if a readable file for ``spec`` is cached (reads its small ``info`` member only; a
        damaged file is discarded), or this cache kept the episode in memory (its write failed)."""
        if spec.key() in self._unwritten:
            return True
        p = self._readable(spec)
        if p is None:
            return False
        try:
            with np.load(p, allow_pickle=False) as z:
                return json.loads(str(z["info"])).get("spec_key") == spec.key()
        except _DAMAGE as exc:
            self._discard(p, exc)
            return False

    def steps(self, spec: EpisodeSpec) -> int:
        """Number of steps of the cached episode of ``spec`` (reads only its actions); for a
        missing or damaged file (a damaged one is discarded), ``spec.max_steps`` (an upper bound)."""
        if spec.key() in self._unwritten:
            return len(self._unwritten[spec.key()].actions)
        p = self._readable(spec)
        if p is None:
            return spec.max_steps
        try:
            with np.load(p, allow_pickle=False) as z:
                return len(z["actions"])
        except _DAMAGE as exc:
            self._discard(p, exc)
            return spec.max_steps

    def put(self, episode: Episode) -> Path | None:
        """Write atomically (:func:`odolab.io.atomic.atomic_open`, a link in the entry's place
        replaced); returns the path. When it cannot be written (:meth:`_keep`) the episode is kept
        in memory and None is returned."""
        key = episode.spec.key()
        if self._write_failed:  # said once; the disk is not retried for every episode
            self._unwritten[key] = episode
            return None
        p = self.path(episode.spec)
        info = json.dumps({**episode.info, "spec_key": key})
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            self._sweep()
            with atomic_open(p, "wb", follow_links=False) as f:
                np.savez(
                    f,
                    rgb=episode.rgb,
                    depth=episode.depth,
                    poses=episode.poses,
                    actions=episode.actions,
                    collisions=episode.collisions,
                    info=np.array(info),
                    **({} if episode.clean_depth_mm is None else {"clean_depth_mm": episode.clean_depth_mm}),
                )
        except (OSError, ValueError) as exc:
            self._keep(episode, p, exc)
            return None
        self._unwritten.pop(key, None)
        return p

    def _keep(self, episode: Episode, path: Path, exc: BaseException) -> None:
        """A failed write (full disk, read-only or vanished folder, a folder or pipe in the entry's
        place): one line on stderr, the first time, and the episode kept in memory."""
        self._unwritten[episode.spec.key()] = episode
        if not self._write_failed:
            self._write_failed = True
            reason = exc.strerror if isinstance(exc, OSError) and exc.strerror else str(exc)
            if not (isinstance(exc, OSError) and exc.errno in _WHOLE_CACHE):  # one entry's: name it
                reason = f"{path.name}: {reason}"
            self._say(
                f"odolab: warning: cannot write the episode cache {self.root} ({reason}); "
                "going on without writing it (the results are kept)"
            )

    def _sweep(self) -> None:
        """Once per cache: remove the temporary files killed writers left (one line on stderr)."""
        if self._swept:
            return
        self._swept = True
        removed = remove_stale_temporaries(self.root, CACHE_TEMPORARY)
        if removed:
            self._say(
                f"odolab: removed {len(removed)} temporary file{'s' if len(removed) > 1 else ''} that a stopped "
                f"episode-cache write left in {self.root}"
            )


def generate_episodes(
    specs: list[EpisodeSpec],
    cache: EpisodeCache | None = None,
    *,
    execution: Execution = Execution(),
) -> dict[int, Episode]:
    """Generate the episodes of ``specs`` that ``cache`` lacks (all without a cache), as Ray tasks
    when ``execution.parallel`` and more than one is missing. With a cache each is written as it finishes and
    not kept in memory; without one they are returned, by index into ``specs``."""

    missing = [i for i, s in enumerate(specs) if cache is None or not cache.has(s)]
    kept: dict[int, Episode] = {}

    def done(k: int, ep: Episode) -> None:
        if cache is not None:
            cache.put(ep)
        else:
            kept[missing[k]] = ep

    fan_out(
        render_episode,
        [specs[i] for i in missing],
        on_result=done,
        execution=execution,
        desc="episodes",
    )
    return kept


def load_episodes(
    specs: list[EpisodeSpec],
    cache: EpisodeCache | None = None,
    *,
    execution: Execution = Execution(),
) -> list[Episode]:
    """All episodes of ``specs`` in memory, in order (generated where the cache lacks them)."""
    return list(stream_episodes(specs, cache, execution=execution))


def stream_episodes(
    specs: list[EpisodeSpec],
    cache: EpisodeCache | None = None,
    *,
    execution: Execution = Execution(),
) -> Iterator[Episode]:
    """The episodes of ``specs`` in order, one at a time: the missing ones are generated first; with
    a cache, each is then read back only when its turn comes, so memory holds one episode."""
    fresh = generate_episodes(specs, cache, execution=execution)
    for i, spec in enumerate(specs):
        ep = fresh.pop(i, None) or (cache.get(spec) if cache is not None else None)
        if ep is None:  # the cache lost it meanwhile (damaged, another process, a full disk): make it again
            ep = render_episode(spec)
            if cache is not None:
                cache.put(ep)
        yield ep
