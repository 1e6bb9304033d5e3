"""``denoised(X)``: odometer X on depth corrected by the learned depth corrector; and
``noiseless-depth(X)``: X on the simulator's noiseless depth (an oracle: the ceiling of any
depth corrector).

    python -m odolab.compare --odometers 'open3d-rgbd,denoised(open3d-rgbd),noiseless-depth(open3d-rgbd)'

``denoised(X)`` runs the corrector (:mod:`odolab.learned.depth_corrector.model`) on each frame once (a
step's current frame is the next step's previous one: frames are recognised by identity, as the
runner hands out read-only frames) and gives X the frame with its depth replaced: RGB, timestamp
and ground truth (for oracles) unchanged. Options: ``checkpoint`` (default: the shipped model),
``max_spread`` (m; > 0: pixels whose predicted error spread exceeds it get no reading, as a depth
camera drops pixels it cannot trust; 0: keep all), ``threads`` (torch threads of the corrector),
``options_file`` (X's options, TOML ``[odometers."icp"]``). Frames of another size than the
model's are resized to it and the correction (a per-pixel ratio) resized back.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from odolab.api import (
    MAX_THREADS,
    Action,
    Estimate,
    Frame,
    Intrinsics,
    Odometer,
    check,
    configure,
    load_inputs,
    one_input,
    setting,
)
from odolab.learned.depth_corrector.checkpoint import SHIPPED, load_model
from odolab.learned.depth_corrector.model import pixel_place
from odolab.learned.training import resize_frame


@dataclass(frozen=True)
class DenoisedOptions:
    """The options of ``denoised(X)`` (module docstring); X's own come from ``options_file``."""

    checkpoint: str = setting("", doc="depth-corrector model file (default: the shipped model)")
    max_spread: float = setting(
        0.0, range=(0.0, 100.0), doc="drop pixels whose corrected depth's spread is above this, m (0: keep every pixel)"
    )
    threads: int = setting(2, range=(1, MAX_THREADS), doc="torch threads while it runs")

    def __post_init__(self) -> None:
        check(self)


class DenoisedOdometer(Odometer):
    """X on corrected depth (module docstring)."""

    composite = True

    Config = DenoisedOptions  # its options: every field (odolab.odometry.configured)

    def __init__(
        self, inputs: str = "", config: DenoisedOptions | None = None, options_file: str = "", **overrides
    ) -> None:
        name = one_input("denoised", inputs)
        opts = configure(DenoisedOptions, config, **overrides)
        self.threads = int(opts.threads)
        self.cfg, self.net, self.info = load_model(opts.checkpoint or SHIPPED)
        self.max_spread = float(opts.max_spread)
        self.inner = load_inputs("denoised", [name], options_file)[name]
        self.oracle, self.needs_action = self.inner.oracle, self.inner.needs_action
        settings = f"{name}={self.inner.identity_digest};{self.info['sha256']};{self.max_spread!r}"
        self.identity_digest = hashlib.sha256(settings.encode()).hexdigest()
        self._place = pixel_place(self.cfg.height, self.cfg.width)[None]
        self._last: list[tuple[np.ndarray, Frame]] = []  # the last two frames' depth arrays and corrected frames

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self.inner.reset(intrinsics)
        self._last = []

    def network_steps_per_s(self, calls: int = 20) -> float:
        """Frames per second of the corrector's pass alone (one frame at the model's size, the caller's
        torch threads) on a random frame: the limit of what ``denoised`` adds to a step (one frame per
        step). Median of ``calls`` timed calls after two untimed ones."""
        import time

        rng = np.random.default_rng(0)
        rgb = torch.from_numpy(rng.integers(0, 256, (1, self.cfg.height, self.cfg.width, 3), dtype=np.uint8))
        depth = torch.from_numpy(rng.uniform(0.5, 6.0, (1, self.cfg.height, self.cfg.width)).astype(np.float32))
        times = []
        with torch.inference_mode():
            for k in range(calls + 2):
                started = time.perf_counter()
                self.net(rgb, depth, self._place)
                if k >= 2:
                    times.append(time.perf_counter() - started)
        return 1.0 / float(np.median(times))

    def correct_depth(self, rgb: np.ndarray, depth: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Corrected depth and its error's spread (H, W) float32 m of one RGB-D frame (0 = no reading)."""
        h, w = depth.shape
        size = (self.cfg.width, self.cfg.height)
        small_rgb, small_depth = resize_frame(rgb, depth, *size)
        with torch.inference_mode():
            corrected, spread = self.net(
                torch.from_numpy(np.array(small_rgb, np.uint8))[None],  # a writable copy (frames are read-only)
                torch.from_numpy(np.array(small_depth, np.float32))[None],
                self._place,
            )
        corrected, spread = corrected[0].numpy(), spread[0].numpy()
        if (w, h) != size:  # the correction as a ratio, resized back to the frame's pixels
            ratio = np.where(small_depth > 0, corrected / np.maximum(small_depth, 1e-6), 1.0).astype(np.float32)
            ratio = cv2.resize(ratio, (w, h), interpolation=cv2.INTER_LINEAR)
            spread = cv2.resize(spread, (w, h), interpolation=cv2.INTER_LINEAR)
            corrected = np.asarray(depth, np.float32) * ratio
        return corrected.astype(np.float32), spread.astype(np.float32)

    def _frame(self, frame: Frame) -> Frame:
        """``frame`` with its depth corrected (each frame once: the last two are kept)."""
        for depth, done in self._last:
            if depth is frame.depth:
                return done
        corrected, spread = self.correct_depth(frame.rgb, frame.depth)
        if self.max_spread > 0:
            corrected[spread > self.max_spread] = 0.0
        corrected.setflags(write=False)
        done = Frame(frame.rgb, corrected, timestamp=frame.timestamp, gt_pose=frame.gt_pose)
        self._last = [*self._last[-1:], (frame.depth, done)]
        return done

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        return self.inner.step(self._frame(prev), self._frame(cur), action)


class NoiselessDepthOdometer(Odometer):
    """X on the simulator's noiseless depth (``Frame.clean_depth``): the ceiling of any depth
    corrector under X. An oracle (it reads what only the simulator knows); on frames without a
    noiseless depth (real data) every step fails with the reason said once. Options:
    ``options_file`` (X's options)."""

    composite = True
    oracle = True

    def __init__(self, inputs: str = "", options_file: str = "") -> None:
        name = one_input("noiseless-depth", inputs)
        self.inner = load_inputs("noiseless-depth", [name], options_file)[name]
        self.needs_action, self.threads = self.inner.needs_action, getattr(self.inner, "threads", None)
        self.identity_digest = hashlib.sha256(
            f"noiseless-depth;{name}={self.inner.identity_digest}".encode()
        ).hexdigest()

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self.inner.reset(intrinsics)

    @staticmethod
    def _clean(frame: Frame) -> Frame:
        if frame.clean_depth is None:
            raise ValueError("noiseless-depth: this frame has no noiseless depth (only simulated episodes have one)")
        return Frame(frame.rgb, frame.clean_depth, timestamp=frame.timestamp, gt_pose=frame.gt_pose)

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        return self.inner.step(self._clean(prev), self._clean(cur), action)
