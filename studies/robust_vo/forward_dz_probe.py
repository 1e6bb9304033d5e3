"""Probe: what limits the robust VO's forward dz? (README, "The robust VO", issue: dz behind icp)

On the val pairs of a recipe's data (made by its training command), for move_forward, with the
shipped model or another of the same input size (``--checkpoint``):

1. ``passes``: the network applied again with the current frame warped by its own answer
   instead of the commanded motion; the motion it then reads beyond the command corrects the answer
   (``T = T_warp inv(T_nominal) T_out``). If the network read only the warp's deviation, a second
   pass would refine dz; if it also reads the scene (how far the wall is, what a collision looks
   like), the second pass counts that twice.
2. ``residual``: a geometric bound with no network: warp the current frame by the true dx and dyaw
   and the commanded dz, and take ``dz = 0.25 m - median(warped depth - previous depth)``; then the
   same with dx and dyaw off by Gaussian errors of a given sigma (m and rad), as a network's would be.

    python -m studies.robust_vo.forward_dz_probe --checkpoint reports/robust-vo/shipped/model.pt --out reports/robust-vo/forward-dz-probe.txt

Mean and median absolute errors are in 1e-2 m and 1e-2 rad, as everywhere in the README.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from odolab.api import FORWARD_STEP, Action, nominal_motion
from odolab.config import check, setting
from odolab.core.geometry import planar_to_transform, transform_to_planar
from odolab.io.atomic import write_text_atomic
from odolab.learned.robust_vo.checkpoint import SHIPPED, load_model
from odolab.learned.robust_vo.config import load_train_config
from odolab.learned.robust_vo.inputs import pair_channels
from odolab.learned.robust_vo.model import predict
from odolab.learned.robust_vo.warp import nominal_transforms, warp_current
from odolab.learned.training import TrainingData

BATCH = 128


@dataclass(frozen=True)
class ProbeSettings:
    """The probe's numbers: ``passes`` of the network over the val pairs."""

    passes: int = setting(2, range=(1, 10), doc="passes of the network")

    def __post_init__(self) -> None:
        check(self)


def _warped_depth(b: dict, T: torch.Tensor, data: TrainingData) -> tuple[torch.Tensor, torch.Tensor]:
    rgb, depth = torch.from_numpy(b["rgb"]), torch.from_numpy(b["depth"])
    return warp_current(rgb[:, 1], depth[:, 1], depth[:, 0], T, data.intrinsics)


def passes(data: TrainingData, idx: np.ndarray, n: int, checkpoint: Path = SHIPPED) -> list[np.ndarray]:
    """|error| (P, 3) of the model's answer after each of ``n`` passes."""
    cfg, nets, _ = load_model(checkpoint)
    undo = np.linalg.inv(nominal_motion(Action.MOVE_FORWARD))
    errors: list[list[np.ndarray]] = [[] for _ in range(n)]
    with torch.no_grad():
        for s in range(0, len(idx), BATCH):
            b = data.pair_batch(idx[s : s + BATCH])
            T = nominal_transforms(b["action"])
            for k in range(n):
                rgb, depth = _warped_depth(b, T, data)
                x = pair_channels(
                    torch.stack([torch.from_numpy(b["rgb"][:, 0]).float(), rgb], 1),
                    torch.stack([torch.from_numpy(b["depth"][:, 0]), depth], 1),
                    data.intrinsics,
                    cfg,
                )
                out = predict(nets, cfg, x, b["action"]).numpy().astype(np.float64)
                motion = np.stack(
                    [T[j].numpy().astype(np.float64) @ undo @ planar_to_transform(*out[j]) for j in range(len(out))]
                )
                errors[k].append(np.abs(np.stack([transform_to_planar(m) for m in motion]) - b["planar"]))
                T = torch.from_numpy(motion.astype(np.float32))
    return [np.concatenate(e) for e in errors]


def residual(data: TrainingData, idx: np.ndarray, sigma: float, seed: int = 0) -> np.ndarray:
    """|dz error| (P,) of the median depth residual after a warp by the true dx, dyaw (plus Gaussian
    errors of ``sigma``) and the commanded dz."""
    rng = np.random.default_rng(seed)
    out = []
    for s in range(0, len(idx), BATCH):
        b = data.pair_batch(idx[s : s + BATCH])
        guess = b["planar"].copy()
        guess[:, 1] = FORWARD_STEP
        guess[:, [0, 2]] += rng.normal(0.0, sigma, (len(guess), 2))
        T = torch.from_numpy(np.stack([planar_to_transform(*g) for g in guess]).astype(np.float32))
        _, depth = _warped_depth(b, T, data)
        prev = torch.from_numpy(b["depth"][:, 0])
        r = torch.where((prev > 0) & (depth > 0), depth - prev, torch.full_like(prev, float("nan")))
        dz = FORWARD_STEP - torch.nanmedian(r.flatten(1), dim=1).values.numpy()
        out.append(np.abs(dz - b["planar"][:, 1]))
    return np.concatenate(out)


def _is_report(path: Path) -> bool:
    """Whether ``path`` holds a report this probe wrote (its first line)."""
    with open(path, encoding="utf-8") as f:
        return f.readline().startswith("move_forward val pairs: ")


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks."""
    from odolab.cli import UsageError, check_output_file, check_replaceable

    if args.out is not None:  # found now, not after the work; only an earlier report is replaced
        check_output_file(args.out, "--out")
        check_replaceable(args.out, "--out", _is_report, "an earlier report of this probe")
    try:
        model, _, _ = load_model(args.checkpoint)  # before the data: its size is what they must have
        cfg = load_train_config(str(args.config))
        data = TrainingData(cfg.data_folder(cfg.val_data))
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    if (data.config.width, data.config.height) != (model.width, model.height):
        raise UsageError(
            f"{args.config}: its val data is {data.config.width} x {data.config.height} px, the model "
            f"{args.checkpoint} takes {model.width} x {model.height}"
        )
    idx = data.select([Action.MOVE_FORWARD])
    torch.set_num_threads(1)
    lines = [
        f"move_forward val pairs: {len(idx)} ({cfg.data_folder(cfg.val_data)})",
        "mean |error| (median) x 1e-2: dx m, dz m, dyaw rad",
        "",
    ]
    for k, e in enumerate(passes(data, idx, args.passes, args.checkpoint)):
        mean, med = 100 * e.mean(axis=0), 100 * np.median(e, axis=0)
        lines.append(f"network, pass {k + 1}: " + ", ".join(f"{a:.2f} ({m:.2f})" for a, m in zip(mean, med)))
    lines.append("")
    for sigma in (0.0, 0.01, 0.02):
        e = 100 * residual(data, idx, sigma)
        lines.append(
            f"median depth residual, dx and dyaw true + N(0, {sigma:g}): dz {np.nanmean(e):.2f} ({np.nanmedian(e):.2f})"
        )
    text = "\n".join(lines) + "\n"
    print(text, end="")
    if args.out is not None:
        write_text_atomic(args.out, text)
    return 0


if __name__ == "__main__":  # python -m studies.robust_vo.forward_dz_probe: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("forward-dz-probe"))
