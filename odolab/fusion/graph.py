"""The pose graph behind fusion: relative-pose factors between camera poses, solved online with
iSAM2 (causal) or in one batch with Levenberg-Marquardt (smoothing).

Conventions (GTSAM's): a pose is ``T_world_cam`` (4x4); a factor between poses i and j measures
``T_ij = inv(T_i) @ T_j`` and its covariance is over (rx, ry, rz, tx, ty, tz) of the *right*
perturbation, ``T_ij_true = T_ij @ exp(xi)`` (rotation first, radians then metres). odolab's
``Estimate.covariance`` is the *left* perturbation in the previous camera; :func:`right_covariance`
converts it.
"""

from __future__ import annotations

from dataclasses import dataclass

import gtsam
import numpy as np

from odolab.core.types import Estimate
from odolab.running.runner import failure_reason

#: Sigmas of the prior that pins the first pose (rad, rad, rad, m, m, m).
ANCHOR_SIGMAS = np.full(6, 1e-6)
KERNELS = ("huber", "cauchy", "none")
#: iSAM2 relinearises a pose whose estimate moved more than this (rad or m) since its last
#: linearisation. A robust kernel's weights are set at the linearisation point, so at 0.01 a step
#: stays weighted much as at its initial guess (the first input's answer). Letting each step settle
#: (1e-5, 5 iterations, started from the answer the others agree with best) was better on 40 val
#: episodes x 100 open-loop steps (yaw 0.258 against 0.275 degrees RMS per step) but worse in
#: navigation (the first 60 test episodes: 46 successes against 53, 1 won, 8 lost), so it is not
#: the default (README, "Navigate").
RELINEARIZE_THRESHOLD = 0.01


@dataclass(frozen=True)
class Measurement:
    """One relative-pose factor: ``T_ij`` (4x4) between poses ``i`` < ``j`` with covariance ``cov``
    (6x6, right perturbation, see the module docstring); ``source`` names who measured it."""

    i: int
    j: int
    T_ij: np.ndarray
    cov: np.ndarray
    source: str = ""


def right_covariance(T: np.ndarray, cov_left: np.ndarray) -> np.ndarray:
    """Covariance of ``exp(delta) @ T`` (left, previous frame) re-expressed as of ``T @ exp(xi)``:
    ``xi = Ad(inv(T)) delta``."""
    ad = gtsam.Pose3(np.asarray(T, np.float64)).inverse().AdjointMap()
    return ad @ np.asarray(cov_left, np.float64) @ ad.T


def left_covariance(T: np.ndarray, cov_right: np.ndarray) -> np.ndarray:
    """The inverse of :func:`right_covariance`: ``delta = Ad(T) xi``."""
    ad = gtsam.Pose3(np.asarray(T, np.float64)).AdjointMap()
    return ad @ np.asarray(cov_right, np.float64) @ ad.T


def residual(T_measured: np.ndarray, T_true: np.ndarray) -> np.ndarray:
    """xi (6,) with ``T_true = T_measured @ exp(xi)``: what a factor's noise model must explain."""
    return gtsam.Pose3.Logmap(
        gtsam.Pose3(np.asarray(T_measured, np.float64)).between(gtsam.Pose3(np.asarray(T_true, np.float64)))
    )


def noise_model(cov: np.ndarray, kernel: str = "huber", k: float = 1.345) -> gtsam.noiseModel.Base:
    """Gaussian noise of covariance ``cov`` (6x6), wrapped in a robust ``kernel`` (``huber``,
    ``cauchy`` or ``none``) of width ``k`` (in standard deviations of the whitened error)."""
    if kernel not in KERNELS:
        raise ValueError(f"kernel must be one of {', '.join(KERNELS)}, got {kernel!r}")
    cov = 0.5 * (np.asarray(cov, np.float64) + np.asarray(cov, np.float64).T)
    gaussian = gtsam.noiseModel.Gaussian.Covariance(cov)
    if kernel == "none":
        return gaussian
    estimator = gtsam.noiseModel.mEstimator.Huber if kernel == "huber" else gtsam.noiseModel.mEstimator.Cauchy
    return gtsam.noiseModel.Robust.Create(estimator.Create(k), gaussian)


