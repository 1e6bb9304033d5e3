"""The pose corrector's network: a small CNN from a pair (the previous frame and the current one
resampled into its view by a motion estimate) to a correction of that estimate and its variance.

Inputs (:func:`pair_inputs`), per pixel (10 channels at the model's size): the previous frame's RGB
in [-0.5, 0.5] and depth / ``depth_scale``; the warped current frame's RGB and depth likewise and
its validity (0 where the warp left a hole); the warped depth's change, (warped - previous) /
``residual_scale`` clipped to [-3, 3] where both have a reading. Per pair (7 values): the action
one-hot (move_forward, turn_left, turn_right; all 0 without an action), whether X failed (the
estimate is then the action prior's), and the estimate's (dx, dz, dyaw) over the nominal step
(0.25 m, 0.25 m, 30 degrees).

Outputs: a correction ``c`` of (dx m, dz m, dyaw rad), each ``max`` x tanh of its head output
(``max_translation``, ``max_rotation``), and its log-variance, the head output plus the log of the
base variance (``base_std_*`` squared). The head starts at zero: an untrained network answers
``c = 0`` exactly, with the base variance. The corrected motion is the estimate's planar motion
plus ``c`` (:func:`apply_correction`).
"""

from __future__ import annotations

import math

import numpy as np
import torch
import torch.nn.functional as F
from torch import nn

from odolab.api import FORWARD_STEP, MOTION_ACTIONS, TURN_ANGLE, Intrinsics, wrap_angle
from odolab.learned.pose_corrector.config import PoseCorrectorModel
from odolab.learned.robust_vo.warp import warp_current

INPUT_CHANNELS = 10
VECTOR_SIZE = len(MOTION_ACTIONS) + 4
#: The stride-2 stages' channels, in multiples of ``base``.
STAGE_WIDTHS = (1, 2, 4, 4)
#: Log-variances are clipped to this many units around the base's (numerically safe variances).
LOG_VARIANCE_RANGE = 10.0


def feature_size(cfg: PoseCorrectorModel) -> tuple[int, int]:
    """(h, w) of the last stage's feature map: each stride-2 stage rounds half the size up."""
    h, w = cfg.height, cfg.width
    for _ in STAGE_WIDTHS:
        h, w = (h + 1) // 2, (w + 1) // 2
    return h, w


