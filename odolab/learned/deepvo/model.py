"""The DeepVO network: two frames stacked on channels -> FlowNetSimple-like convolutions (BatchNorm,
LeakyReLU 0.1, dropout) -> a stacked LSTM over the sequence of pairs -> linear to (dx, dz, dyaw)."""

from __future__ import annotations

import numpy as np
import torch
from torch import nn

from odolab.learned.deepvo.config import FLOWNET_LAYERS, DeepVOModel

#: (dx m, dz m, dyaw rad): the scale of the outputs (the network predicts motion / SCALE).
SCALE = (0.1, 0.25, 0.5)


def frame_tensor(rgb: np.ndarray, depth: np.ndarray, cfg: DeepVOModel) -> torch.Tensor:
    """(..., H, W, 3) uint8 RGB and (..., H, W) depth in metres -> (..., C, H, W) float in about
    [-0.5, 0.5]: RGB / 255 - 0.5, and depth / max_depth - 0.5 when the model sees depth."""
    x = torch.from_numpy(np.ascontiguousarray(rgb)).to(torch.float32).movedim(-1, -3) / 255.0 - 0.5
    if cfg.depth:
        d = torch.from_numpy(np.ascontiguousarray(depth)).to(torch.float32).clamp(0, cfg.max_depth) / cfg.max_depth
        x = torch.cat([x, (d - 0.5).unsqueeze(-3)], dim=-3)
    return x


def _conv(cin: int, cout: int, kernel: int, stride: int, dropout: float) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(cin, cout, kernel, stride, kernel // 2, bias=False),
        nn.BatchNorm2d(cout),
        nn.LeakyReLU(0.1, inplace=True),
        nn.Dropout(dropout),
    )


#: Actions a model with ``actions`` takes (their one-hot index is ``value - 1``).
ACTION_INPUTS = 3


class DeepVONet(nn.Module):
    """``forward(frames (B, T+1, C, H, W), state, actions)`` -> (motions (B, T, 3), state): the
    motion of each consecutive pair, the LSTM carrying ``state`` ((h, c), or None for zeros) across
    calls; ``actions`` (B, T) :class:`~odolab.api.Action` values, for a model with ``actions``."""

    def __init__(self, cfg: DeepVOModel) -> None:
        super().__init__()
        layers, cin = [], 2 * cfg.frame_channels
        for cout, (_, kernel, stride) in zip(cfg.channels, FLOWNET_LAYERS):
            layers.append(_conv(cin, cout, kernel, stride, cfg.dropout))
            cin = cout
        self.encoder = nn.Sequential(*layers)
        self.encoder.eval()  # a probe of one image: BatchNorm in training mode needs more than one value
        with torch.no_grad():
            features = self.encoder(torch.zeros(1, 2 * cfg.frame_channels, cfg.height, cfg.width)).numel()
        self.encoder.train()
        self.actions = cfg.actions
        self.lstm = nn.LSTM(
            features + (ACTION_INPUTS if cfg.actions else 0),
            cfg.hidden,
            cfg.layers,
            batch_first=True,
            dropout=cfg.dropout if cfg.layers > 1 else 0.0,
        )
        self.drop = nn.Dropout(cfg.dropout)
        self.head = nn.Linear(cfg.hidden, 3)
        nn.init.zeros_(self.head.weight)  # start at the mean motion (the bias); see odolab.learned.robust_vo.model
        self.register_buffer("scale", torch.tensor(SCALE))

    def forward(
        self,
        frames: torch.Tensor,
        state: tuple[torch.Tensor, torch.Tensor] | None = None,
        actions: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, tuple[torch.Tensor, torch.Tensor]]:
        b, t1 = frames.shape[:2]
        pairs = torch.cat([frames[:, :-1], frames[:, 1:]], dim=2).flatten(0, 1)
        f = self.encoder(pairs).flatten(1).reshape(b, t1 - 1, -1)
        if self.actions:
            if actions is None or tuple(actions.shape) != (b, t1 - 1):
                got = None if actions is None else tuple(actions.shape)
                raise ValueError(
                    f"this DeepVO takes the action of each pair: expected actions of shape {(b, t1 - 1)}, got {got}"
                )
            f = torch.cat([f, nn.functional.one_hot(actions.long() - 1, ACTION_INPUTS).to(f.dtype)], dim=2)
        out, state = self.lstm(f, state)
        return self.head(self.drop(out)) * self.scale, state
