"""The robust VO network (facts.md section 3): a running input normaliser, a ResNet-18 with
GroupNorm, a 3x3 compression conv and a two-layer head with dropout predicting (dx, dz, dyaw)."""

from __future__ import annotations

import math

import torch
from torch import nn

from odolab.learned.robust_vo.config import ModelConfig

#: Negative slope of the head's hidden activation.
HIDDEN_SLOPE = 0.01


class RunningNorm(nn.Module):
    """Per-channel normalisation by the running mean and variance of every training batch seen
    (updated in training mode only; variance floored at 1e-2 as habitat-baselines does)."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        self.register_buffer("mean", torch.zeros(channels))
        self.register_buffer("var", torch.ones(channels))
        self.register_buffer("count", torch.zeros(()))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        if self.training:
            with torch.no_grad():
                n = x.shape[0] * x.shape[2] * x.shape[3]
                mean, var = batch_moments(x)
                total = self.count + n
                delta = mean - self.mean
                self.var.copy_((self.var * self.count + var * n + delta**2 * self.count * n / total) / total)
                self.mean.add_(delta * n / total)
                self.count.copy_(total)
        return (x - self.mean[None, :, None, None]) / self.var.clamp_min(1e-2).sqrt()[None, :, None, None]


def batch_moments(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    """Per-channel mean and population variance of ``x`` (N, C, H, W) over N, H and W, as float32.

    From the float32 sums of x and x^2 (pairwise, about 1e-7 relative), combined in float64: two
    to three times faster on a CPU than ``Tensor.var``, whose one-pass update runs per element. A
    channel whose variance is under 1e-3 of its mean square (where the difference would lose more
    than three of float32's seven digits: a near-constant channel far from zero) is computed again
    with ``Tensor.var``; so every variance is within about 1e-4 of exact, relative."""
    dims = (0, 2, 3)
    n = x.shape[0] * x.shape[2] * x.shape[3]
    mean = x.sum(dim=dims).double() / n
    square = x.square().sum(dim=dims).double() / n
    var = square - mean**2
    lost = (var * 1e3 < square).nonzero().flatten()
    if len(lost):
        var[lost] = x[:, lost].var(dim=dims, unbiased=False).double()
    return mean.float(), var.clamp_min(0.0).float()


class BasicBlock(nn.Module):
    def __init__(self, cin: int, cout: int, stride: int, groups: int) -> None:
        super().__init__()
        self.conv1 = nn.Conv2d(cin, cout, 3, stride, 1, bias=False)
        self.gn1 = nn.GroupNorm(groups, cout)
        self.conv2 = nn.Conv2d(cout, cout, 3, 1, 1, bias=False)
        self.gn2 = nn.GroupNorm(groups, cout)
        self.down = None
        if stride != 1 or cin != cout:
            self.down = nn.Sequential(nn.Conv2d(cin, cout, 1, stride, bias=False), nn.GroupNorm(groups, cout))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        out = torch.relu(self.gn1(self.conv1(x)))
        out = self.gn2(self.conv2(out))
        return torch.relu(out + (x if self.down is None else self.down(x)))


class ResNet18GN(nn.Module):
    """ResNet-18 (basic blocks [2, 2, 2, 2], stride 32) with ``planes`` base channels and GroupNorm."""

    def __init__(self, cin: int, planes: int, groups: int) -> None:
        super().__init__()
        self.stem = nn.Sequential(
            nn.Conv2d(cin, planes, 7, 2, 3, bias=False),
            nn.GroupNorm(groups, planes),
            nn.ReLU(inplace=True),
            nn.MaxPool2d(3, 2, 1),
        )
        layers, c = [], planes
        for k, width in enumerate((planes, 2 * planes, 4 * planes, 8 * planes)):
            stride = 1 if k == 0 else 2
            layers += [BasicBlock(c, width, stride, groups), BasicBlock(width, width, 1, groups)]
            c = width
        self.layers = nn.Sequential(*layers)
        self.out_channels = c

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.layers(self.stem(x))


def feature_size(height: int, width: int) -> tuple[int, int]:
    """Spatial size after the ResNet's five stride-2 stages (conv and pool: ceil-ish halving)."""
    for _ in range(5):
        height, width = math.floor((height - 1) / 2) + 1, math.floor((width - 1) / 2) + 1
    return height, width


class VONet(nn.Module):
    """One network: (B, 2C, H, W) pair channels [+ (B,) action indices for ActEmbed] -> (B, 3)."""

    def __init__(self, cfg: ModelConfig) -> None:
        super().__init__()
        cin = cfg.input_channels
        self.norm = RunningNorm(cin)
        self.encoder = ResNet18GN(cin, cfg.base_planes, cfg.groups)
        self.compress = nn.Sequential(
            nn.Conv2d(self.encoder.out_channels, cfg.compress_channels, 3, 1, 1, bias=False),
            nn.GroupNorm(1, cfg.compress_channels),
            nn.ReLU(inplace=True),
        )
        fh, fw = feature_size(cfg.height, cfg.width)
        features = cfg.compress_channels * fh * fw
        self.embed = nn.Embedding(3, cfg.embed_dim) if cfg.kind == "actembed" else None
        extra = cfg.embed_dim if self.embed is not None else 0
        # The hidden layer leaks (slope 0.01; the paper: ReLU) and the last layer starts at zero (its
        # bias is set to the mean motion before training). With ReLU, Adam and targets whose spread is
        # ~0.05, every hidden unit of our turn networks died within the first epoch (measured: 0 of 512
        # alive), leaving a network that predicts the mean motion and never recovers.
        self.head = nn.Sequential(
            nn.Dropout(cfg.dropout),
            nn.Linear(features + extra, cfg.hidden),
            nn.LeakyReLU(HIDDEN_SLOPE, inplace=True),
            nn.Dropout(cfg.dropout),
            nn.Linear(cfg.hidden, 3),
        )
        nn.init.zeros_(self.head[-1].weight)

    def forward(self, x: torch.Tensor, action_index: torch.Tensor | None = None) -> torch.Tensor:
        f = self.compress(self.encoder(self.norm(x))).flatten(1)
        if self.embed is not None:
            if action_index is None:
                raise ValueError("an ActEmbed network needs the action of each pair")
            f = torch.cat([f, self.embed(action_index)], dim=1)
        return self.head(f)


def build_networks(cfg: ModelConfig) -> nn.ModuleDict:
    """The networks of a config by name (:meth:`ModelConfig.model_names`)."""
    return nn.ModuleDict({name: VONet(cfg) for name in cfg.model_names()})


def predict(nets: nn.ModuleDict, cfg: ModelConfig, x: torch.Tensor, actions) -> torch.Tensor:
    """(B, 3) planar motions of pairs ``x`` (B, 2C, H, W) taken with ``actions`` (B,) :class:`Action`
    values: each pair goes through the network of its action (SepAct) or the one network; with
    ``mirror_turns`` a right turn goes through the left-turn network mirrored (input flipped left to
    right, dx and dyaw of the answer negated)."""
    from odolab.api import Action

    acts = [Action(int(a)) for a in actions]
    index = torch.tensor([a.value - 1 for a in acts], device=x.device)
    flip = torch.tensor([cfg.mirrored(a) for a in acts], device=x.device)
    if flip.any():
        x = torch.where(flip[:, None, None, None], x.flip(-1), x)
    names = dict.fromkeys(cfg.model_for(a) for a in acts)
    if len(names) == 1:  # one network for the batch: no copy of its rows
        return _unflip(nets[next(iter(names))](x, index).to(x.dtype), flip)  # autocast answers in bf16
    out = x.new_zeros((x.shape[0], 3))
    for name in names:
        rows = torch.tensor([k for k, a in enumerate(acts) if cfg.model_for(a) == name], device=x.device)
        out[rows] = nets[name](x[rows], index[rows]).to(out.dtype)
    return _unflip(out, flip)


def _unflip(out: torch.Tensor, flip: torch.Tensor) -> torch.Tensor:
    """Answers (B, 3) of mirrored inputs (``flip``, B) mirrored back: dx and dyaw negated."""
    if flip.any():
        out = torch.where(flip[:, None], out * out.new_tensor([-1.0, 1.0, -1.0]), out)
    return out
