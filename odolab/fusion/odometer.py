"""``fused(a,b,...)``: several odometers fused through a GTSAM pose graph, itself an odometer.

    python -m odolab.compare --odometers 'icp,open3d-rgbd,robust-vo,fused(icp,open3d-rgbd,robust-vo)'

Every step, each input odometer sees the same pair; each valid answer, corrected by the input's
calibrated bias for the action, becomes a between-factor from the previous pose to the new one,
with the input's calibrated covariance for the action (the near-view entry when the previous
frame's median depth is below the calibration's ``near_depth``: a wall ahead)
(:mod:`odolab.fusion.calibration`; file: option ``calibration``, default the shipped one) inside a
robust kernel (``kernel``: huber, cauchy or none; ``kernel_width`` in whitened sigmas), so one
wild answer cannot pull the result. These options are the fields of :class:`FusionConfig`. With ``span`` k > 1 the inputs named in ``span_inputs`` (those
that can register frames further apart, e.g. icp) also measure pose t-k+1..t-2 -> t without an
action, which ties the graph across steps (span factors are not bias-corrected: a bias is
calibrated per action, and a span has none). iSAM2 solves it online, each step started from the
first input's answer (:data:`~odolab.fusion.graph.RELINEARIZE_THRESHOLD` says why it is not solved to
convergence): the answer for step t uses frames up to t only;
:meth:`FusedOdometer.smoothed_trajectory` re-solves the whole sequence in one batch. When no input
answered and no span factor constrains the step, the action prior's
motion enters with its calibrated covariance and the step is reported invalid (the runner then uses
that prior motion, as it would for any failed step). The answer's covariance is the inverse of the
summed information of the step's factors (span factors left out), as of the previous camera.

When an input is an oracle (it reads ``Frame.gt_pose``), so is the fused odometer: it is given
the ground truth to hand on, and reports mark its row oracle.

Options of the inputs themselves come from ``options_file`` (TOML, ``[odometers."icp"] key = value``
tables, as ``python -m odolab.compare --options-file``).
"""

from __future__ import annotations

import hashlib
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

from odolab.config import check, setting
from odolab.core.geometry import planar_to_transform
from odolab.core.types import Action, Estimate, Frame, Intrinsics
from odolab.fusion.calibration import Calibration, view_is_near
from odolab.fusion.graph import (
    Measurement,
    OnlineGraph,
    check_covariance,
    left_covariance,
    right_covariance,
    smooth,
)
from odolab.odometry.action_prior import ActionPrior
from odolab.odometry.composites import load_inputs
from odolab.odometry.configured import configure
from odolab.odometry.odometer import COMPOSITE, REGISTRY, Odometer, UnknownOdometerError, split_odometer_names
from odolab.running.runner import failure_reason

#: The calibration shipped with odolab (its command is in the file's ``source``).
SHIPPED_CALIBRATION = Path(__file__).resolve().parent.parent / "data" / "fusion" / "calibration.json"
PRIOR = "action-prior"


#: The robust kernels of :mod:`odolab.fusion.graph` (its ``KERNELS``).
Kernel = Literal["huber", "cauchy", "none"]


@dataclass(frozen=True)
class FusionConfig:
    """The options of a fused odometer besides its inputs (module docstring); its constructor's
    keyword arguments of the same names."""

    calibration: str | Path = setting("", doc="calibration file of the inputs' biases and covariances ('': shipped)")
    kernel: Kernel = setting("huber", doc="robust kernel round every factor")
    kernel_width: float = setting(1.345, range=(0.1, 100.0), doc="width of the robust kernel, whitened sigmas")
    span: int = setting(1, range=(1, 10), doc="factors reach this many steps back (1: consecutive steps only)")
    span_inputs: str = setting("", doc="comma-separated inputs that also measure the span factors")
    options_file: str = setting("", doc='the inputs\' own options (TOML, [odometers."icp"] tables)')

    def __post_init__(self) -> None:
        if not isinstance(self.calibration, (str, Path)):
            raise ValueError(f"calibration must be a file path, got {self.calibration!r:.40}")
        check(self)
        if split_odometer_names(self.span_inputs) and self.span < 2:
            raise ValueError(f"span_inputs needs span >= 2 (factors over more than one step), got span {self.span}")


