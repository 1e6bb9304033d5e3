"""odolab's value types: what flows between the simulator, sequences, odometers and the runner.

:class:`Action` (with the task's nominal motions), :class:`Intrinsics`, :class:`Frame`,
:class:`Estimate` and the :class:`Sequence` protocol. Conventions (frames, planar motion) are
those of :mod:`odolab.core.geometry`. This module knows no odometer, no file format and no simulator.
"""

from __future__ import annotations

import enum
import numbers
from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np

from odolab.core.geometry import planar_to_transform, transform_to_planar

__all__ = [
    "FORWARD_STEP",
    "MOTION_ACTIONS",
    "TURN_ANGLE",
    "Action",
    "Estimate",
    "Frame",
    "Intrinsics",
    "Sequence",
    "as_action",
    "nominal_motion",
    "nominal_planar",
]


class Action(enum.Enum):
    """Discrete actions of the PointNav task (Habitat PointNav Challenge 2020)."""

    STOP = 0
    MOVE_FORWARD = 1
    TURN_LEFT = 2
    TURN_RIGHT = 3

    @property
    def label(self) -> str:
        """Lower-case name as the paper writes it, e.g. ``move_forward``."""
        return self.name.lower()


MOTION_ACTIONS = (Action.MOVE_FORWARD, Action.TURN_LEFT, Action.TURN_RIGHT)


def as_action(value: object) -> Action | None:
    """``value`` as an :class:`Action`: an Action or None as it is, an integer 0-3 (numpy's too,
    as a saved episode's ``actions`` hold them) as the Action of that value; ``TypeError`` naming
    what was expected for anything else (a bool, a name, 7)."""
    if value is None or isinstance(value, Action):
        return value
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)) and 0 <= int(value) <= 3:
        return Action(int(value))
    raise TypeError(f"action: expected an Action (or its value, 0-3) or None, got {value!r}")


#: The commanded (noiseless) motions of the PointNav Challenge 2020 task (Habitat's
#: ``challenge_pointnav2020.local.rgbd.yaml``: ``FORWARD_STEP_SIZE: 0.25``, ``TURN_ANGLE: 30``).
FORWARD_STEP = 0.25  # m
TURN_ANGLE = float(np.radians(30.0))  # rad


def nominal_planar(action: Action | None) -> tuple[float, float, float]:
    """``(dx m, dz m, dyaw rad)`` of an action's noiseless motion; zero for STOP or no action."""
    if action is Action.MOVE_FORWARD:
        return 0.0, FORWARD_STEP, 0.0
    if action is Action.TURN_LEFT:
        return 0.0, 0.0, TURN_ANGLE
    if action is Action.TURN_RIGHT:
        return 0.0, 0.0, -TURN_ANGLE
    return 0.0, 0.0, 0.0


def nominal_motion(action: Action | None) -> np.ndarray:
    """``T_prev_cur`` (4x4, camera axes) of an action's noiseless motion; identity for STOP or none."""
    return planar_to_transform(*nominal_planar(action))


@dataclass(frozen=True)
class Intrinsics:
    """Pinhole intrinsics in pixels; the image is ``width`` x ``height``.

    Pixel convention (OpenCV's, used everywhere in odolab): the pixel in column ``i`` and row ``j``
    has its centre at image coordinates (u, v) = (i, j) and sees the ray
    ((u - cx) / fx, (v - cy) / fy, 1); the image spans u in [-0.5, width - 0.5]. A centred principal
    point is therefore cx = (width - 1) / 2, cy = (height - 1) / 2.
    """

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int

    @property
    def matrix(self) -> np.ndarray:
        """The 3x3 camera matrix K."""
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])

    @classmethod
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> Intrinsics:
        """Square-pixel pinhole, principal point at the image centre, whose horizontal field of view
        (degrees) spans the whole image width (edge to edge: ``fx = width / 2 / tan(hfov / 2)``)."""
        f = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
        return cls(f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height)

    def resized(self, width: int, height: int) -> Intrinsics:
        """The same camera seen through an image resized (stretched) to ``width`` x ``height``: pixel
        edges map to pixel edges, so u' = (u + 0.5) * width / self.width - 0.5 (likewise v)."""
        sx, sy = width / self.width, height / self.height
        return Intrinsics(
            float(self.fx * sx),
            float(self.fy * sy),
            float((self.cx + 0.5) * sx - 0.5),
            float((self.cy + 0.5) * sy - 0.5),
            int(width),
            int(height),
        )


