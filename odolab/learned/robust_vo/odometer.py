"""``robust-vo``: the paper's learned visual odometry as an :class:`~odolab.api.Odometer`.

    python -m odolab.compare --odometers action-prior,icp,robust-vo
    python -m odolab.compare --odometers robust-vo --odometer-option robust-vo.checkpoint=runs/robust-vo/x/model.pt

Each frame is resized to the model's input size (:func:`odolab.learned.training.resize_frame`, as the
training data was), the pair's channels psi are computed and the network of the action taken
predicts ``(dx, dz, dyaw)``. Options (the fields of :class:`RobustVOOptions`): ``checkpoint`` (default: the shipped model), ``mirror_tta``
(also run the mirrored pair through the opposite action's network and average; Partsey et al.
2022), ``mc_samples`` (> 1: that many passes with dropout on, whose spread gives
``Estimate.covariance``; the paper's "rnd" mode; its dropout draws are seeded by ``seed`` and the
step's place in the sequence, so reruns give the same numbers), ``threads``, ``batch_size``,
``device``, ``precision`` (``bf16``: the networks under bf16 autocast, faster on a CPU with native
bf16; docs/learned.md has its speed and error beside fp32's). Frames are recognised by identity: the runner's frames are read-only, and a caller who
rewrites a frame's arrays in place between steps must call ``reset``.
A SepAct or ActEmbed model, or one with the ``nominal`` warp (:mod:`odolab.learned.robust_vo.warp`), needs
the action: on real data (no action) it answers ``valid=False``.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import torch

from odolab.api import MAX_THREADS, Action, Estimate, Frame, Intrinsics, Odometer, check, configure, setting
from odolab.learned.robust_vo.checkpoint import SHIPPED, load_model
from odolab.learned.robust_vo.inputs import frame_channels, residual_channel
from odolab.learned.robust_vo.model import predict
from odolab.learned.robust_vo.motion import mirror, swap_action
from odolab.learned.robust_vo.warp import nominal_transforms, warp_current
from odolab.learned.training import Compute, pick_device, resize_frame
from odolab.learned.training.compute import native_bf16

#: Variance (m^2 or rad^2) given to the out-of-plane components (rx, rz, ty) of the covariance.
PLANAR_VARIANCE = 1e-6


def planar_covariance_to_6d(cov: np.ndarray) -> np.ndarray:
    """3x3 covariance of (dx, dz, dyaw) -> 6x6 over (rx, ry, rz, tx, ty, tz) of ``T_prev_cur``
    (camera axes: ry = -dyaw because y points down, tx = dx, tz = dz)."""
    J = np.zeros((6, 3))
    J[1, 2], J[3, 0], J[5, 1] = -1.0, 1.0, 1.0
    out = J @ cov @ J.T
    out[[0, 2, 4], [0, 2, 4]] = PLANAR_VARIANCE
    return out


@dataclass(frozen=True)
class RobustVOOptions:
    """The options of ``robust-vo`` (module docstring); the network itself comes from ``checkpoint``."""

    checkpoint: str = setting("", doc="robust-VO model file (default: the shipped model)")
    mirror_tta: bool = setting(
        False, doc="also run the mirrored pair through the opposite action's network and average"
    )
    mc_samples: int = setting(0, range=(0, 1000), doc="passes with dropout on for a covariance: 0 (off) or 2-1000")
    threads: int = setting(1, range=(1, MAX_THREADS), doc="torch threads while it runs")
    batch_size: int = setting(1, range=(1, 4096), doc="consecutive pairs per network pass")
    device: str = setting("", doc="torch device (default cpu)")
    seed: int = setting(0, range=(0, 2**32 - 1), doc="seed of the dropout draws")
    precision: Literal["fp32", "bf16"] = setting(
        "fp32",
        doc="the networks' precision: bf16 (autocast) is faster where the CPU has native bf16, not the same numbers",
    )

    def __post_init__(self) -> None:
        check(self)
        if self.mc_samples == 1:
            raise ValueError(f"mc_samples must be 0 (off) or in [2, 1000], got {self.mc_samples}")


class RobustVOOdometer(Odometer):
    """The robust VO. See the module docstring for the options."""

    Config = RobustVOOptions  # its options: every field (odolab.odometry.configured)

    def __init__(self, config: RobustVOOptions | None = None, **overrides) -> None:
        self.options = opts = configure(RobustVOOptions, config, **overrides)
        self.cfg, self.nets, self.info = load_model(opts.checkpoint or SHIPPED)
        self.identity_digest = self.info["sha256"]
        self.device = pick_device(opts.device or "cpu")
        if opts.precision == "bf16" and self.device.type == "cuda" and not native_bf16(self.device):
            raise ValueError(f"precision bf16 needs a GPU with bf16; {self.device} has none: use precision fp32")
        self.nets.to(self.device)
        self.mirror_tta, self.mc_samples = bool(opts.mirror_tta), int(opts.mc_samples)
        self.threads, self.batch_size = int(opts.threads), int(opts.batch_size)
        self.compute = Compute(self.device, opts.precision, "channels_last")  # its autocast: the networks' precision
        self.seed, self._draws = int(opts.seed), 0  # MC-dropout draws: seeded per call, counted from reset
        # SepAct and ActEmbed pick by action, the nominal warp moves by it
        self.needs_action = self.cfg.kind != "unified" or self.cfg.warp != "none"
        self._input_intrinsics: Intrinsics | None = None
        # NHWC: oneDNN's convolutions at batch 1 run faster on a CPU than in the contiguous layout
        self.nets.to(memory_format=torch.channels_last)
        self._last: tuple[np.ndarray, torch.Tensor] | None = None  # (the last frame's pixels, its psi)
        self._sized: list[tuple[np.ndarray, tuple[torch.Tensor, torch.Tensor]]] = []  # the last frames resized

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self._input_intrinsics = intrinsics.resized(self.cfg.width, self.cfg.height)
        self._last = None
        self._sized = []
        self._draws = 0

    def network_steps_per_s(self, calls: int = 20) -> float:
        """Steps per second of the forward network's pass alone at batch 1, as :meth:`step` runs it
        (layout, device; the caller's torch threads), on a random input: the limit of the step's
        rate. Median of ``calls`` timed calls after two untimed ones."""
        from odolab.learned.robust_vo.speed import calls_per_s

        x = torch.rand(1, self.cfg.input_channels, self.cfg.height, self.cfg.width)
        x = x.to(self.device, memory_format=torch.channels_last)
        actions = np.array([Action.MOVE_FORWARD.value])

        def call() -> torch.Tensor:
            with self.compute.autocast():
                return predict(self.nets, self.cfg, x, actions)

        return calls_per_s(call, calls)

    def input_ms(self, prev: Frame, cur: Frame, action: Action, calls: int = 20) -> float:
        """Milliseconds of one step's network input alone, as :meth:`step` makes it from nothing
        cached: both frames resized, the current one warped (with the ``nominal`` warp) and psi of
        both written into the channels-last input; median of ``calls`` timed calls after two untimed
        ones. What a step adds to its network's pass, beside the prediction's own overhead. Needs
        :meth:`reset` first; the frames kept for the next step are forgotten (as by :meth:`reset`)."""
        from odolab.learned.robust_vo.speed import calls_per_s

        if self._input_intrinsics is None:
            raise RuntimeError("input_ms needs reset(intrinsics) first")
        shape = (1, self.cfg.height, self.cfg.width, self.cfg.input_channels)
        x = torch.empty(shape, dtype=torch.float32).permute(0, 3, 1, 2)

        def call() -> None:
            self._last, self._sized = None, []
            self._pair_channels(prev, cur, action, x[0])

        try:
            return 1000.0 / calls_per_s(call, calls)
        finally:
            self._last, self._sized = None, []

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        return self.step_batch([(prev, cur, action)])[0]

    def _resized(self, frame: Frame) -> tuple[torch.Tensor, torch.Tensor]:
        """A frame's RGB (1, h, w, 3) and depth (1, h, w) at the model's size, as the training data was;
        the last two frames' are kept (a step's current frame is the next step's previous one)."""
        for pixels, sized in self._sized:
            if pixels is frame.rgb:
                return sized
        rgb, depth = resize_frame(frame.rgb, frame.depth, self.cfg.width, self.cfg.height)
        rgb, depth = (a if a.flags.writeable else a.copy() for a in (rgb, depth))  # torch wants writable arrays
        sized = torch.from_numpy(rgb)[None], torch.from_numpy(depth)[None]
        self._sized = [*self._sized[-1:], (frame.rgb, sized)]
        return sized

    def _frame_channels(self, frame: Frame, out: torch.Tensor) -> None:
        """Write psi of one frame into ``out`` (C, h, w); a frame whose psi the last call wrote (the
        previous pair's current frame, the same arrays) is copied from there, not computed again."""
        if self._last is not None and self._last[0] is frame.rgb:
            out.copy_(self._last[1])
        else:
            frame_channels(*self._resized(frame), self._input_intrinsics, self.cfg, out=out[None])
        self._last = (frame.rgb, out)

    def _pair_channels(self, prev: Frame, cur: Frame, action: Action, out: torch.Tensor) -> None:
        """Write psi of a pair into ``out`` (2C [+ 1], h, w), a slice of the network's channels-last
        input (no copy of the parts after): [prev, cur] and, with ``depth_residual``, the residual;
        with the ``nominal`` warp the current frame is first resampled into the previous view by the
        action's commanded motion."""
        c = self.cfg.channels_per_frame
        self._frame_channels(prev, out[:c])
        if self.cfg.warp == "none":
            self._frame_channels(cur, out[c : 2 * c])
            return
        (_, prev_depth), (rgb, depth) = self._resized(prev), self._resized(cur)
        rgb, depth = warp_current(
            rgb, depth, prev_depth, nominal_transforms(np.array([action.value])), self._input_intrinsics
        )
        frame_channels(rgb, depth, self._input_intrinsics, self.cfg, out=out[None, c : 2 * c])
        if self.cfg.depth_residual:
            out[2 * c].copy_(residual_channel(prev_depth, depth, self.cfg.depth_residual)[0, 0])

    def _predict(self, x: torch.Tensor, actions: np.ndarray) -> torch.Tensor:
        """(B, 3) motions of pair inputs ``x`` (B, 2C, h, w); with ``mirror_tta`` averaged with the
        mirror of the prediction for the mirrored pair (taken with the opposite turn's network)."""
        with self.compute.autocast():
            out = predict(self.nets, self.cfg, x, actions)
            if self.mirror_tta:
                out = 0.5 * (out + mirror(predict(self.nets, self.cfg, x.flip(-1), swap_action(actions))))
        return out.float().cpu()

    def step_batch(self, pairs: list[tuple[Frame, Frame, Action | None]]) -> list[Estimate]:
        answers: list[Estimate | None] = [None] * len(pairs)
        todo = []
        for k, (_, _, action) in enumerate(pairs):
            if action is Action.STOP:
                answers[k] = Estimate(np.eye(4))
            elif action is None and self.needs_action:
                answers[k] = Estimate.invalid()
            else:
                todo.append(k)
        if todo:
            chosen = [pairs[k][2] or Action.MOVE_FORWARD for k in todo]  # a unified model may get no action
            # (B, h, w, channels) memory seen as (B, channels, h, w): the network's channels-last input
            shape = (len(todo), self.cfg.height, self.cfg.width, self.cfg.input_channels)
            x = torch.empty(shape, dtype=torch.float32).permute(0, 3, 1, 2)
            for j, (k, a) in enumerate(zip(todo, chosen)):
                self._pair_channels(pairs[k][0], pairs[k][1], a, x[j])
            if len(todo) > 1 and self._last is not None:  # keep the last frame's psi, not the whole batch's input
                self._last = (self._last[0], self._last[1].clone())
            x = x.to(self.device)
            actions = np.array([a.value for a in chosen])
            with torch.inference_mode():
                if self.mc_samples:
                    for m in self.nets.modules():
                        if isinstance(m, torch.nn.Dropout):
                            m.train()
                    with torch.random.fork_rng(devices=[]):  # same seed, same sequence: same draws
                        torch.manual_seed(self.seed * 1_000_003 + self._draws)
                        self._draws += 1
                        draws = torch.stack([self._predict(x, actions) for _ in range(self.mc_samples)]).numpy()
                    for m in self.nets.modules():
                        m.eval()
                    mean = draws.mean(axis=0)
                    for j, k in enumerate(todo):
                        cov = np.cov(draws[:, j].T) + np.diag([1e-8, 1e-8, 1e-8])
                        answers[k] = Estimate.from_planar(*map(float, mean[j]), covariance=planar_covariance_to_6d(cov))
                else:
                    out = self._predict(x, actions).numpy()
                    for j, k in enumerate(todo):
                        answers[k] = Estimate.from_planar(*map(float, out[j]))
        return answers  # type: ignore[return-value]