class FusedOdometer(Odometer):
    """Pose-graph fusion of ``inputs`` (comma-separated odometer names); the other keyword arguments
    are the fields of :class:`FusionConfig`, kept as ``config``. See the module docstring."""

    composite = True

    Config = FusionConfig  # its options: every field of FusionConfig (odolab.odometry.configured)

    def __init__(self, inputs: str = "", config: FusionConfig | None = None, **overrides) -> None:
        names = split_odometer_names(inputs)
        if not names:
            raise ValueError(
                "fused needs its inputs, e.g. fused(icp,open3d-rgbd) or the option inputs='icp,open3d-rgbd'"
            )
        if len(set(names)) != len(names):
            raise ValueError(f"fused: an input is named twice in {names}")
        if any(map(is_fused, names)):
            raise ValueError("fused: an input cannot itself be fused(...)")
        self.config = cfg = configure(FusionConfig, config, **overrides)
        spanning = split_odometer_names(cfg.span_inputs)
        if [n for n in spanning if n not in names]:
            raise ValueError(f"span_inputs must be among the inputs {names}, got {spanning}")
        if not cfg.calibration and not SHIPPED_CALIBRATION.exists():
            raise ValueError(
                "odolab ships no fusion calibration here; make one with python -m odolab.fusion.calibrate "
                "and pass it as the option calibration=FILE"
            )
        self.calibration = Calibration.load(cfg.calibration or SHIPPED_CALIBRATION)
        self.input_calibration = {n: self.calibration.for_input(n) for n in names}
        self.prior_calibration = self.calibration.for_input(PRIOR)
        self.inputs: dict[str, Odometer] = load_inputs("fused", names, cfg.options_file)
        self.spanning = spanning
        self.kernel, self.kernel_width, self.span = cfg.kernel, cfg.kernel_width, cfg.span
        self.prior = ActionPrior.shipped()
        # an input that needs actions would answer nothing without them: say so, as that input would
        self.needs_action = any(o.needs_action for o in self.inputs.values())
        # an input that reads ground truth makes this an oracle: the runner then hands the frames' gt_pose on
        self.oracle = any(o.oracle for o in self.inputs.values())
        # what its answers depend on besides code: its inputs' model files or settings and the calibration
        parts = [f"{n}={o.identity_digest}" for n, o in self.inputs.items() if o.identity_digest]
        self.identity_digest = hashlib.sha256(
            ";".join(parts + [f"calibration={self.calibration.digest}"]).encode()
        ).hexdigest()
        #: seconds spent in the graph alone (not in the inputs), and steps, over this object's life
        self.fusion_seconds, self.fused_steps = 0.0, 0
        self._graph: OnlineGraph | None = None
        self._measurements: list[Measurement] = []
        self._frames: deque[Frame] = deque(maxlen=self.span)
        self._step_covs: deque[dict[str, np.ndarray]] = deque(maxlen=self.span)  # per step: input -> covariance

    def reset(self, intrinsics: Intrinsics) -> None:
        super().reset(intrinsics)
        for odo in self.inputs.values():
            odo.reset(intrinsics)
        self._graph = OnlineGraph(self.kernel, self.kernel_width)
        self._graph.add_pose([], np.eye(4))
        self._frames.clear()
        self._step_covs.clear()
        self._measurements = []

    def _answer(self, odo: Odometer, prev: Frame, cur: Frame, action: Action | None) -> Estimate | None:
        try:
            est = odo.step(prev, cur, action)
        except Exception:  # noqa: BLE001 - an input that raises is an input that did not answer
            return None
        return est if failure_reason(est) is None else None

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        if self._graph is None:
            raise RuntimeError("call reset(intrinsics) before step")
        j = self._graph.n  # the new pose
        if not self._frames:
            self._frames.append(prev)
        answers = {n: self._answer(o, prev, cur, action) for n, o in self.inputs.items()}
        # span answers (t-k -> t) from inputs that answered this step and each step in between
        span_answers = {}
        for k in range(2, min(self.span, len(self._frames)) + 1):
            for n in self.spanning:
                if answers[n] is not None and all(n in covs for covs in list(self._step_covs)[-(k - 1) :]):
                    span_answers[k, n] = self._answer(self.inputs[n], self._frames[-k], cur, None)
        started = time.perf_counter()  # from here on: the graph's own time, not the inputs'
        steps, step_covs = [], {}
        near = view_is_near(prev.depth, self.calibration.near_depth)  # a wall ahead: the near-view entries
        for n, est in answers.items():
            if est is None:
                continue
            cal = self.input_calibration[n]
            try:  # an answer whose own covariance is not one (singular, 3x3, ...) is no answer
                own = right_covariance(est.transform, est.covariance) if est.covariance is not None else None
                m = Measurement(
                    j - 1, j, cal.corrected(action, est.transform, near), cal.covariance(action, own, near), n
                )
                check_covariance(m.cov)  # the motion itself passed the runner's rigidity check
            except ValueError:
                continue
            steps.append(m)
            step_covs[n] = m.cov
        spans = []
        for (k, n), est in span_answers.items():
            if est is not None:  # weighted as the input's consecutive steps it spans, summed
                cov = sum(covs[n] for covs in list(self._step_covs)[-(k - 1) :]) + step_covs[n]
                spans.append(Measurement(j - k, j, est.transform, cov, n))
        valid = bool(steps or spans)
        prior_T = planar_to_transform(*self.prior.motion(action))
        measurements = steps + spans
        if not valid:
            prior_cov = self.prior_calibration.covariance(action, None, near)
            measurements = [Measurement(j - 1, j, prior_T, prior_cov, PRIOR)]
            step_covs = {PRIOR: prior_cov}
        guess = steps[0].T_ij if steps else prior_T
        T = self._graph.add_pose(measurements, guess)
        self._measurements += measurements
        info = sum(np.linalg.inv(c) for c in step_covs.values())
        cov_left = left_covariance(T, np.linalg.inv(info))
        self._frames.append(cur)
        self._step_covs.append(step_covs)
        self.fusion_seconds += time.perf_counter() - started
        self.fused_steps += 1
        return Estimate(T, valid=valid, covariance=cov_left)

    def smoothed_trajectory(self) -> np.ndarray:
        """The whole sequence so far re-solved in one batch (Levenberg-Marquardt over every factor
        added since ``reset``): (n + 1, 4, 4) camera poses relative to the first, each using all
        frames (not causal: for evaluating a finished trajectory, not for driving)."""
        if self._graph is None:
            raise RuntimeError("call reset(intrinsics) and step before smoothing")
        return smooth(
            self._graph.n, self._measurements, guess=self._graph.poses(), kernel=self.kernel, k=self.kernel_width
        )


def is_fused(name: str) -> bool:
    """Whether odometer ``name`` (or the head of a composite ``head(a,b)``) is a fused odometer,
    whatever name its class is registered under; False for a name that names no odometer."""
    composite = COMPOSITE.fullmatch(name)
    try:
        factory = REGISTRY.resolve(composite["head"] if composite else name)
    except (UnknownOdometerError, ValueError):
        return False
    return isinstance(factory, type) and issubclass(factory, FusedOdometer)
