"""Configuration of the baselines: what they all share.

Every odometer in ``baselines/`` takes one frozen config dataclass (``ICPConfig``,
``Open3DRGBDConfig``, ``FeatureEssentialConfig``, ``PlanarDepthConfig``), derived from
:class:`OdometerConfig`, its fields declared with :func:`odolab.api.setting` (a range, checked by
:func:`odolab.api.check`, and a one-line description), and keeps it as ``odometer.config`` (``dataclasses.asdict`` writes it
out); each odometer declares it as its ``Config`` (:mod:`odolab.odometry.configured`), so keyword
options override single fields wherever they sit: ``load_odometer("icp", max_depth=3.0, voxel=0.05)``
sets ``config.depth.max_depth`` and ``config.voxel``.
"""

from __future__ import annotations

from dataclasses import dataclass

from baselines.depth_geometry import DepthRange
from baselines.verification import VerifyConfig


@dataclass(frozen=True)
class OdometerConfig:
    """What every baseline shares: the depth readings it trusts and their noise model (``depth``),
    and when the images confirm a motion (``verify``)."""

    depth: DepthRange = DepthRange()
    verify: VerifyConfig = VerifyConfig()
