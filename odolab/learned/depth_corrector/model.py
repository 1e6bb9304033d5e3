"""The depth corrector's network: a small U-Net from an RGB-D frame to a corrected depth and the
spread of its error.

Inputs (per pixel, 7 channels): depth / ``depth_scale``, validity (depth > 0), RGB in [-0.5, 0.5],
and the pixel's place in the whole image (x, y in [-1, 1]); a training crop passes the place of its
pixels in the full frame, so crops and whole frames see the same function. Outputs: a relative
correction ``c`` (``max_correction`` x tanh of the first output channel) and a log spread ``s``;
the corrected depth is ``depth x (1 + c)`` where the depth has a reading (0 stays 0) and its error's
Laplace scale is ``b = exp(s) x B(depth)`` m with ``B(d) = 0.002 + 0.005 d^2`` (Redwood's
disparity quantisation grows as d^2). The last layer starts at zero: an untrained network answers
the input depth unchanged, with spread ``B(depth)``.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

from odolab.learned.depth_corrector.config import CorrectorModel

INPUT_CHANNELS = 7


def base_spread(depth: torch.Tensor) -> torch.Tensor:
    """``B(d) = 0.002 + 0.005 d^2`` m: the spread an untrained network gives depth ``d`` (m)."""
    return 0.002 + 0.005 * depth * depth


def _block(cin: int, cout: int, stride: int = 1) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, 3, stride=stride, padding=1),
        nn.ReLU(inplace=True),
        nn.Conv2d(cout, cout, 3, padding=1),
        nn.ReLU(inplace=True),
    )


class DepthCorrectorNet(nn.Module):
    """The U-Net (module docstring). ``forward(rgb, depth, place)`` -> ``(corrected depth, spread)``,
    each (B, H, W) float32 m."""

    def __init__(self, cfg: CorrectorModel) -> None:
        super().__init__()
        self.cfg = cfg
        widths = [cfg.base * 2**k for k in range(cfg.levels)]
        self.down = nn.ModuleList(
            [_block(INPUT_CHANNELS, widths[0])] + [_block(widths[k - 1], widths[k], 2) for k in range(1, cfg.levels)]
        )
        self.up = nn.ModuleList(
            [_block(widths[k] + widths[k - 1], widths[k - 1]) for k in range(cfg.levels - 1, 0, -1)]
        )
        self.head = nn.Conv2d(widths[0], 2, 1)
        nn.init.zeros_(self.head.weight)
        nn.init.zeros_(self.head.bias)

    def forward(self, rgb: torch.Tensor, depth: torch.Tensor, place: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """``rgb`` (B, H, W, 3) uint8, ``depth`` (B, H, W) float32 m (0 = no reading), ``place``
        (B, 2, H, W) pixel x, y in [-1, 1] of the full frame -> corrected depth and spread (B, H, W) m."""
        cfg = self.cfg
        valid = (depth > 0).to(depth.dtype)
        colour = rgb.permute(0, 3, 1, 2).to(depth.dtype) / 255.0 - 0.5
        x = torch.cat([(depth / cfg.depth_scale)[:, None], valid[:, None], colour, place.to(depth.dtype)], dim=1)
        h, w = x.shape[-2:]
        m = 2 ** (cfg.levels - 1)
        x = F.pad(x, (0, (-w) % m, 0, (-h) % m), mode="replicate")
        skips = []
        for block in self.down:
            x = block(x)
            skips.append(x)
        for block, skip in zip(self.up, reversed(skips[:-1])):
            x = F.interpolate(x, size=skip.shape[-2:], mode="bilinear", align_corners=False)
            x = block(torch.cat([x, skip], dim=1))
        out = self.head(x)[:, :, :h, :w].float()
        correction = cfg.max_correction * torch.tanh(out[:, 0])
        corrected = depth * (1.0 + correction)
        spread = torch.exp(out[:, 1].clamp(-8.0, 8.0)) * base_spread(depth)
        return corrected, spread


def pixel_place(
    height: int, width: int, top: int = 0, left: int = 0, full: tuple[int, int] | None = None
) -> torch.Tensor:
    """(2, height, width) x, y in [-1, 1] of the pixels of the window at (``top``, ``left``) in a
    frame of ``full`` = (H, W) px (default: the window is the whole frame); pixel centres."""
    H, W = full or (height, width)
    ys = (torch.arange(top, top + height, dtype=torch.float32) + 0.5) / H * 2.0 - 1.0
    xs = (torch.arange(left, left + width, dtype=torch.float32) + 0.5) / W * 2.0 - 1.0
    return torch.stack(torch.meshgrid(xs, ys, indexing="xy"))
