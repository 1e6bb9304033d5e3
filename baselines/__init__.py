"""Odometers other than odolab's own, written only against :mod:`odolab.api`.

They read like KISS-ICP's ``register_frame``: each takes one frozen config dataclass
(:class:`~baselines.icp.ICPConfig`, :class:`~baselines.open3d_rgbd.Open3DRGBDConfig`,
:class:`~baselines.feature_essential.FeatureEssentialConfig`,
:class:`~baselines.planar_depth.PlanarDepthConfig`; every threshold named, with its unit),
kept as ``odometer.config``. They share ``depth`` (the trusted range and the one depth-noise model,
:class:`~baselines.depth_geometry.DepthRange`) and ``verify`` (when the images confirm a motion,
:class:`~baselines.verification.VerifyConfig`). Keyword options override any field, nested or not:
``load_odometer("icp", max_depth=3.0, voxel=0.05)`` (each declares its ``Config``: :mod:`odolab.odometry.configured`).
"""
