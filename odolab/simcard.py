"""``python -m odolab.simcard``: the simulator in numbers, beside the paper's and Habitat's.

For N episodes of a split it measures what every learned odometer and table is fitted to:

* motion (rollouts only, no images): action mix, collision rate per action, geodesic start-goal
  distance and geodesic / euclidean ratio, episode length, goals reached;
* images (a few rendered episodes, clean and noisy frames of the same poses): grey-level mean and
  spread per frame (grey = 0.299 R + 0.587 G + 0.114 B of the clean frame), depth holes
  (no noisy reading where the clean depth has one), and the noisy / clean depth ratio per 1 m bin
  of clean depth (its mean - 1 is the bias, its standard deviation the spread; pixels off by more
  than 20 %, depth edges read through the jitter, are counted apart as outliers);

and writes ``card.json``, ``card.md`` (the table below with the references) and figures:
``motion.png``, ``depth.png`` and ``frames.png`` (a contact sheet of clean and noisy RGB and depth).
References: the paper's training data (Table S2 of Zhao et al. 2021: 573,232 / 213,434 / 213,334
forward / left / right steps, 12.10 / 12.68 / 7.51 % collided, 11.25 % overall), habitat-lab's
PointNav generator (geodesic 1-30 m; episodes with geodesic / euclidean < 1.1 mostly rejected) and
the TUM RGB-D fr1/xyz frames shipped in ``tests/data`` (grey spread median 93, mean 137).
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from odolab.config import SEED_RANGE, check, setting
from odolab.core.parallel import Execution, fan_out
from odolab.sim.scenes import SPLITS

PAPER_COLLISIONS = {"move_forward": 12.10, "turn_left": 12.68, "turn_right": 7.51, "all": 11.25}  # %
PAPER_MIX = {"move_forward": 57.32, "turn_left": 21.34, "turn_right": 21.33}  # % of 1,000,000 steps
DEPTH_BINS = np.arange(0.0, 10.5, 1.0)  # m, edges of the clean-depth bins
OUTLIER = 0.2  # relative depth error counted as an outlier (a depth edge), not as spread
#: The files a card is made of (under --out, with the manifest).
CARD_FILES = ("card.json", "card.md", "motion.png", "depth.png", "frames.png")
CARD_NAMES = re.compile("|".join(re.escape(name) for name in CARD_FILES))


@dataclass(frozen=True)
class MotionStats:
    """One rollout's numbers (no images)."""

    actions: list[int]
    collisions: list[bool]
    geodesic: float
    euclidean: float
    reached: bool


def motion_stats(spec) -> MotionStats:
    """Roll out ``spec`` (an :class:`~odolab.sim.episodes.EpisodeSpec`) and keep what the card needs."""
    from odolab.sim.episodes import rollout

    r = rollout(spec)
    return MotionStats(
        [a.value for a in r.actions],
        [bool(c) for c in r.collisions],
        r.start_distance,
        r.euclidean_distance,
        r.reached_goal,
    )


