"""psi(I): the network input of a frame pair, computed on torch batches (facts.md section 3).

Per frame, in this channel order: RGB / 255 (3, if the visual input has RGB), depth / max_depth
clipped to [0, 1] (1, if it has depth), one-hot discretised depth over N equal bins of [0, 1]
(N = ``dd_bins``, holes fall in the first bin), and the soft top-down projection (1, if ``sproj``).
A pair stacks [prev, cur]; with RGB-D, 10 bins and S-proj that is 2 x 15 = 30 channels. With
``depth_residual`` (beyond the paper) one more channel follows: the current depth minus the previous
one, per pixel, over that many metres and clipped to [-1, 1] (0 where either is a hole). After the
nominal warp, the current depth is in the previous camera, so this is the depth change that the
deviation from the command made, e.g. -1 cm where the robot went 1 cm further than commanded
towards a wall it faces.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F

from odolab.api import Intrinsics
from odolab.learned.robust_vo.config import ModelConfig


def top_down_projection(
    depth: torch.Tensor, intrinsics: Intrinsics, max_depth: float, rows: float = 100 / 192, min_depth: float = 0.1
) -> torch.Tensor:
    """Soft top-down projection (B, H, W) in [0, 1] of depth images (B, H, W) in metres.

    Valid depth is smoothed by a 3x3 box filter over valid readings only, the central
    ``rows`` share of image rows is unprojected with ``intrinsics`` (camera x right, z forward), and
    the points are counted in an H x W grid spanning x in [-x_max, x_max] (x_max: the image edge at
    ``max_depth``) left to right and z in [min_depth, max_depth] bottom (near) to top (far). Counts
    are divided by each image's largest count. Only the central rows and their neighbours are
    filtered (the same numbers as filtering the whole image). The filter is average pooling of the
    band padded left and right (:func:`_box3`: ``avg_pool2d``'s numbers at a fraction of its time).
    """
    b, h, w = depth.shape
    keep = max(1, int(round(rows * h)))
    top = (h - keep) // 2
    band = torch.arange(top - 1, top + keep + 1, device=depth.device).clamp(0, h - 1)  # replicated borders
    d = depth.index_select(1, band)
    valid = (d > 0).to(depth.dtype)
    padded = F.pad(torch.stack([d * valid, valid], dim=1), (1, 1, 0, 0), mode="replicate")
    smooth, share = _box3(padded).unbind(1)
    z = torch.where(valid[:, 1:-1] > 0, smooth / share.clamp_min(1e-6), torch.zeros_like(smooth))
    u = torch.arange(w, dtype=depth.dtype, device=depth.device)
    x = (u - intrinsics.cx) / intrinsics.fx * z
    x_max = max_depth * (intrinsics.cx + 0.5) / intrinsics.fx
    col = torch.floor((x + x_max) / (2 * x_max) * w)
    row = (h - 1) - torch.floor((z - min_depth) / (max_depth - min_depth) * h)
    ok = (z >= min_depth) & (z <= max_depth) & (col >= 0) & (col < w) & (row >= 0) & (row < h)
    # each image's cells, and one more where the points outside the grid go (no masked copy)
    cell = torch.where(ok, row * w + col, float(h * w)).long()
    image = torch.arange(b, device=depth.device)[:, None, None] * (h * w + 1)
    counts = torch.bincount((cell + image).flatten(), minlength=b * (h * w + 1)).reshape(b, h * w + 1)
    counts = counts[:, :-1].reshape(b, h, w).to(depth.dtype)
    return counts / counts.flatten(1).amax(dim=1).clamp_min(1.0)[:, None, None]


def _box3(x: torch.Tensor) -> torch.Tensor:
    """The 3 x 3 mean over the last two axes of ``x`` (..., H, W) -> (..., H - 2, W - 2): the nine
    values summed in ``F.avg_pool2d``'s CPU order (rows, then columns within a row) and divided by
    9, so its numbers to the bit on a CPU in float32 and float64 (psi's depth is float32; a sum of
    nine -0.0 stays -0.0 here), at 0.12-0.2x its time (341 x 192, one thread). kornia's ``box_blur``
    (``replicate`` border) gives them within 2e-6 m (depths to 10 m), but below 2^22 elements oneDNN
    convolves there, measured 2.9x (one pair) to 3.6x (8 pairs) ``avg_pool2d``'s time."""
    h, w = x.shape[-2] - 2, x.shape[-1] - 2
    total = x[..., 0:h, 0:w] + x[..., 0:h, 1 : w + 1]
    for i, j in ((0, 2), (1, 0), (1, 1), (1, 2), (2, 0), (2, 1), (2, 2)):
        total += x[..., i : i + h, j : j + w]
    return total / 9


def frame_channels(
    rgb: torch.Tensor,
    depth: torch.Tensor,
    intrinsics: Intrinsics,
    cfg: ModelConfig,
    out: torch.Tensor | None = None,
) -> torch.Tensor:
    """psi of single frames: ``rgb`` (B, H, W, 3) uint8 and ``depth`` (B, H, W) metres -> (B, C, H, W)
    float32, written into one tensor (no concatenation): ``out`` where given, a float32 tensor of
    that shape in any memory layout (e.g. a slice of a channels-last network input), else a new one."""
    n, h, w = depth.shape
    if out is None:
        out = torch.empty((n, cfg.channels_per_frame, h, w), dtype=torch.float32, device=depth.device)
    elif out.dtype != torch.float32 or out.shape != (n, cfg.channels_per_frame, h, w):
        raise ValueError(
            f"psi: out must be float32 {(n, cfg.channels_per_frame, h, w)}, got {out.dtype} {tuple(out.shape)}"
        )
    k = 0
    if cfg.visual in ("rgb", "rgbd"):
        out[:, 0:3].copy_(rgb.permute(0, 3, 1, 2)).div_(255.0)
        k = 3
    d = (depth.to(torch.float32) / cfg.max_depth).clamp(0.0, 1.0)
    if cfg.visual in ("depth", "rgbd"):
        out[:, k].copy_(d)
        k += 1
    if cfg.dd_bins:
        index = torch.clamp((d * cfg.dd_bins).long(), 0, cfg.dd_bins - 1)
        out[:, k : k + cfg.dd_bins].zero_().scatter_(1, index[:, None], 1.0)
        k += cfg.dd_bins
    if cfg.sproj:
        out[:, k].copy_(top_down_projection(depth.to(torch.float32), intrinsics, cfg.max_depth, cfg.sproj_rows))
    return out


def residual_channel(prev_depth: torch.Tensor, cur_depth: torch.Tensor, scale: float) -> torch.Tensor:
    """(B, 1, H, W) depth change ``(cur - prev) / scale`` clipped to [-1, 1], 0 where either depth
    (B, H, W, metres) is a hole (0)."""
    prev, cur = prev_depth.to(torch.float32), cur_depth.to(torch.float32)
    r = ((cur - prev) / scale).clamp(-1.0, 1.0)
    return torch.where((prev > 0) & (cur > 0), r, torch.zeros_like(r))[:, None]


def pair_channels(rgb: torch.Tensor, depth: torch.Tensor, intrinsics: Intrinsics, cfg: ModelConfig) -> torch.Tensor:
    """psi of pairs: ``rgb`` (B, 2, H, W, 3) uint8, ``depth`` (B, 2, H, W) m -> (B, 2C [+ 1], H, W),
    [prev, cur] and, with ``depth_residual``, the residual channel."""
    b = rgb.shape[0]
    x = frame_channels(rgb.flatten(0, 1), depth.flatten(0, 1), intrinsics, cfg)
    x = x.reshape(b, 2 * x.shape[1], *x.shape[2:])
    if cfg.depth_residual:
        x = torch.cat([x, residual_channel(depth[:, 0], depth[:, 1], cfg.depth_residual)], dim=1)
    return x
