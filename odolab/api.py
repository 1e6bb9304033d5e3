"""odolab's public face: everything an odometer author or a script needs, in one import.

``baselines/`` and third-party odometers import only from here.
"""
from __future__ import annotations

from odolab.geometry import (
    integrate,
    invert,
    planar_to_transform,
    transform_to_planar,
    wrap_angle,
)
from odolab.odometer import (
    MOTION_ACTIONS,
    Action,
    Estimate,
    Frame,
    Intrinsics,
    Odometer,
    Sequence,
    UnknownOdometerError,
    available_odometers,
    load_odometer,
    register_odometer,
)

__all__ = [
    "MOTION_ACTIONS",
    "Action",
    "Estimate",
    "Frame",
    "Intrinsics",
    "Odometer",
    "Sequence",
    "UnknownOdometerError",
    "available_odometers",
    "integrate",
    "invert",
    "load_odometer",
    "load_tum_sequence",
    "planar_to_transform",
    "register_odometer",
    "transform_to_planar",
    "wrap_angle",
]


def load_tum_sequence(path, **options):
    """Read a TUM RGB-D folder as a :class:`Sequence` (see :mod:`odolab.io.tum_rgbd`)."""
    from odolab.io.tum_rgbd import load_tum_sequence as _load

    return _load(path, **options)
