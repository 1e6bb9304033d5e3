"""The one interface every odometer implements, its value types, and the name registry.

An odometer sees a sequence of :class:`Frame` pairs and answers, for each pair, an
:class:`Estimate` of ``T_prev_cur`` (conventions in :mod:`odolab.geometry`)::

    odo = load_odometer("icp")
    odo.reset(intrinsics)
    for prev, cur, action in pairs:
        est = odo.step(prev, cur, action)   # est.transform: 4x4, est.valid: bool

Odometers are found by name: built-ins and third-party packages declare an entry point in the
group ``odolab.odometers``; a class can also be registered in code with :func:`register_odometer`,
or named directly as ``"package.module:Class"``.
Heavy imports happen when an odometer is loaded, not when :mod:`odolab` is imported.
"""
from __future__ import annotations

import enum
import importlib
from dataclasses import dataclass, field
from importlib.metadata import entry_points
from typing import Callable, Iterator, Protocol, runtime_checkable

import numpy as np

from odolab.geometry import planar_to_transform, transform_to_planar

ENTRY_POINT_GROUP = "odolab.odometers"


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
    def from_hfov(cls, width: int, height: int, hfov_deg: float) -> "Intrinsics":
        """Square-pixel pinhole, principal point at the image centre, whose horizontal field of view
        (degrees) spans the whole image width (edge to edge: ``fx = width / 2 / tan(hfov / 2)``)."""
        f = (width / 2.0) / np.tan(np.radians(hfov_deg) / 2.0)
        return cls(f, f, (width - 1) / 2.0, (height - 1) / 2.0, width, height)


@dataclass(frozen=True)
class Frame:
    """One RGB-D observation.

    ``rgb``: (H, W, 3) uint8. ``depth``: (H, W) float32 metres, 0 = no reading.
    ``timestamp``: seconds. ``gt_pose``: ``T_world_cam`` 4x4 when ground truth exists; only
    oracle odometers (see :attr:`Odometer.oracle`) may read it.
    """

    rgb: np.ndarray
    depth: np.ndarray
    timestamp: float = 0.0
    gt_pose: np.ndarray | None = field(default=None, repr=False)


@dataclass(frozen=True)
class Estimate:
    """An odometer's answer for one frame pair.

    ``transform``: 4x4 ``T_prev_cur`` (camera axes, metres). ``valid``: False when the odometer
    could not estimate (the runner then falls back to the action prior and counts a failure).
    ``covariance``: 6x6 over (rx, ry, rz, tx, ty, tz) in the previous camera frame, or None.
    """

    transform: np.ndarray
    valid: bool = True
    covariance: np.ndarray | None = None

    @classmethod
    def from_planar(cls, dx: float, dz: float, dyaw: float, **kw) -> "Estimate":
        """Build from the paper's planar motion (signs: :mod:`odolab.geometry`)."""
        return cls(planar_to_transform(dx, dz, dyaw), **kw)

    @classmethod
    def invalid(cls) -> "Estimate":
        """An estimate that says 'I could not tell' (identity transform, ``valid=False``)."""
        return cls(np.eye(4), valid=False)

    @property
    def planar(self) -> np.ndarray:
        """``(dx m, dz m, dyaw rad)`` in the previous agent frame."""
        return transform_to_planar(self.transform)


@runtime_checkable
class Sequence(Protocol):
    """What the runner consumes: simulated episodes and real recordings alike."""

    intrinsics: Intrinsics

    def __len__(self) -> int: ...

    def __getitem__(self, i: int) -> Frame: ...

    def action(self, i: int) -> Action | None:
        """The action taken between frame ``i`` and ``i + 1`` (None on real data)."""
        ...

    def gt_pose(self, i: int) -> np.ndarray | None:
        """``T_world_cam`` of frame ``i``, or None."""
        ...


class Odometer:
    """Base class of all odometers. Subclass it and override :meth:`step` (and :meth:`reset`).

    Class attributes: ``name`` (registry key), ``oracle`` (True if it reads ground truth, e.g.
    ``Frame.gt_pose``; reports mark such rows).
    """

    name: str = "odometer"
    oracle: bool = False
    _intrinsics: Intrinsics | None = None

    @property
    def intrinsics(self) -> Intrinsics:
        """The camera of the current sequence (set by :meth:`reset`)."""
        if self._intrinsics is None:
            raise RuntimeError(f"{type(self).__name__}: call reset(intrinsics) before step()")
        return self._intrinsics

    @intrinsics.setter
    def intrinsics(self, value: Intrinsics) -> None:
        self._intrinsics = value

    def reset(self, intrinsics: Intrinsics) -> None:
        """Start a new sequence seen through a camera with these intrinsics."""
        self.intrinsics = intrinsics

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        """Estimate ``T_prev_cur`` for one consecutive frame pair; ``action`` is None on real data."""
        raise NotImplementedError(f"{type(self).__name__} must implement step()")


class UnknownOdometerError(KeyError):
    """Raised by :func:`load_odometer` for a name nobody registered."""

    def __str__(self) -> str:  # KeyError quotes its message; we want it plain
        return str(self.args[0])


def _registry() -> dict[str, Callable[..., Odometer] | str]:
    """Name -> class or "module:attr" string, from entry points (installed built-ins included)."""
    reg: dict[str, Callable[..., Odometer] | str] = {
        "ground-truth": "odolab.reference_odometers:GroundTruthOdometer",
        "action-prior": "odolab.reference_odometers:ActionPriorOdometer",
    }
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        reg.setdefault(ep.name, ep.value)
    return reg


class OdometerRegistry:
    """Names to odometer factories: entry points plus classes registered in code."""

    def __init__(self) -> None:
        self._extra: dict[str, Callable[..., Odometer]] = {}

    def register(self, name: str, factory: Callable[..., Odometer]) -> None:
        """Make ``factory`` (usually an :class:`Odometer` subclass) loadable as ``name``."""
        self._extra[name] = factory

    def names(self) -> list[str]:
        """All loadable names, sorted."""
        return sorted({**_registry(), **self._extra})

    def resolve(self, name: str) -> Callable[..., Odometer]:
        """The factory for ``name``; :class:`UnknownOdometerError` lists the valid choices."""
        target = self._extra.get(name) or _registry().get(name)
        if target is None and ":" in name:  # "package.module:Class", imported on demand
            target = name
        if target is None:
            raise UnknownOdometerError(
                f"unknown odometer {name!r}; available: {', '.join(self.names())}"
            )
        if isinstance(target, str):
            module, _, attr = target.partition(":")
            try:
                obj = importlib.import_module(module)
                for part in attr.split("."):
                    obj = getattr(obj, part)
            except (ImportError, AttributeError) as exc:
                raise UnknownOdometerError(f"odometer {name!r}: cannot import {target!r} ({exc})") from None
            return obj
        return target

    def load(self, name: str, **options) -> Odometer:
        """Instantiate odometer ``name`` with keyword ``options``."""
        odo = self.resolve(name)(**options)
        odo.name = name
        return odo

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())


#: The default registry behind :func:`load_odometer` and friends.
REGISTRY = OdometerRegistry()


def register_odometer(name: str, factory: Callable[..., Odometer]) -> None:
    """Register a class (or any callable returning an :class:`Odometer`) under ``name``."""
    REGISTRY.register(name, factory)


def available_odometers() -> list[str]:
    """Names :func:`load_odometer` accepts."""
    return REGISTRY.names()


def load_odometer(name: str, **options) -> Odometer:
    """Instantiate a registered odometer by name."""
    return REGISTRY.load(name, **options)