@dataclass(frozen=True)
class Frame:
    """One RGB-D observation.

    ``rgb``: (H, W, 3) uint8. ``depth``: (H, W) float32 metres, 0 = no reading.
    ``timestamp``: seconds. ``gt_pose``: ``T_world_cam`` 4x4 when ground truth exists;
    ``clean_depth``: the simulator's noiseless depth (H, W) float32 m of the same view, when the
    frame is simulated. Only oracle odometers (see :attr:`Odometer.oracle`) may read these two.
    """

    rgb: np.ndarray
    depth: np.ndarray
    timestamp: float = 0.0
    gt_pose: np.ndarray | None = field(default=None, repr=False)
    clean_depth: np.ndarray | None = field(default=None, repr=False)

    def __post_init__(self) -> None:
        """``ValueError`` naming the field for arrays that cannot be an RGB-D frame (an odometer
        would otherwise fail deep inside OpenCV or Open3D, or answer for the wrong pixels)."""
        rgb, depth = self.rgb, self.depth
        if not isinstance(depth, np.ndarray) or depth.ndim != 2:
            raise ValueError(
                f"Frame.depth: expected an (H, W) array of metres, got {getattr(depth, 'shape', type(depth).__name__)}"
            )
        if not isinstance(rgb, np.ndarray) or rgb.ndim != 3 or rgb.shape[2] != 3:
            raise ValueError(f"Frame.rgb: expected an (H, W, 3) array, got {getattr(rgb, 'shape', type(rgb).__name__)}")
        if rgb.shape[:2] != depth.shape:
            raise ValueError(
                f"Frame: rgb is {rgb.shape[0]}x{rgb.shape[1]} pixels but depth {depth.shape[0]}x{depth.shape[1]}"
            )
        clean = self.clean_depth
        if clean is not None and (not isinstance(clean, np.ndarray) or clean.shape != depth.shape):
            raise ValueError(
                f"Frame.clean_depth: expected an array of the depth's shape {depth.shape}, "
                f"got {getattr(clean, 'shape', type(clean).__name__)}"
            )


@dataclass(frozen=True)
class Estimate:
    """An odometer's answer for one frame pair.

    ``transform``: 4x4 ``T_prev_cur`` (camera axes, metres). ``valid``: False when the odometer
    could not estimate (the runner then falls back to the action prior and counts a failure).
    ``covariance``: 6x6 over (rx, ry, rz, tx, ty, tz) in the previous camera frame, or None.
    ``unverified``: with ``valid=False``, the 4x4 ``T_prev_cur`` the odometer computed and then
    refused (its own checks failed), which the paper's protocol scores; None when it computed none.
    """

    transform: np.ndarray
    valid: bool = True
    covariance: np.ndarray | None = None
    unverified: np.ndarray | None = None

    @classmethod
    def from_planar(cls, dx: float, dz: float, dyaw: float, **kw) -> Estimate:
        """Build from the paper's planar motion (signs: :mod:`odolab.core.geometry`)."""
        return cls(planar_to_transform(dx, dz, dyaw), **kw)

    @classmethod
    def invalid(cls, unverified: np.ndarray | None = None) -> Estimate:
        """An estimate that says 'I could not tell' (identity transform, ``valid=False``), keeping
        the refused ``T_prev_cur`` as ``unverified`` when one was computed."""
        return cls(np.eye(4), valid=False, unverified=unverified)

    @property
    def planar(self) -> np.ndarray:
        """``(dx m, dz m, dyaw rad)`` in the previous agent frame."""
        return transform_to_planar(self.transform)


@runtime_checkable
class Sequence(Protocol):
    """What the runner consumes: simulated episodes and real recordings alike.

    ``name``: a short label for reports (e.g. ``test-s0-e003`` or the folder name).
    ``collisions``: (len - 1,) bool, True where the step's translation was blocked, or None when
    unknown (real data).
    """

    intrinsics: Intrinsics

    @property
    def name(self) -> str: ...

    @property
    def collisions(self) -> np.ndarray | None: ...

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> Frame: ...

    def action(self, i: int) -> Action | None:
        """The action taken between frame ``i`` and ``i + 1`` (None on real data)."""
        ...

    def gt_pose(self, i: int) -> np.ndarray | None:
        """``T_world_cam`` of frame ``i``, or None."""
        ...