class PoseCorrectorNet(nn.Module):
    """The CNN (module docstring). ``forward(images, vector)`` -> ``(correction, log_variance)``,
    each (B, 3) float32 over (dx m, dz m, dyaw rad)."""

    def __init__(self, cfg: PoseCorrectorModel) -> None:
        super().__init__()
        self.cfg = cfg
        layers: list[nn.Module] = []
        cin = INPUT_CHANNELS
        for k in STAGE_WIDTHS:
            cout = cfg.base * k
            layers += [nn.Conv2d(cin, cout, 3, stride=2, padding=1), nn.ReLU(inplace=True)]
            layers += [nn.Conv2d(cout, cout, 3, padding=1), nn.ReLU(inplace=True)]
            cin = cout
        self.features = nn.Sequential(*layers)
        fh, fw = feature_size(cfg)
        self.hidden = nn.Linear(cin * fh * fw + VECTOR_SIZE, cfg.hidden)
        self.head = nn.Linear(cfg.hidden, 6)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)
        t, r = cfg.max_translation, cfg.max_rotation
        self.register_buffer("bound", torch.tensor([t, t, r], dtype=torch.float32), persistent=False)
        st, sr = cfg.base_std_translation, cfg.base_std_rotation
        base = torch.tensor([2 * math.log(st), 2 * math.log(st), 2 * math.log(sr)], dtype=torch.float32)
        self.register_buffer("base_log_variance", base, persistent=False)

    def forward(self, images: torch.Tensor, vector: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``images`` (B, 10, h, w), ``vector`` (B, 7) (:func:`pair_inputs`) -> correction and its
        log-variance (B, 3) float32 (m, m, rad; m^2, m^2, rad^2)."""
        f = self.features(images).flatten(1)
        h = F.leaky_relu(self.hidden(torch.cat([f, vector.to(f.dtype)], dim=1)), 0.01)
        out = self.head(h).float()
        correction = self.bound * torch.tanh(out[:, :3])
        log_variance = out[:, 3:].clamp(-LOG_VARIANCE_RANGE, LOG_VARIANCE_RANGE) + self.base_log_variance
        return correction, log_variance


def _planar_of(T: torch.Tensor) -> torch.Tensor:
    """(B, 3) (dx, dz, dyaw) of (B, 4, 4) ``T_prev_cur`` (as :func:`odolab.api.transform_to_planar`)."""
    return torch.stack([T[:, 0, 3], T[:, 2, 3], torch.atan2(-T[:, 0, 2], T[:, 2, 2])], dim=1)


def action_one_hot(actions: np.ndarray) -> torch.Tensor:
    """(B, 3) float32 one-hot of action values over move_forward, turn_left, turn_right (-1 or any
    other value: all 0)."""
    values = torch.as_tensor(np.asarray(actions, np.int64))
    return torch.stack([(values == a.value).float() for a in MOTION_ACTIONS], dim=1)


def pair_inputs(
    prev_rgb: torch.Tensor,
    prev_depth: torch.Tensor,
    cur_rgb: torch.Tensor,
    cur_depth: torch.Tensor,
    T_prev_cur: torch.Tensor,
    actions: np.ndarray,
    failed: torch.Tensor,
    intrinsics: Intrinsics,
    cfg: PoseCorrectorModel,
) -> tuple[torch.Tensor, torch.Tensor]:
    """The network's inputs (module docstring) of pairs at the model's size: RGB (B, h, w, 3) uint8
    or float 0-255, depth (B, h, w) m of the previous and the current frames, the estimates
    ``T_prev_cur`` (B, 4, 4) by which the current frame is warped (:func:`warp_current`), the action
    values (B,) (-1: none), ``failed`` (B,) bool (the estimate is the action prior's) and the
    intrinsics of frames of this size -> images (B, 10, h, w) and vector (B, 7), float32."""
    T = T_prev_cur.to(torch.float32)
    warped_rgb, warped_depth = warp_current(cur_rgb, cur_depth, prev_depth, T, intrinsics)
    prev_depth = prev_depth.to(torch.float32)
    both = (warped_depth > 0) & (prev_depth > 0)
    residual = torch.where(both, (warped_depth - prev_depth) / cfg.residual_scale, torch.zeros_like(prev_depth))
    images = torch.cat(
        [
            prev_rgb.to(torch.float32).permute(0, 3, 1, 2) / 255.0 - 0.5,
            (prev_depth / cfg.depth_scale)[:, None],
            warped_rgb.permute(0, 3, 1, 2) / 255.0 - 0.5,
            (warped_depth / cfg.depth_scale)[:, None],
            (warped_depth > 0).to(torch.float32)[:, None],
            residual.clamp(-3.0, 3.0)[:, None],
        ],
        dim=1,
    )
    nominal = torch.tensor([FORWARD_STEP, FORWARD_STEP, TURN_ANGLE], dtype=torch.float32)
    vector = torch.cat([action_one_hot(actions), failed.to(torch.float32)[:, None], _planar_of(T) / nominal], dim=1)
    return images, vector


def apply_correction(T_prev_cur: np.ndarray, correction: np.ndarray) -> np.ndarray:
    """``T_prev_cur`` (4x4) whose planar motion is its own plus ``correction`` (dx m, dz m, dyaw rad):
    dx and dz added to its translation, its rotation turned by dyaw about the up axis (its
    out-of-plane parts kept). A zero correction returns the same values, bit for bit."""
    dx, dz, dyaw = (float(v) for v in correction)
    c, s = math.cos(dyaw), math.sin(dyaw)
    turn = np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]])  # as odolab.api.planar_to_transform
    out = np.array(T_prev_cur, dtype=np.float64, copy=True)
    out[:3, :3] = turn @ out[:3, :3]
    out[0, 3] += dx
    out[2, 3] += dz
    return out


def residual_targets(truth: np.ndarray, estimate: np.ndarray) -> np.ndarray:
    """(N, 3) what the correction should answer: the true (dx, dz, dyaw) minus the estimate's
    (yaw wrapped to (-pi, pi])."""
    out = np.asarray(truth, np.float64) - np.asarray(estimate, np.float64)
    out[:, 2] = wrap_angle(out[:, 2])
    return out
