"""The nominal-motion warp (a switch beyond the paper): the current frame of a pair, resampled into
the previous frame's view as if the robot had moved exactly as commanded.

For every pixel of the previous frame with depth d (holes: ``fallback_depth``), the point
P = d * ray(u, v) (previous camera axes) is moved into the current camera by the inverse of the
action's nominal ``T_prev_cur`` (:func:`odolab.api.nominal_motion`) and projected; the current RGB is sampled
there (bilinear) and the current depth (nearest), the sampled point is carried back into the previous
camera and its z becomes the warped depth. Pixels that fall outside the current image or on a depth
hole get RGB 0 and depth 0 (a hole). If the robot moved as commanded, the warped frame equals the
previous one up to noise and occlusions, so the network sees only the deviation from the command
(what it must predict beyond the action prior). For a pure rotation the warp does not depend on the
depth at all: it is the homography K R^T K^-1.

The back-projection is d * ((u - cx) / fx, (v - cy) / fy, 1) with integer pixel centres (as
:class:`odolab.core.types.Intrinsics` has them), each coordinate a plane of its own: the column and
row factors are two vectors broadcast over the depth image, and the rotation is written out per
component: on a CPU, the numbers of kornia's ``depth_to_3d_v2`` followed by a batched matrix
product (``einsum``, which rounds each product and sum there, no fused multiply-add), to the bit
(tests/test_robust_vo_warp.py holds that form), at 0.5-0.6x its time at 341 x 192 on one thread
(kornia rebuilds its pixel grid on every call, and the (B, H, W, 3) point layout costs strided
passes). kornia's ``transform_points`` with ``project_points`` measured 1.6-1.7x the time of that
``einsum`` and round differently.
"""

from __future__ import annotations

import numpy as np
import torch
import torch.nn.functional as F

from odolab.api import Action, Intrinsics, nominal_motion

#: Depth (m) assumed where the previous frame has no reading (only matters for translations).
FALLBACK_DEPTH = 5.0


def nominal_transforms(actions: np.ndarray) -> torch.Tensor:
    """(B, 4, 4) float32 nominal ``T_prev_cur`` of action values ``actions`` (B,)."""
    return torch.from_numpy(np.stack([nominal_motion(Action(int(a))) for a in actions]).astype(np.float32)).reshape(
        -1, 4, 4
    )


def warp_current(
    rgb: torch.Tensor,
    depth: torch.Tensor,
    prev_depth: torch.Tensor,
    T_prev_cur: torch.Tensor,
    intrinsics: Intrinsics,
    fallback_depth: float = FALLBACK_DEPTH,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Resample current frames into their previous frames' views (module docstring).

    ``rgb`` (B, H, W, 3) uint8 or float 0-255 and ``depth`` (B, H, W) m: the current frames;
    ``prev_depth`` (B, H, W) m; ``T_prev_cur`` (B, 4, 4) camera axes; ``intrinsics`` of these images.
    Returns RGB (B, H, W, 3) float32 0-255 and depth (B, H, W) float32 m in the previous camera.
    """
    _b, h, w = depth.shape
    K = intrinsics
    d = prev_depth.to(torch.float32)
    d = d.masked_fill(~(d > 0), fallback_depth)
    rx, ry = pixel_rays(K, h, w, d.device)
    R = T_prev_cur[:, :3, :3].to(torch.float32)[:, :, :, None, None]  # (B, 3, 3, 1, 1)
    t = T_prev_cur[:, :3, 3].to(torch.float32)[:, :, None, None]  # (B, 3, 1, 1)
    p = (d * rx - t[:, 0], d * ry - t[:, 1], d - t[:, 2])  # P - t, previous camera axes
    x, y, z = ((R[:, 0, i] * p[0] + R[:, 1, i] * p[1]) + R[:, 2, i] * p[2] for i in range(3))  # R^T (P - t)
    ahead = z > 1e-3
    zs = torch.where(ahead, z, torch.ones_like(z))
    uc = K.fx * x / zs + K.cx
    vc = K.fy * y / zs + K.cy
    inside = ahead & (uc >= -0.5) & (uc <= w - 0.5) & (vc >= -0.5) & (vc <= h - 0.5)
    grid = torch.stack([(uc + 0.5) / w * 2 - 1, (vc + 0.5) / h * 2 - 1], dim=-1)  # align_corners=False
    colour = F.grid_sample(
        rgb.to(torch.float32).permute(0, 3, 1, 2), grid, mode="bilinear", padding_mode="border", align_corners=False
    )
    sampled = F.grid_sample(
        depth.to(torch.float32)[:, None], grid, mode="nearest", padding_mode="zeros", align_corners=False
    )[:, 0]
    ok = inside & (sampled > 0)
    # the sampled current point, back in the previous camera: z of R Q + t with Q = sampled * ray(uc, vc)
    q = (sampled * ((uc - K.cx) / K.fx), sampled * ((vc - K.cy) / K.fy), sampled)
    z_prev = ((R[:, 2, 0] * q[0] + R[:, 2, 1] * q[1]) + R[:, 2, 2] * q[2]) + t[:, 2]
    ok = ok & (z_prev > 0)
    return colour.masked_fill_(~ok[:, None], 0.0).permute(0, 2, 3, 1), z_prev.masked_fill_(~ok, 0.0)


def pixel_rays(
    intrinsics: Intrinsics, h: int, w: int, device: torch.device | str | None = None
) -> tuple[torch.Tensor, torch.Tensor]:
    """The camera-axes ray (x, y, 1) of each pixel of an ``h`` x ``w`` image as two factors: x (W,)
    ``(u - cx) / fx`` and y (H, 1) ``(v - cy) / fy``, float32, integer pixel centres."""
    K = intrinsics
    rx = (torch.arange(w, dtype=torch.float32, device=device) - K.cx) / K.fx
    ry = (torch.arange(h, dtype=torch.float32, device=device) - K.cy) / K.fy
    return rx, ry[:, None]


def warp_pairs(
    rgb: torch.Tensor, depth: torch.Tensor, actions: np.ndarray, intrinsics: Intrinsics
) -> tuple[torch.Tensor, torch.Tensor]:
    """Pairs ``rgb`` (B, 2, H, W, 3), ``depth`` (B, 2, H, W) with their current frames warped by the
    nominal motion of ``actions`` (B,) (float32 RGB 0-255, depth m)."""
    cur_rgb, cur_depth = warp_current(
        rgb[:, 1], depth[:, 1], depth[:, 0], nominal_transforms(actions).to(depth.device), intrinsics
    )
    return (
        torch.stack([rgb[:, 0].to(torch.float32), cur_rgb], dim=1),
        torch.stack([depth[:, 0].to(torch.float32), cur_depth], dim=1),
    )