@dataclass
class ImageStats:
    """Per-frame grey statistics and per-depth-bin depth error sums over rendered frames."""

    grey_mean: list[float] = field(default_factory=list)
    grey_std: list[float] = field(default_factory=list)
    pixels: int = 0
    holes: int = 0  # clean reading, no noisy reading
    zero: int = 0  # no noisy reading at all
    bin_n: np.ndarray = field(default_factory=lambda: np.zeros(len(DEPTH_BINS) - 1))
    bin_sum: np.ndarray = field(default_factory=lambda: np.zeros(len(DEPTH_BINS) - 1))
    bin_sq: np.ndarray = field(default_factory=lambda: np.zeros(len(DEPTH_BINS) - 1))
    bin_outliers: np.ndarray = field(default_factory=lambda: np.zeros(len(DEPTH_BINS) - 1))
    hole_map: np.ndarray | None = None  # (H, W) share of frames with a hole at each pixel
    frames: int = 0

    def add(self, clean_rgb: np.ndarray, clean_depth: np.ndarray, noisy_depth: np.ndarray) -> None:
        grey = clean_rgb.astype(np.float32) @ np.array([0.299, 0.587, 0.114], np.float32)
        self.grey_mean.append(float(grey.mean()))
        self.grey_std.append(float(grey.std()))
        has = clean_depth > 0
        hole = has & (noisy_depth == 0)
        self.pixels += clean_depth.size
        self.holes += int(hole.sum())
        self.zero += int((noisy_depth == 0).sum())
        self.hole_map = hole.astype(np.float64) if self.hole_map is None else self.hole_map + hole
        self.frames += 1
        both = has & (noisy_depth > 0)
        rel = noisy_depth[both] / clean_depth[both] - 1.0
        b = np.digitize(clean_depth[both], DEPTH_BINS) - 1
        inl = np.abs(rel) <= OUTLIER
        k = len(DEPTH_BINS) - 1
        self.bin_n += np.bincount(b[inl], minlength=k)[:k]
        self.bin_sum += np.bincount(b[inl], rel[inl], minlength=k)[:k]
        self.bin_sq += np.bincount(b[inl], rel[inl] ** 2, minlength=k)[:k]
        self.bin_outliers += np.bincount(b[~inl], minlength=k)[:k]

    def depth_rows(self) -> list[dict]:
        """Per clean-depth bin: pixels, bias % (mean ratio - 1), spread % (std), outliers %."""
        rows = []
        for i in range(len(DEPTH_BINS) - 1):
            n = self.bin_n[i]
            if n < 100:
                continue
            mean = self.bin_sum[i] / n
            std = np.sqrt(max(self.bin_sq[i] / n - mean**2, 0.0))
            rows.append(
                {
                    "depth_m": f"{DEPTH_BINS[i]:.0f}-{DEPTH_BINS[i + 1]:.0f}",
                    "pixels": int(n),
                    "bias_pct": 100 * mean,
                    "spread_pct": 100 * std,
                    "outliers_pct": 100 * self.bin_outliers[i] / (n + self.bin_outliers[i]),
                }
            )
        return rows


