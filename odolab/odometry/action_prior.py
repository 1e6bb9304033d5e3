"""The action prior: the mean true motion of each action over the train split.

This is the paper's ``sys_error`` reference (always predict the training mean of each action) and
the runner's fallback when an odometer fails. The shipped table ``odolab/data/action_prior.json``
is made by::

    python -m odolab.action_prior --episodes 400 --out odolab/data/action_prior.json

Fitting needs only the motion (no images), so 400 episodes take a few seconds.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass
from importlib.resources import files

import numpy as np

from odolab.config import SEED_RANGE, check, setting
from odolab.core.geometry import invert, transform_to_planar
from odolab.core.types import MOTION_ACTIONS, Action
from odolab.io.inputs import read_input_json

_SHIPPED = "action_prior.json"
#: A step's mean motion beyond this (m or rad) is no action's: one step is 0.25 m or 30 degrees.
MEAN_LIMIT = 2.0


@dataclass(frozen=True)
class ActionPrior:
    """Mean planar motion ``(dx m, dz m, dyaw rad)`` per motion action, and how it was obtained."""

    means: dict[Action, tuple[float, float, float]]
    samples: dict[Action, int]
    source: str = ""

    def motion(self, action: Action | None) -> np.ndarray:
        """Mean (dx, dz, dyaw) of ``action``; zero motion for None or STOP."""
        if action is None or action not in self.means:
            return np.zeros(3)
        return np.array(self.means[action])

    def to_json(self) -> dict:
        return {
            "source": self.source,
            "means": {a.label: list(self.means[a]) for a in self.means},
            "samples": {a.label: self.samples[a] for a in self.samples},
        }

    @classmethod
    def from_json(cls, data: dict, origin: str = "action prior") -> ActionPrior:
        """Parse :meth:`to_json` output; ``ValueError`` naming ``origin`` (the file), the field and
        the action for anything else: every motion action needs a mean of 3 finite numbers within
        ``MEAN_LIMIT`` and a whole, non-negative sample count."""
        labels = ", ".join(a.label for a in MOTION_ACTIONS)
        fields = {}
        for field in ("means", "samples"):
            table = data.get(field) if isinstance(data, dict) else None
            if not isinstance(table, dict):
                raise ValueError(
                    f"{origin}: '{field}' must be an object mapping each of {labels} to a value, "
                    f"got {type(table).__name__}"
                )
            unknown = sorted(set(table) - {a.label for a in MOTION_ACTIONS})
            if unknown:
                raise ValueError(f"{origin}: {field}: unknown action {unknown[0]!r}; expected {labels}")
            missing = [a.label for a in MOTION_ACTIONS if a.label not in table]
            if missing:
                raise ValueError(f"{origin}: {field}: no value for {missing[0]!r}; expected {labels}")
            fields[field] = {a: table[a.label] for a in MOTION_ACTIONS}
        means, samples = {}, {}
        for a, v in fields["means"].items():
            if (
                not isinstance(v, list)
                or len(v) != 3
                or not all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
                or not all(np.isfinite(x) and abs(x) <= MEAN_LIMIT for x in v)
            ):
                raise ValueError(
                    f"{origin}: means.{a.label}: expected [dx m, dz m, dyaw rad], 3 numbers within "
                    f"+-{MEAN_LIMIT:g}, got {v!r:.80}"
                )
            means[a] = tuple(float(x) for x in v)
        for a, n in fields["samples"].items():
            if not isinstance(n, int) or isinstance(n, bool) or n < 0:
                raise ValueError(f"{origin}: samples.{a.label}: expected a whole number >= 0, got {n!r:.80}")
            samples[a] = n
        return cls(means, samples, str(data.get("source", "")))

    @classmethod
    def load(cls, path: str | os.PathLike) -> ActionPrior:
        """Read a prior written by ``python -m odolab.action_prior``; errors name the file."""
        data = read_input_json(path, "action prior file")  # regular files only, no repeated keys
        if not isinstance(data, dict):
            raise ValueError(f"{path}: not an action prior file (expected a JSON object)")
        return cls.from_json(data, origin=str(path))

    @classmethod
    def shipped(cls) -> ActionPrior:
        """The table fitted on the train split and shipped with odolab."""
        text = files("odolab.data").joinpath(_SHIPPED).read_text()
        return cls.from_json(json.loads(text), origin=_SHIPPED)


@dataclass(frozen=True)
class PriorFit:
    """What :func:`fit_action_prior` averages over: ``n_episodes`` train rollouts from ``seed``, at most
    ``max_steps`` actions each (rollouts render nothing, so they may be longer than the Challenge's)."""

    n_episodes: int = setting(400, range=(1, 100_000), doc="train episodes (rollouts)")
    max_steps: int = setting(500, range=(1, 2000), doc="actions per rollout at most")
    seed: int = setting(0, range=SEED_RANGE, doc="seed of the rollouts")

    def __post_init__(self) -> None:
        check(self)


def fit_action_prior(n_episodes: int = 400, max_steps: int = 500, seed: int = 0, noise=None) -> ActionPrior:
    """Average the true per-step motion of each action over ``n_episodes`` train rollouts (ranges:
    :class:`PriorFit`)."""
    PriorFit(n_episodes, max_steps, seed)  # ValueError for a number outside its range
    from odolab.sim.camera import CameraSpec
    from odolab.sim.episodes import EpisodeSpec, NoiseConfig, rollout

    noise = noise or NoiseConfig()
    sums = {a: np.zeros(3) for a in MOTION_ACTIONS}
    counts = {a: 0 for a in MOTION_ACTIONS}
    for i in range(n_episodes):
        r = rollout(EpisodeSpec(split="train", index=i, seed=seed, max_steps=max_steps, noise=noise))
        poses = r.camera_poses(CameraSpec().mount_height)
        rel = invert(poses[:-1]) @ poses[1:]
        for a, T in zip(r.actions, rel):
            sums[a] += transform_to_planar(T)
            counts[a] += 1
    means = {a: tuple(float(x) for x in sums[a] / max(counts[a], 1)) for a in MOTION_ACTIONS}
    src = f"fit_action_prior(n_episodes={n_episodes}, max_steps={max_steps}, seed={seed}, noise={noise})"
    return ActionPrior(means, counts, src)