def _factor(m: Measurement, kernel: str, k: float) -> gtsam.BetweenFactorPose3:
    return gtsam.BetweenFactorPose3(
        m.i, m.j, gtsam.Pose3(np.asarray(m.T_ij, np.float64)), noise_model(m.cov, kernel, k)
    )


def check_measurement(m: Measurement, what: str = "measurement") -> None:
    """``ValueError`` naming ``what`` unless ``m.T_ij`` passes the runner's test of a usable motion
    (:func:`~odolab.running.runner.failure_reason`: a finite rigid 4x4 transform) and
    ``m.cov`` is a finite, symmetric positive-definite 6x6 matrix."""
    reason = failure_reason(Estimate(np.asarray(m.T_ij)))  # the runner's own test of a usable motion
    if reason is not None:
        raise ValueError(f"{what} ({m.source or 'no source'}): T_ij is not a rigid transform: {reason}")
    check_covariance(m.cov, f"{what} ({m.source or 'no source'})")


def check_covariance(cov: np.ndarray, what: str = "covariance") -> None:
    """``ValueError`` naming ``what`` unless ``cov`` is a finite, symmetric positive-definite 6x6 matrix."""
    cov = np.asarray(cov, np.float64)
    if cov.shape != (6, 6) or not np.all(np.isfinite(cov)):
        raise ValueError(f"{what}: cov must be a finite 6x6 matrix, got shape {cov.shape}")
    if not np.allclose(cov, cov.T, rtol=1e-6, atol=1e-12) or np.linalg.eigvalsh(0.5 * (cov + cov.T))[0] <= 0:
        raise ValueError(f"{what}: cov must be symmetric positive definite")


def _anchor(key: int = 0, pose: gtsam.Pose3 | None = None) -> gtsam.PriorFactorPose3:
    return gtsam.PriorFactorPose3(key, pose or gtsam.Pose3(), gtsam.noiseModel.Diagonal.Sigmas(ANCHOR_SIGMAS))