def render_stats(spec, max_frames: int = 30, keep: int = 0) -> tuple[ImageStats, list[tuple]]:
    """Clean and noisy frames of ``spec``'s first ``max_frames`` poses; also returns ``keep`` sample
    frames (clean rgb, noisy rgb, clean depth, noisy depth) for the contact sheet."""
    from itertools import islice

    from odolab.sim.episodes import render_frames, rollout

    motion = rollout(spec)
    n = min(max_frames, len(motion.states))
    stats, samples = ImageStats(), []
    for i, (rgb, depth, noisy_rgb, noisy_depth) in enumerate(islice(render_frames(spec, motion), n)):
        stats.add(rgb, depth, noisy_depth)
        if len(samples) < keep and i % max(1, n // max(keep, 1)) == 0:
            samples.append((rgb, noisy_rgb, depth, noisy_depth))
    return stats, samples


def merge_images(parts: list[ImageStats]) -> ImageStats:
    """Sum several :class:`ImageStats`."""
    out = ImageStats()
    for p in parts:
        out.grey_mean += p.grey_mean
        out.grey_std += p.grey_std
        out.pixels += p.pixels
        out.holes += p.holes
        out.zero += p.zero
        out.bin_n, out.bin_sum = out.bin_n + p.bin_n, out.bin_sum + p.bin_sum
        out.bin_sq, out.bin_outliers = out.bin_sq + p.bin_sq, out.bin_outliers + p.bin_outliers
        out.hole_map = p.hole_map if out.hole_map is None else out.hole_map + p.hole_map
        out.frames += p.frames
    return out


def summarize_motion(stats: list[MotionStats]) -> dict:
    """Action mix and collision rate per action (%), distances, ratios and lengths."""
    from odolab.core.types import MOTION_ACTIONS

    acts = np.concatenate([s.actions for s in stats]).astype(int)
    hits = np.concatenate([s.collisions for s in stats]).astype(bool)
    out = {"episodes": len(stats), "steps": len(acts), "mix_pct": {}, "collisions_pct": {}}
    for a in MOTION_ACTIONS:
        sel = acts == a.value
        out["mix_pct"][a.label] = 100 * float(sel.mean())
        out["collisions_pct"][a.label] = 100 * float(hits[sel].mean()) if sel.any() else None  # null: no step
    out["collisions_pct"]["all"] = 100 * float(hits.mean())
    geo = np.array([s.geodesic for s in stats])
    ratio = geo / np.array([s.euclidean for s in stats])
    lengths = np.array([len(s.actions) for s in stats])
    out.update(
        geodesic_m=geo.tolist(),
        ratio=ratio.tolist(),
        lengths=lengths.tolist(),
        reached_pct=100 * float(np.mean([s.reached for s in stats])),
        worst_collisions=int(max(sum(s.collisions) for s in stats)),
    )
    return out


def _fmt(v) -> str:
    return f"{v:.2f}" if isinstance(v, float) else str(v)


def card_table(motion: dict, images: ImageStats) -> list[tuple[str, str, str]]:
    """(statistic, odolab, reference) rows of the card."""
    c, m = motion["collisions_pct"], motion["mix_pct"]
    geo, ratio, lengths = (np.array(motion[k]) for k in ("geodesic_m", "ratio", "lengths"))
    rows = [
        (
            "collisions, % of steps: forward / left / right / all",
            " / ".join(
                "-" if c[k] is None else f"{c[k]:.1f}" for k in ("move_forward", "turn_left", "turn_right", "all")
            ),
            " / ".join(f"{PAPER_COLLISIONS[k]:.1f}" for k in ("move_forward", "turn_left", "turn_right", "all"))
            + " (paper, Table S2)",
        ),
        (
            "action mix, %: forward / left / right",
            " / ".join(f"{m[k]:.1f}" for k in PAPER_MIX),
            " / ".join(f"{v:.1f}" for v in PAPER_MIX.values()) + " (paper, Table S2)",
        ),
        (
            "geodesic start-goal distance, m: min / median / max",
            f"{geo.min():.1f} / {np.median(geo):.1f} / {geo.max():.1f}",
            "1-30 (habitat-lab PointNav generator)",
        ),
        (
            "episodes with geodesic / euclidean < 1.1, %",
            f"{100 * np.mean(ratio < 1.1):.1f}",
            "kept with probability 20 (r - 0.98)^2 <= 14.4 % (habitat-lab)",
        ),
        (
            "episode length, steps: median / max (goals reached %)",
            f"{np.median(lengths):.0f} / {lengths.max()} ({motion['reached_pct']:.0f})",
            "up to 500 (the task)",
        ),
        (
            "clean frames: grey mean, median over frames",
            f"{np.median(images.grey_mean):.0f}",
            "90-150 wanted; TUM fr1/xyz 137",
        ),
        (
            "clean frames: grey spread (std), median over frames",
            f"{np.median(images.grey_std):.0f}",
            ">= 40 wanted; TUM fr1/xyz 93",
        ),
        (
            "depth holes, % of pixels with a clean reading",
            f"{100 * images.holes / max(images.pixels, 1):.1f}",
            "about 11 % (habitat-sim's Redwood table: its hole cells)",
        ),
    ]
    return rows


def write_card(out: Path, motion: dict, images: ImageStats, samples: list[tuple], source: str, command: str) -> None:
    """card.json, card.md, motion.png, depth.png, frames.png under ``out`` (atomic writes)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from odolab.io.atomic import save_figure_atomic, write_text_atomic
    from odolab.reporting.report import OutputFolder

    folder = OutputFolder(
        out, "simcard", CARD_NAMES
    )  # a manifest: an interrupted run never leaves two runs' files mixed
    rows = card_table(motion, images)
    depth_rows = images.depth_rows()
    data = {
        "command": command,
        "redwood_table": source,
        "motion": motion,
        "images": {
            "frames": images.frames,
            "grey_mean": images.grey_mean,
            "grey_std": images.grey_std,
            "holes_pct": 100 * images.holes / max(images.pixels, 1),
            "depth_bins": depth_rows,
        },
        "table": [{"statistic": a, "odolab": b, "reference": c} for a, b, c in rows],
    }
    write_text_atomic(folder.path("card.json"), json.dumps(data, indent=1, default=float, allow_nan=False))
    md = [
        f"# The simulator in numbers\n\n`{command}`\n\nRedwood distortion table: {source}\n",
        "| statistic | odolab | reference |",
        "|---|---|---|",
    ]
    md += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    md += [
        "\n## Noisy / clean depth per clean-depth bin\n",
        "| depth m | pixels | bias % | spread % | outliers % |",
        "|---|---|---|---|---|",
    ]
    md += [
        f"| {r['depth_m']} | {r['pixels']} | {r['bias_pct']:+.2f} | {r['spread_pct']:.2f} | {r['outliers_pct']:.2f} |"
        for r in depth_rows
    ]
    md += ["\nFigures: `motion.png`, `depth.png`, `frames.png`."]
    write_text_atomic(folder.path("card.md"), "\n".join(md) + "\n")

    fig, ax = plt.subplots(2, 3, figsize=(15, 8))
    labels = ["move_forward", "turn_left", "turn_right"]
    x = np.arange(4)
    c = motion["collisions_pct"]
    ax[0, 0].bar(x - 0.2, [c[k] or 0.0 for k in labels + ["all"]], 0.4, label="odolab (no bar: no step)")
    ax[0, 0].bar(x + 0.2, [PAPER_COLLISIONS[k] for k in labels + ["all"]], 0.4, label="paper (Table S2)")
    ax[0, 0].set(
        xticks=x,
        xticklabels=["forward", "left", "right", "all"],
        ylabel="collided steps (%)",
        title="Collision rate per action",
    )
    ax[0, 0].legend()
    x3 = np.arange(3)
    ax[0, 1].bar(x3 - 0.2, [motion["mix_pct"][k] for k in labels], 0.4, label="odolab")
    ax[0, 1].bar(x3 + 0.2, [PAPER_MIX[k] for k in labels], 0.4, label="paper (Table S2)")
    ax[0, 1].set(xticks=x3, xticklabels=["forward", "left", "right"], ylabel="share of steps (%)", title="Action mix")
    ax[0, 1].legend()
    ax[0, 2].hist(motion["lengths"], bins=30, color="C2")
    ax[0, 2].set(xlabel="episode length (steps)", ylabel="episodes", title="Episode length")
    ax[1, 0].hist(motion["geodesic_m"], bins=30, range=(0, 30), color="C0")
    ax[1, 0].axvline(1, color="k", ls="--", lw=1, label="habitat-lab range 1-30 m")
    ax[1, 0].set(xlabel="geodesic start-goal distance (m)", ylabel="episodes", title="Geodesic distance")
    ax[1, 0].legend()
    ax[1, 1].hist(np.clip(motion["ratio"], 1, 3), bins=40, range=(1, 3), color="C1")
    ax[1, 1].axvline(1.1, color="k", ls="--", lw=1, label="1.1: below mostly rejected")
    ax[1, 1].set(xlabel="geodesic / euclidean distance (clipped at 3)", ylabel="episodes", title="Path ratio")
    ax[1, 1].legend()
    ax[1, 2].hist(images.grey_std, bins=30, color="C4", alpha=0.7, label="grey std")
    ax[1, 2].hist(images.grey_mean, bins=30, color="C5", alpha=0.7, label="grey mean")
    ax[1, 2].axvline(40, color="C4", ls="--", lw=1, label="std >= 40 wanted")
    ax[1, 2].set(xlabel="grey level (0-255), clean frames", ylabel="frames", title="Image brightness and contrast")
    ax[1, 2].legend()
    fig.suptitle(f"odolab simulator: {motion['episodes']} episodes, {motion['steps']} steps")
    fig.tight_layout()
    save_figure_atomic(fig, folder.path("motion.png"))
    plt.close(fig)

    fig, ax = plt.subplots(1, 2, figsize=(13, 4.5))
    centres = [float(r["depth_m"].split("-")[0]) + 0.5 for r in depth_rows]
    ax[0].plot(centres, [r["bias_pct"] for r in depth_rows], "o-", label="bias: mean(noisy / clean) - 1")
    ax[0].plot(centres, [r["spread_pct"] for r in depth_rows], "s-", label="spread: std(noisy / clean)")
    ax[0].axhline(0, color="k", lw=0.5)
    ax[0].set(xlabel="clean depth (m)", ylabel="relative depth error (%)", title="Redwood depth noise per depth")
    ax[0].legend()
    if images.hole_map is not None:
        im = ax[1].imshow(100 * images.hole_map / max(images.frames, 1), cmap="magma", vmin=0, vmax=100)
        fig.colorbar(im, ax=ax[1], label="frames with a hole (%)")
    ax[1].set(
        title=f"Depth holes per pixel ({100 * images.holes / max(images.pixels, 1):.1f} % of pixels)",
        xlabel="image column (px)",
        ylabel="image row (px)",
    )
    fig.tight_layout()
    save_figure_atomic(fig, folder.path("depth.png"))
    plt.close(fig)

    if samples:
        fig, ax = plt.subplots(len(samples), 4, figsize=(16, 2.4 * len(samples)), squeeze=False)
        for i, (rgb, nrgb, d, nd) in enumerate(samples):
            for j, (img, title) in enumerate(
                ((rgb, "clean RGB"), (nrgb, "noisy RGB"), (d, "clean depth (m)"), (nd, "noisy depth (m), black = none"))
            ):
                kw = {} if img.ndim == 3 else {"cmap": "viridis", "vmin": 0, "vmax": 10}
                ax[i, j].imshow(img, **kw)
                ax[i, j].set_axis_off()
                if i == 0:
                    ax[i, j].set_title(title)
        fig.tight_layout()
        save_figure_atomic(fig, folder.path("frames.png"), dpi=80)
        plt.close(fig)
    folder.finish()


@dataclass(frozen=True)
class CardConfig:
    """What the card measures: ``episodes`` rollouts of at most ``max_steps`` steps for the motion
    statistics and ``rendered`` episodes of ``frames`` frames for the image statistics, of ``split``
    from ``seed``."""

    split: str = setting("train", doc="scene split")
    episodes: int = setting(400, range=(1, 100_000), doc="rollouts for the motion statistics")
    rendered: int = setting(24, range=(1, 1000), doc="episodes rendered for the image statistics")
    frames: int = setting(30, range=(1, 500), doc="frames per rendered episode")
    max_steps: int = setting(500, range=(1, 2000), doc="steps per episode")
    seed: int = setting(0, range=SEED_RANGE, doc="episode seed")

    def __post_init__(self) -> None:
        check(self)
        if self.split not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {self.split!r:.80}")


def measure(
    config: CardConfig,
    *,
    family: str = "boxes",
    scenes=None,
    execution: Execution = Execution(),
) -> tuple[dict, ImageStats, list[tuple]]:
    """The card's numbers (:class:`CardConfig`): the motion summary of the rollouts, the image
    statistics of the rendered episodes, and the sample frames of the first four (for the contact
    sheet), in procedural scenes of ``family`` or in mesh ``scenes``
    (:class:`odolab.sim.mesh_scenes.SceneFiles`); as Ray tasks (:func:`odolab.core.parallel.fan_out`)
    unless ``execution.parallel`` is False."""
    from odolab.sim.episodes import EpisodeSpec

    def spec(i: int, steps: int) -> EpisodeSpec:
        return EpisodeSpec(split=config.split, index=i, seed=config.seed, max_steps=steps, family=family, scenes=scenes)

    specs = [spec(i, config.max_steps) for i in range(config.episodes)]
    motion = summarize_motion(fan_out(motion_stats, specs, desc="rollouts", execution=execution))
    shown = [spec(i, config.frames) for i in range(config.rendered)]
    parts = fan_out(
        _render_part,
        [(s, config.frames, 1 if i < 4 else 0) for i, s in enumerate(shown)],
        desc="rendered episodes",
        execution=execution,
    )
    return motion, merge_images([p for p, _ in parts]), [s for _, ss in parts for s in ss]


def _render_part(job: tuple) -> tuple[ImageStats, list[tuple]]:
    spec, frames, keep = job
    return render_stats(spec, frames, keep)


if __name__ == "__main__":  # python -m odolab.simcard: the command line is odolab.cli.simcard's
    import runpy

    runpy.run_module("odolab.cli.simcard", run_name="__main__", alter_sys=True)
