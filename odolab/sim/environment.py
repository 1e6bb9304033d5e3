"""The step-wise simulator: the one place where an agent moves and sees.

:class:`Sensors` turns a camera pose into a noisy RGB-D frame (renderer + RGB noise + Redwood depth
noise, each drawing from its own random stream in order); :class:`PointNavEnv` holds the agent's
true state in a scene and moves it by noisy actions (``step``), seeing through ``Sensors``
(``observe``). The episode generator (:func:`odolab.sim.episodes.rollout`, :func:`~odolab.sim.episodes.render_frames`)
and closed-loop navigation both go through these two classes: the same laws of motion and sensing,
and the generator's policy driven step by step sees exactly the stored frames.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

import numpy as np

from odolab.core.geometry import camera_pose_from_agent
from odolab.core.types import Action, Frame
from odolab.sim.agent import AgentState, step_agent
from odolab.sim.camera import CameraSpec, Renderer
from odolab.sim.noise import ActuationNoise, RedwoodDepthNoise, RGBNoise
from odolab.sim.scenes import Scene


@dataclass(frozen=True)
class SensorReading:
    """One camera reading: clean and noisy RGB (H, W, 3) uint8 and depth (H, W) float32 m."""

    clean_rgb: np.ndarray
    clean_depth: np.ndarray
    rgb: np.ndarray
    depth: np.ndarray


class Sensors:
    """Noisy RGB-D of a scene from any camera pose; ``rgb_rng`` and ``depth_rng`` are consumed in
    call order (the same poses in the same order give the same frames).

    After the ray cast, the colour path (texture, shading) and the depth path (range, Redwood noise,
    and the RGB noise, which does not depend on the image) share nothing but the cast's read-only
    result and draw from their own streams, so with ``threads=2`` the depth path runs in a second
    thread (numpy releases the GIL in its loops): the same frames, bit for bit, 0.4-0.6 ms sooner per
    frame on two idle cores. ``threads=1`` runs both in the calling thread.
    """

    def __init__(
        self,
        scene: Scene,
        camera: CameraSpec,
        rgb_noise: float,
        depth_noise: float,
        rgb_rng: np.random.Generator,
        depth_rng: np.random.Generator,
        threads: int = 2,
    ) -> None:
        if isinstance(threads, bool) or not isinstance(threads, (int, np.integer)) or threads not in (1, 2):
            raise ValueError(f"Sensors threads must be the integer 1 or 2, got {threads!r}")
        self.camera = camera
        self.threads = int(threads)
        self._pool, self._pool_pid = None, None
        self.renderer = Renderer(scene, camera)
        self.rgb_noise = RGBNoise(multiplier=rgb_noise)
        self.depth_noise = RedwoodDepthNoise(
            multiplier=depth_noise, min_depth=camera.min_depth, max_depth=camera.max_depth
        )
        self.rgb_rng, self.depth_rng = rgb_rng, depth_rng

    def read(self, T_world_cam: np.ndarray) -> SensorReading:
        """The clean and noisy frame seen from ``T_world_cam`` (4x4, OpenCV camera axes, world Z up)."""
        hit = self.renderer.cast(T_world_cam)
        if self.threads == 2 and self._pool_pid != os.getpid():  # first read, or in a forked child
            from concurrent.futures import ThreadPoolExecutor  # (a fork copies no threads)

            self._pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="odolab-depth")
            self._pool_pid = os.getpid()
        if self._pool is None:
            clean_depth, depth, steps = self._depth_path(hit)
        else:
            pending = self._pool.submit(self._depth_path, hit)
        clean_rgb = self.renderer.colour(hit)
        if self._pool is not None:
            clean_depth, depth, steps = pending.result()
        return SensorReading(clean_rgb, clean_depth, self.rgb_noise.add(clean_rgb, steps), depth)

    def _depth_path(self, hit) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Clean and noisy depth, and the RGB noise (image-independent) drawn meanwhile: the colour
        path is the longer one."""
        cam = self.camera
        clean = self.renderer.depth(hit)
        steps = self.rgb_noise.draw((cam.height, cam.width, 3), self.rgb_rng)
        return clean, self.depth_noise.apply(clean, self.depth_rng), steps

    def close(self) -> None:
        """Stop the depth thread (also done when the object is collected); a later read runs in one
        thread."""
        if self._pool is not None and self._pool_pid == os.getpid():
            self._pool.shutdown(wait=True)
        self._pool, self._pool_pid, self.threads = None, None, 1

    def __del__(self) -> None:
        pool = getattr(self, "_pool", None)
        if pool is not None and getattr(self, "_pool_pid", None) == os.getpid():
            pool.shutdown(wait=False)


class PointNavEnv:
    """An agent in a scene: ``step(action)`` moves it with a fresh actuation-noise draw (collisions
    stop it at contact, or keep it in place), ``observe()`` renders what it sees.

    ``state``: the true :class:`~odolab.sim.agent.AgentState` (world x, y m, yaw rad) -- for the
    simulator and the metrics, never for the agent's policy. ``sensors``: None for a motion-only
    environment (the episode generator's rollout renders later, in one pass)."""

    def __init__(
        self,
        scene: Scene,
        start: AgentState,
        actuation: ActuationNoise,
        act_rng: np.random.Generator,
        sensors: Sensors | None = None,
        stop_at_contact: bool = True,
    ) -> None:
        self.scene, self.state, self.actuation, self.act_rng = scene, start, actuation, act_rng
        self.sensors, self.stop_at_contact = sensors, stop_at_contact
        self.steps, self.collisions = 0, 0

    def camera_pose(self) -> np.ndarray:
        """``T_world_cam`` (4x4) of the current true state."""
        height = self.sensors.camera.mount_height if self.sensors else CameraSpec().mount_height
        return camera_pose_from_agent(self.state.x, self.state.y, self.state.yaw, height)

    def observe(self, timestamp: float = 0.0) -> Frame:
        """The noisy frame at the current state (``gt_pose`` and ``clean_depth`` set: only oracles may
        read them)."""
        if self.sensors is None:
            raise RuntimeError("this environment has no sensors (made for motion only)")
        pose = self.camera_pose()
        reading = self.sensors.read(pose)
        return Frame(reading.rgb, reading.depth, timestamp=timestamp, gt_pose=pose, clean_depth=reading.clean_depth)

    def step(self, action: Action) -> bool:
        """Execute a motion action; returns whether its translation was blocked. STOP is refused:
        ending an episode is the caller's decision, not a motion."""
        if action not in (Action.MOVE_FORWARD, Action.TURN_LEFT, Action.TURN_RIGHT):
            raise ValueError(f"step takes a motion action, got {action!r}")
        self.state, collided = step_agent(
            self.scene, self.state, action, self.actuation, self.act_rng, self.stop_at_contact
        )
        self.steps += 1
        self.collisions += int(collided)
        return collided