class OnlineGraph:
    """Poses 0, 1, 2, ... added one at a time with iSAM2; pose 0 is the origin.

    :meth:`add_pose` takes the factors that end at the new pose (from the previous pose and,
    optionally, from earlier ones) and returns the new estimate of ``inv(T_{j-1}) @ T_j`` given
    everything so far (the past is not revised in the returned steps: a robot uses them as they come).

    Should iSAM2 find its linear system indeterminate (seen once in a few hundred steps on long
    navigation episodes), the graph restarts from the previous pose's estimate, anchored there, and
    the step is solved from the factors of the previous pose alone; the poses before it keep their
    last estimates (:attr:`restarts` counts these).
    """

    def __init__(self, kernel: str = "huber", k: float = 1.345, iterations: int = 2) -> None:
        if isinstance(k, bool) or not isinstance(k, (int, float)) or not (np.isfinite(k) and k > 0):
            raise ValueError(f"kernel width k must be a finite number > 0, got {k!r:.40}")
        if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or iterations < 1:
            raise ValueError(f"iterations must be a whole number >= 1, got {iterations!r:.40}")
        noise_model(np.eye(6), kernel, k)  # checks the kernel's name
        self.kernel, self.k, self.iterations = kernel, float(k), int(iterations)
        self.isam = self._new_isam()
        self.n = 0  # poses so far
        self.estimate: gtsam.Values | None = None
        self.frozen: dict[int, gtsam.Pose3] = {}  # estimates of poses left behind by a restart
        self.restarts = 0

    @staticmethod
    def _new_isam() -> gtsam.ISAM2:
        params = gtsam.ISAM2Params()
        params.setRelinearizeThreshold(RELINEARIZE_THRESHOLD)
        params.relinearizeSkip = 1
        return gtsam.ISAM2(params)

    def _pose(self, i: int) -> gtsam.Pose3:
        return self.frozen[i] if i in self.frozen else self.estimate.atPose3(i)

    def add_pose(self, measurements: list[Measurement], guess: np.ndarray) -> np.ndarray:
        """Add pose ``n`` with ``measurements`` (each ``j == n``, ``i < n``); ``guess``: its initial
        ``inv(T_{n-1}) @ T_n`` (used when nothing constrains it better). Returns the estimate of
        ``inv(T_{n-1}) @ T_n`` (4x4); the very first call (pose 0) returns the identity."""
        graph, values = gtsam.NonlinearFactorGraph(), gtsam.Values()
        j = self.n
        if j == 0:
            graph.add(_anchor())
            values.insert(0, gtsam.Pose3())
        else:
            bad = [m for m in measurements if m.j != j or not 0 <= m.i < j]
            if bad:
                raise ValueError(
                    f"measurements for pose {j} must end at it and start before it, got {bad[0].i}->{bad[0].j}"
                )
            for n, m in enumerate(measurements):
                check_measurement(m, f"measurement {n} for pose {j}")
            if np.asarray(guess).shape != (4, 4) or not np.all(np.isfinite(guess)):
                raise ValueError(f"guess for pose {j} must be a finite 4x4 transform")
            for m in measurements:
                if m.i not in self.frozen:  # a span from before a restart has no pose to hold on to
                    graph.add(_factor(m, self.kernel, self.k))
            previous = self._pose(j - 1)
            values.insert(j, previous.compose(gtsam.Pose3(np.asarray(guess, np.float64))))
        try:
            self._solve(graph, values)
        except RuntimeError:  # gtsam's IndeterminantLinearSystemException
            if j == 0:
                raise
            self._restart(j, measurements, values)
        self.n += 1
        if j == 0:
            return np.eye(4)
        return self._pose(j - 1).between(self._pose(j)).matrix()

    def _solve(self, graph: gtsam.NonlinearFactorGraph, values: gtsam.Values) -> None:
        self.isam.update(graph, values)
        for _ in range(self.iterations - 1):
            self.isam.update()
        self.estimate = self.isam.calculateEstimate()

    def _restart(self, j: int, measurements: list[Measurement], values: gtsam.Values) -> None:
        """A fresh iSAM2 anchored at pose ``j - 1``'s last estimate, given pose ``j``'s factors from it."""
        for i in range(j):
            self.frozen.setdefault(i, self._pose(i))
        self.restarts += 1
        self.isam = self._new_isam()
        graph, start = gtsam.NonlinearFactorGraph(), gtsam.Values()
        graph.add(_anchor(j - 1, self.frozen[j - 1]))
        start.insert(j - 1, self.frozen[j - 1])
        start.insert(j, values.atPose3(j))
        for m in measurements:
            if m.i == j - 1:
                graph.add(_factor(m, self.kernel, self.k))
        self._solve(graph, start)
        self.frozen.pop(j - 1)  # the new graph's anchor now holds it

    def poses(self) -> np.ndarray:
        """(n, 4, 4) current estimates of every pose (revised by later factors)."""
        return np.stack([self._pose(i).matrix() for i in range(self.n)]) if self.n else np.zeros((0, 4, 4))


def smooth(
    n_poses: int,
    measurements: list[Measurement],
    guess: np.ndarray | None = None,
    kernel: str = "huber",
    k: float = 1.345,
) -> np.ndarray:
    """Batch Levenberg-Marquardt over poses 0 .. n_poses - 1 (pose 0 at the origin): (n, 4, 4).

    ``guess`` (n, 4, 4): initial poses (default: the first measurement of each consecutive pair,
    integrated; identity steps where there is none)."""
    graph = gtsam.NonlinearFactorGraph()
    graph.add(_anchor())
    for m in measurements:
        if not 0 <= m.i < m.j < n_poses:
            raise ValueError(f"measurement {m.i}->{m.j} outside poses 0..{n_poses - 1}")
        graph.add(_factor(m, kernel, k))
    if guess is None:
        step = {m.j: m.T_ij for m in reversed(measurements) if m.j == m.i + 1}
        guess = np.empty((n_poses, 4, 4))
        guess[0] = np.eye(4)
        for j in range(1, n_poses):
            guess[j] = guess[j - 1] @ step.get(j, np.eye(4))
    values = gtsam.Values()
    for j in range(n_poses):
        values.insert(j, gtsam.Pose3(np.asarray(guess[j], np.float64)))
    result = gtsam.LevenbergMarquardtOptimizer(graph, values, gtsam.LevenbergMarquardtParams()).optimize()
    return np.stack([result.atPose3(j).matrix() for j in range(n_poses)])
