"""Pose-graph fusion of several odometers (GTSAM): the graph (:mod:`.graph`), per-input covariance
calibration (:mod:`.calibration`, ``python -m odolab.fusion.calibrate``) and the ``fused(...)``
odometer (:mod:`.odometer`)."""
