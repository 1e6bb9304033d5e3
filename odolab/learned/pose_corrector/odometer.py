"""``corrected(X)``: odometer X's estimate, corrected by a small CNN that reads the pair resampled by
that estimate (after DPC-Net, Peretroukhin and Kelly, RA-L 2018).

    python -m odolab.compare --odometers 'open3d-rgbd,corrected(open3d-rgbd)'

Each step X runs first; the current frame is resampled into the previous view by X's ``T_prev_cur``
(:func:`odolab.learned.robust_vo.warp.warp_current`, at the model's size after
:func:`odolab.learned.training.resize_frame`) and the network (:mod:`odolab.learned.pose_corrector.model`) answers a
correction of X's (dx, dz, dyaw) and its variance. The answer is X's motion with the correction
added (:func:`~odolab.learned.pose_corrector.model.apply_correction`); its covariance is the learned
variance (6x6, :func:`odolab.learned.robust_vo.odometer.planar_covariance_to_6d`), so ``fused(...)`` can
weigh it. Where X fails (raises, answers ``valid=False`` or no rigid motion:
:func:`odolab.api.failure_reason`) the action prior's motion is warped and corrected instead: the
answer is never invalid. An untrained model (its head at zero) answers exactly X where X answers.

Options: ``checkpoint`` (default: the shipped model for X, ``odolab/data/pose_corrector/<X>.pt``;
a model trained for another X is refused), ``threads`` (torch threads of the network),
``options_file`` (X's options, TOML ``[odometers."open3d-rgbd"]``). Frames are recognised by
identity (a step's current frame is the next step's previous one), as the runner hands out
read-only frames; a caller who rewrites a frame's arrays in place between steps must call ``reset``.
"""

from __future__ import annotations

import hashlib
from collections import Counter
from dataclasses import dataclass

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
    failure_reason,
    load_inputs,
    load_odometer,
    one_input,
    setting,
)
from odolab.learned.pose_corrector.checkpoint import SHIPPED_RECIPE, load_model, shipped_model
from odolab.learned.pose_corrector.config import PoseCorrectorTraining
from odolab.learned.pose_corrector.model import apply_correction, pair_inputs
from odolab.learned.robust_vo.odometer import planar_covariance_to_6d
from odolab.learned.training import resize_frame


@dataclass(frozen=True)
class CorrectedOptions:
    """The options of ``corrected(X)`` (module docstring); X's own come from ``options_file``."""

    checkpoint: str = setting("", doc="pose-corrector model file (default: the one shipped for X)")
    threads: int = setting(1, range=(1, MAX_THREADS), doc="torch threads while it runs")

    def __post_init__(self) -> None:
        check(self)


class CorrectedOdometer(Odometer):
    """X's estimate corrected by the learned pose corrector (module docstring)."""

    composite = True

    Config = CorrectedOptions  # its options: every field (odolab.odometry.configured)

    def __init__(
        self, inputs: str = "", config: CorrectedOptions | None = None, options_file: str = "", **overrides
    ) -> None:
        name = one_input("corrected", inputs)
        opts = configure(CorrectedOptions, config, **overrides)
        self.threads, checkpoint = int(opts.threads), opts.checkpoint
        path = checkpoint or shipped_model(name)
        if not checkpoint and not path.is_file():
            change = "" if name == PoseCorrectorTraining().inner else f" --set 'inner={name}'"
            raise ValueError(
                f"corrected({name}): no shipped model for {name} ({path}); train one (python -m "
                f"odolab.learned.pose_corrector.train --config {SHIPPED_RECIPE}{change} --export {path}) "
                "or pass checkpoint=<model file>"
            )
        self.cfg, self.net, self.info = load_model(path)
        trained_for = self.info["recipe"].get("inner")
        if trained_for != name:
            raise ValueError(
                f"{path}: a model trained to correct {trained_for!r}, not {name!r}; train one for "
                f"{name} (the recipe's inner) or pass its model as checkpoint="
            )
        self.inner = load_inputs("corrected", [name], options_file)[name]
        self.prior = load_odometer("action-prior")
        self.oracle, self.needs_action = self.inner.oracle, self.inner.needs_action
        self.identity_digest = hashlib.sha256(
            f"corrected;{name}={self.inner.identity_digest};{self.info['sha256']}".encode()
        ).hexdigest()
        #: Why X failed, counted since construction (its steps are then the corrected action prior).
        self.inner_failures: Counter[str] = Counter()
        self._small: Intrinsics | None = None
        self._sized: list[tuple[np.ndarray, tuple[torch.Tensor, torch.Tensor]]] = []  # the last frames resized

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self.inner.reset(intrinsics)
        self._small = intrinsics.resized(self.cfg.width, self.cfg.height)
        self._sized = []

    def _resized(self, frame: Frame) -> tuple[torch.Tensor, torch.Tensor]:
        """A frame's RGB (1, h, w, 3) uint8 and depth (1, h, w) float32 m at the model's size; the last
        two frames' are kept."""
        for pixels, sized in self._sized:
            if pixels is frame.rgb:
                return sized
        rgb, depth = resize_frame(frame.rgb, frame.depth, self.cfg.width, self.cfg.height)
        sized = torch.from_numpy(np.array(rgb, np.uint8))[None], torch.from_numpy(np.array(depth, np.float32))[None]
        self._sized = [*self._sized[-1:], (frame.rgb, sized)]
        return sized

    def _inner_step(self, prev: Frame, cur: Frame, action: Action | None) -> tuple[np.ndarray, bool]:
        """(X's ``T_prev_cur``, False), or (the action prior's, True) where X fails."""
        try:
            est = self.inner.step(prev, cur, action)
            reason = failure_reason(est) if isinstance(est, Estimate) else "not-an-estimate"
        except Exception as exc:  # noqa: BLE001 - any failure of X is answered by the corrected prior
            est, reason = None, f"raised {type(exc).__name__}"
        if reason is None:
            return np.array(est.transform, np.float64), False
        self.inner_failures[reason] += 1
        return np.array(self.prior.step(prev, cur, action).transform, np.float64), True

    def correction(
        self, prev: Frame, cur: Frame, action: Action | None, T_prev_cur: np.ndarray, failed: bool
    ) -> tuple[np.ndarray, np.ndarray]:
        """The network's correction (dx m, dz m, dyaw rad) of motion ``T_prev_cur`` and its variance
        (m^2, m^2, rad^2), float64 (3,) each."""
        (prev_rgb, prev_depth), (cur_rgb, cur_depth) = self._resized(prev), self._resized(cur)
        action_value = np.array([action.value if action is not None else -1])
        images, vector = pair_inputs(
            prev_rgb,
            prev_depth,
            cur_rgb,
            cur_depth,
            torch.from_numpy(T_prev_cur)[None],
            action_value,
            torch.tensor([failed]),
            self._small,
            self.cfg,
        )
        with torch.inference_mode():
            correction, log_variance = self.net(images, vector)
        return correction[0].double().numpy(), np.exp(log_variance[0].double().numpy())

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        if self._small is None:
            raise RuntimeError("CorrectedOdometer: call reset(intrinsics) before step()")
        T, failed = self._inner_step(prev, cur, action)
        correction, variance = self.correction(prev, cur, action, T, failed)
        return Estimate(apply_correction(T, correction), covariance=planar_covariance_to_6d(np.diag(variance)))
