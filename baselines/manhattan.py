"""``manhattan(inner)``: another odometer's heading held to the walls of a Manhattan world.

Runs ``inner`` unchanged and corrects only its yaw, with a one-state Kalman filter on the heading
since the sequence start (radians, counter-clockwise): each step predicts by the inner odometer's
yaw (the action prior's where the inner step fails) and measures :func:`wall_direction` of the
current depth image, modulo 90 degrees. The first ``anchor_steps`` views fix the world's wall
direction (:func:`anchor_direction`); later views within 3 sigma of the prediction correct the
heading, and ``relock_views`` agreeing views beyond that gate re-lock it (the inner odometer, not
the walls, is taken to have jumped). The answer is the inner transform followed by the correction's
rotation about the vertical axis; a correction due on a failed step goes to the next answered one.

Why: most indoor walls meet at right angles, so their direction is a heading cue that does not
drift (the "Manhattan frame" of structured-scene VO, e.g. Kim et al., ICRA 2018). It assumes a
level camera moving in the plane (details and measurements: docs/odometers.md#manhattaninner).

    python -m odolab.compare --odometers 'open3d-rgbd,manhattan(open3d-rgbd)'
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

import numpy as np

from odolab.api import (
    Action,
    Estimate,
    Frame,
    Intrinsics,
    Odometer,
    check,
    configure,
    failure_reason,
    load_inputs,
    load_odometer,
    planar_to_transform,
    setting,
    split_odometer_names,
)

#: Vertical surfaces agree on a direction when within this of their mean (deg, modulo 90).
INLIER_DEG = 10.0
#: Anchor views agree on the world's wall direction when within this of each other (deg, modulo 90).
ANCHOR_DEG = 3.0


@dataclass(frozen=True)
class WallDirection:
    """The dominant direction of a view's vertical surfaces: ``angle`` (rad, in (-pi/4, pi/4]) of
    their normals in the camera's x-z plane (``atan2(n_x, n_z)``, modulo 90 degrees), ``support``
    (the share of vertical-surface samples within :data:`INLIER_DEG` of it) and ``samples``."""

    angle: float
    support: float
    samples: int


def wall_direction(
    depth: np.ndarray,
    intrinsics: Intrinsics,
    max_depth: float = 4.0,
    stride: int = 4,
    baseline: int = 2,
    max_vertical: float = 0.15,
    min_samples: int = 30,
) -> WallDirection | None:
    """The walls' direction in a depth image (H, W, metres; 0 = no reading), or None when fewer than
    ``min_samples`` vertical-surface samples agree.

    Pixels on a ``stride`` grid are back-projected; each sample's normal is the cross product of the
    steps to its neighbours ``baseline`` grid cells right and down (skipped across depth edges of
    more than 10 %, and beyond ``max_depth``, where depth noise tilts the surfaces); samples whose
    normal has a vertical (camera y) part above ``max_vertical`` are floor, ceiling or clutter. Their
    horizontal angles, times 4, are averaged on the unit circle (so walls at right angles agree),
    twice: the second time only over samples within :data:`INLIER_DEG` of the first mean.
    """
    K = intrinsics
    d = np.asarray(depth, np.float64)[::stride, ::stride]
    d = np.where(np.isfinite(d), d, 0.0)  # no reading
    v, u = np.mgrid[0 : depth.shape[0] : stride, 0 : depth.shape[1] : stride].astype(np.float64)
    points = np.stack([(u - K.cx) / K.fx * d, (v - K.cy) / K.fy * d, d], axis=-1)
    b = baseline
    here, right, down = d[:-b, :-b], d[:-b, b:], d[b:, :-b]
    ok = (here > 0) & (right > 0) & (down > 0) & (here < max_depth)
    ok &= (np.abs(right - here) < 0.1 * here) & (np.abs(down - here) < 0.1 * here)
    normal = np.cross(points[:-b, b:] - points[:-b, :-b], points[b:, :-b] - points[:-b, :-b])
    length = np.linalg.norm(normal, axis=-1)
    ok &= length > 0
    normal = normal[ok] / length[ok][:, None]
    normal = normal[np.abs(normal[:, 1]) < max_vertical]
    if len(normal) < min_samples:
        return None
    z = np.exp(4j * np.arctan2(normal[:, 0], normal[:, 2]))
    first = np.mean(z)
    if abs(first) == 0:
        return None
    inliers = np.abs(np.angle(z * np.conj(first))) < np.radians(4 * INLIER_DEG)
    if inliers.sum() < min_samples:
        return None
    return WallDirection(float(np.angle(np.mean(z[inliers])) / 4), float(inliers.mean()), int(inliers.sum()))


def wrap_quarter(a: float) -> float:
    """An angle (rad) modulo 90 degrees, in (-pi/4, pi/4]."""
    return float(np.angle(np.exp(4j * a)) / 4)


def anchor_direction(views: list[tuple[float, int]]) -> float:
    """The world's wall direction (rad, modulo 90 degrees) from anchor views' (implied direction
    rad, sample count): the sample-weighted mean of the largest group within :data:`ANCHOR_DEG` of
    one of them (ties: the group with more samples), so a stray view does not pull it."""
    views = list(views)
    angles = np.array([a for a, _ in views], np.float64)
    weights = np.array([n for _, n in views], np.float64)
    if not len(views) or not np.isfinite(angles).all() or not (np.isfinite(weights) & (weights > 0)).all():
        raise ValueError(
            f"anchor_direction needs views with finite angles and positive sample counts, got {views!r:.200}"
        )
    near = np.abs(np.angle(np.exp(4j * (angles[:, None] - angles[None, :])))) / 4 <= np.radians(ANCHOR_DEG)
    score = [(int(row.sum()), float(weights[row].sum())) for row in near]
    group = near[max(range(len(views)), key=lambda i: score[i])]
    return float(np.angle(np.sum(weights[group] * np.exp(4j * angles[group]))) / 4)


@dataclass(frozen=True)
class ManhattanConfig:
    """The heading filter of :class:`ManhattanOdometer` (module docstring; in full:
    docs/odometers.md#manhattaninner); its constructor's keyword arguments of the same names. Angles
    in degrees."""

    step_sigma_deg: float = setting(0.3, range=(1e-3, 45.0), doc="heading noise of an answered step, deg")
    prior_sigma_deg: float = setting(3.5, range=(1e-3, 45.0), doc="heading noise of a failed step (action prior), deg")
    wall_sigma_deg: float = setting(1.0, range=(1e-3, 45.0), doc="noise of a view's wall direction, deg")
    anchor_steps: int = setting(5, range=(1, 1000), doc="first views that fix the world's wall direction")
    relock_views: int = setting(5, range=(0, 1000), doc="agreeing views beyond the gate that re-lock it (0: off)")
    relock_spread_deg: float = setting(2.0, range=(0.0, 45.0), doc="... agreeing within this of each other, deg")
    relock_support: float = setting(0.9, range=(0.0, 1.0), doc="... each with this share of samples on the walls")
    min_support: float = setting(0.3, range=(0.0, 1.0), doc="a view's share of samples on the walls to count at all")
    max_depth: float = setting(4.0, range=(0.5, 20.0), doc="wall samples beyond this are not used, m")

    def __post_init__(self) -> None:
        check(self, "manhattan: ")


class ManhattanOdometer(Odometer):
    """``inner``'s answers with its heading held to the walls (module docstring). Options: the
    fields of :class:`ManhattanConfig` (kept as ``config``); ``options_file``: the inner odometer's
    options (TOML, ``[odometers."icp"]``)."""

    composite = True

    Config = ManhattanConfig  # its options: every field of ManhattanConfig (odolab.odometry.configured)

    def __init__(
        self, inputs: str = "", config: ManhattanConfig | None = None, options_file: str = "", **overrides
    ) -> None:
        names = split_odometer_names(inputs) if isinstance(inputs, str) else []
        if len(names) != 1:
            raise ValueError(
                f"manhattan takes one inner odometer, e.g. manhattan(open3d-rgbd), got {len(names)}"
                + (f" ({', '.join(names)})" if names else "")
            )
        if names[0].startswith("manhattan"):
            raise ValueError(f"manhattan({names[0]}) would hold the heading to the walls twice; use one manhattan(...)")
        self.config = cfg = configure(ManhattanConfig, config, **overrides)
        self.inner = load_inputs("manhattan", names, options_file)[names[0]]
        self.prior = load_odometer("action-prior")
        self.step_var, self.prior_var = np.radians(cfg.step_sigma_deg) ** 2, np.radians(cfg.prior_sigma_deg) ** 2
        self.wall_var = np.radians(cfg.wall_sigma_deg) ** 2
        self.anchor_steps, self.min_support, self.max_depth = cfg.anchor_steps, cfg.min_support, cfg.max_depth
        self.relock_views, self.relock_spread = cfg.relock_views, np.radians(cfg.relock_spread_deg)
        self.relock_support = cfg.relock_support
        self.oracle, self.needs_action = self.inner.oracle, self.inner.needs_action
        self.threads = self.inner.threads
        sigmas = ";".join(str(v) for v in (cfg.step_sigma_deg, cfg.prior_sigma_deg, cfg.wall_sigma_deg))  # floats
        settings = (
            f"{names[0]}={self.inner.identity_digest};{sigmas};"
            f"{cfg.anchor_steps};{cfg.relock_views};{cfg.relock_spread_deg};{cfg.relock_support};"
            f"{cfg.min_support};{cfg.max_depth};"
            f"anchor-consensus-{ANCHOR_DEG}"
        )
        self.identity_digest = hashlib.sha256(settings.encode()).hexdigest()
        self._reset_state()

    def _reset_state(self) -> None:
        self.heading = 0.0  # rad since the sequence start, counter-clockwise (the planar dyaw's sign)
        self.variance = 0.0
        self.world: float | None = None  # the walls' direction in the start frame, modulo 90 degrees
        self._anchor: list[tuple[float, int]] = []  # (implied world direction rad, samples) of the first views
        self._rejected: list[float] = []  # innovations (rad) of the views in a row beyond the gate
        self._pending = 0.0  # a correction made on a failed step, for the next answered one
        self._steps = 0

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        self.inner.reset(intrinsics)
        self.prior.reset(intrinsics)
        self._reset_state()

    def _observe(self, frame: Frame) -> float:
        """Fold the view's wall direction into the heading; returns the correction (rad) made."""
        wall = wall_direction(frame.depth, self.intrinsics, self.max_depth)
        if wall is None or wall.support < self.min_support:
            return 0.0
        # a wall of world direction w appears at w + heading in the camera (camera x right, yaw left)
        implied = wrap_quarter(wall.angle - self.heading)
        if self.world is None or len(self._anchor) < self.anchor_steps:
            self._anchor.append((implied, wall.samples))
            self.world = anchor_direction(self._anchor)
            return 0.0
        innovation = wrap_quarter(implied - self.world)  # heading error, as the walls see it
        if innovation**2 > 9.0 * (self.variance + self.wall_var):
            if not self.relock_views or wall.support < self.relock_support:
                return 0.0
            self._rejected.append(innovation)
            recent = self._rejected[-self.relock_views :]
            if len(recent) < self.relock_views or max(recent) - min(recent) > self.relock_spread:
                return 0.0
            self.variance = max(self.variance, float(np.mean(recent)) ** 2)  # the inner odometer jumped
        self._rejected.clear()
        gain = self.variance / (self.variance + self.wall_var)
        correction = gain * innovation
        self.heading += correction
        self.variance *= 1.0 - gain
        return correction

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        if self._steps == 0:
            self._observe(prev)  # the start view anchors too
        self._steps += 1
        try:
            est = self.inner.step(prev, cur, action)
        except Exception:
            if action is not Action.STOP:
                self._advance(prev, cur, action, None)
            raise  # the runner records it and uses the action prior, which the heading has followed
        if action is Action.STOP:
            return est
        answered = failure_reason(est) is None
        self._advance(prev, cur, action, est if answered else None)
        if not answered:
            return est
        turn, self._pending = self._pending, 0.0
        return Estimate(
            np.asarray(est.transform, np.float64) @ planar_to_transform(0.0, 0.0, turn), covariance=est.covariance
        )

    def _advance(self, prev: Frame, cur: Frame, action: Action | None, est: Estimate | None) -> None:
        """Predict the heading by ``est`` (None: the step failed, the action prior's motion) and
        observe the current view; a correction is kept for the next answered step."""
        motion = est if est is not None else self.prior.step(prev, cur, action)
        self.heading += float(motion.planar[2])
        self.variance += self.step_var if est is not None else self.prior_var
        self._pending += self._observe(cur)
