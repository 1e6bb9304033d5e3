"""Probe: does warping the current frame by the commanded turn let a turn network learn?

The shipped turn networks did not learn (README, "The robust VO"). This probe trains one fresh
``turn_left`` network of the shipped recipe for a fixed wall-clock budget on the shipped recipe's
train pairs (made by its training command) and reports its val error beside the action prior's,
either on the pairs as they are or with the current frame's RGB and depth warped by the homography
of the nominal 30 degree rotation, K R^T K^-1, so that the network sees only the residual motion
(a warped depth keeps the current frame's z; S-proj is computed from it).

    python -m studies.robust_vo.derotation_probe --samples 30304              # as the pairs are
    python -m studies.robust_vo.derotation_probe --samples 30304 --derotate   # warped first
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import cv2
import numpy as np
import torch

from odolab.api import TURN_ANGLE, Action, planar_to_transform
from odolab.config import check, setting
from odolab.learned.robust_vo.config import load_train_config
from odolab.learned.robust_vo.inputs import pair_channels
from odolab.learned.robust_vo.model import build_networks
from odolab.learned.training import TrainingData


@dataclass(frozen=True)
class ProbeSettings:
    """The probe's training budget: ``seconds`` of wall clock, or ``samples`` pairs when not 0."""

    seconds: float = setting(300.0, range=(1.0, 86_400.0), doc="training budget (wall clock, s)")
    samples: int = setting(0, range=(0, 10**8), doc="training budget in samples instead (0: use --seconds)")

    def __post_init__(self) -> None:
        check(self)


def derotation(data: TrainingData, angle: float) -> np.ndarray:
    """3x3 map from a pixel of the previous view to the current image under a pure rotation."""
    K = data.intrinsics
    Km = np.array([[K.fx, 0, K.cx], [0, K.fy, K.cy], [0, 0, 1]])
    R = planar_to_transform(0.0, 0.0, angle)[:3, :3]  # T_prev_cur's rotation
    return Km @ R.T @ np.linalg.inv(Km)


def batch(data: TrainingData, idx: np.ndarray, warp: np.ndarray | None, model) -> tuple[torch.Tensor, torch.Tensor]:
    b = data.pair_batch(idx)
    rgb, depth = b["rgb"].copy(), b["depth"].copy()
    if warp is not None:
        size = (model.width, model.height)
        for k in range(len(idx)):
            rgb[k, 1] = cv2.warpPerspective(rgb[k, 1], warp, size, flags=cv2.INTER_LINEAR | cv2.WARP_INVERSE_MAP)
            depth[k, 1] = cv2.warpPerspective(depth[k, 1], warp, size, flags=cv2.INTER_NEAREST | cv2.WARP_INVERSE_MAP)
    x = pair_channels(torch.from_numpy(rgb), torch.from_numpy(depth), data.intrinsics, model)
    return x, torch.from_numpy(b["planar"]).float()


#: Training pairs per step.
BATCH = 32


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks."""
    from odolab.cli import UsageError

    try:
        cfg = load_train_config(str(args.config))
        train, val = (TrainingData(cfg.data_folder(d)) for d in (cfg.train_data, cfg.val_data))
    except ValueError as exc:
        raise UsageError(f"--config {args.config}: {exc}") from None
    model = cfg.model
    train_idx, val_idx = train.select([Action.TURN_LEFT]), val.select([Action.TURN_LEFT])
    for data, idx, need in ((train, train_idx, BATCH), (val, val_idx, 1)):
        if len(idx) < need:
            raise UsageError(
                f"--config {args.config}: {data.root}: expected at least {need} turn_left pairs, found {len(idx)}"
            )
    warp = derotation(train, TURN_ANGLE) if args.derotate else None
    torch.manual_seed(0)
    net = build_networks(model)["turn_left"]
    mean = train.pair_planar[train_idx].mean(axis=0)
    with torch.no_grad():
        net.head[-1].bias.copy_(torch.from_numpy(mean).float())
    opt = torch.optim.Adam(net.parameters(), lr=5e-4)
    rng = np.random.default_rng(0)
    start, seen = time.monotonic(), 0
    while (seen < args.samples) if args.samples else (time.monotonic() - start < args.seconds):
        net.train()
        x, y = batch(train, np.sort(rng.choice(train_idx, BATCH, replace=False)), warp, model)
        loss = (net(x) - y).pow(2).sum(1).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        seen += BATCH
    net.eval()
    x, y = batch(val, val_idx, warp, model)
    with torch.no_grad():
        out = net(x)
    mae = ((out - y).abs().mean(0) * 100).numpy()
    prior = ((y - torch.from_numpy(mean).float()).abs().mean(0) * 100).numpy()
    print(
        f"{'derotated' if args.derotate else 'as they are'}: {seen} training samples in "
        f"{time.monotonic() - start:.0f} s; "
        f"val turn_left error x 1e-2 (dx, dz, dyaw) {[round(float(v), 2) for v in mae]}, "
        f"action prior {[round(float(v), 2) for v in prior]}, "
        f"spread of the outputs {[round(float(v), 4) for v in out.std(0)]}"
    )


if __name__ == "__main__":  # python -m studies.robust_vo.derotation_probe: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("derotation-probe"))
