"""Episodes as training data for learned odometers: specs per split, true motions, and frame pairs.

* :func:`episode_specs`: the first ``n`` episodes of a split (``train``, ``val``, ``test``: disjoint
  scene pools, see :mod:`odolab.sim.scenes`).
* :func:`true_motions`: ``T_prev_cur`` of every consecutive pair of a sequence, from its poses.
* :class:`PairDataset`: random access to ``(prev, cur, action, true motion)`` pairs of cached
  episodes, reading only the two frames asked for.

Storage choice for :class:`PairDataset`: the episode cache already holds each episode as an
*uncompressed* ``.npz`` (``np.savez``), whose members are ``.npy`` files stored byte for byte.
They are memory-mapped in place (:func:`odolab.io.npz_mmap.mmap_npz_member`), so a pair costs
two frames of page reads, there is no second copy of the data on disk, the operating system's
page cache is shared by every data-loader worker, and nothing is decompressed. (Writing ``.npy``
shards beside the cache would double the disk use for the same access pattern; compressed
``.npz`` members cannot be mapped at all.) This module imports no torch; a torch ``Dataset`` is a
small wrapper (``TorchPairs`` in ``examples/tiny_learned.py``).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from odolab.core.geometry import invert, transform_to_planar
from odolab.core.types import Action, Frame, Intrinsics, Sequence
from odolab.io.npz_mmap import mmap_npz_member
from odolab.sim.episodes import EpisodeCache, EpisodeSpec, NoiseConfig
from odolab.sim.mesh_scenes import SceneFiles

__all__ = ["Pair", "PairDataset", "episode_specs", "true_motions"]


def episode_specs(
    split: str,
    n: int,
    *,
    seed: int = 0,
    max_steps: int = 100,
    noise: NoiseConfig | None = None,
    first: int = 0,
    scenes: SceneFiles | None = None,
    family: str = "boxes",
) -> list[EpisodeSpec]:
    """Specs of episodes ``first .. first + n - 1`` of ``split`` from ``seed`` (same args, same
    episodes), in the split's procedural scenes of ``family`` or in mesh ``scenes``."""
    noise = noise or NoiseConfig()
    return [
        EpisodeSpec(
            split=split, index=first + i, seed=seed, max_steps=max_steps, noise=noise, scenes=scenes, family=family
        )
        for i in range(n)
    ]


def true_motions(seq: Sequence) -> np.ndarray:
    """True ``T_prev_cur`` (N, 4, 4) of the N consecutive pairs of ``seq`` (camera axes, metres);
    raises ``ValueError`` when a frame has no ground-truth pose."""
    poses = [seq.gt_pose(i) for i in range(len(seq))]
    if any(p is None for p in poses):
        raise ValueError(f"{seq.name}: no ground-truth pose for every frame")
    P = np.stack(poses).astype(np.float64)
    return invert(P[:-1]) @ P[1:]


@dataclass(frozen=True)
class Pair:
    """One training example: consecutive frames, the action between them and the true motion.

    ``motion``: ``T_prev_cur`` (4x4); ``planar``: its ``(dx m, dz m, dyaw rad)``; ``episode`` and
    ``step`` say where it came from; ``collision``: the step's translation was blocked.
    """

    prev: Frame
    cur: Frame
    action: Action
    motion: np.ndarray
    planar: np.ndarray
    episode: int
    step: int
    collision: bool


class PairDataset:
    """All consecutive pairs of the cached episodes of ``specs``, by index ``0 .. len - 1``.

    The episodes must be in ``cache`` (``odolab.api.generate_episodes(specs, cache)``); opening
    reads only their small ``actions`` members. ``ds[k]`` is a :class:`Pair` whose frames are
    fresh arrays (writable, yours). Maps are opened lazily per process, so the dataset can be sent
    to data-loader workers. Ordering: episode by episode, step by step.
    """

    def __init__(self, specs: list[EpisodeSpec], cache: EpisodeCache) -> None:
        self.specs = list(specs)
        self.paths = []
        counts = []
        for spec in self.specs:
            if not cache.has(spec):
                raise ValueError(
                    f"episode {spec.split}-s{spec.seed}-e{spec.index:03d} is not in the cache "
                    f"{cache.root}; generate it first"
                )
            path = cache.path(spec)
            if not path.is_file():  # kept in memory only: the cache could not be written
                raise ValueError(
                    f"episode {spec.split}-s{spec.seed}-e{spec.index:03d}: no file {path} (the cache "
                    f"{cache.root} could not be written); free space or choose a writable cache"
                )
            with np.load(path, allow_pickle=False) as z:
                counts.append(len(z["actions"]))
            self.paths.append(path)
        self._offsets = np.concatenate([[0], np.cumsum(counts)]).astype(np.int64)
        self._open: dict[int, dict[str, Any]] = {}

    def __len__(self) -> int:
        return int(self._offsets[-1])

    def locate(self, k: int) -> tuple[int, int]:
        """``(episode index into specs, step)`` of pair ``k``."""
        if not -len(self) <= k < len(self):
            raise IndexError(f"pair {k} out of range for {len(self)} pairs")
        k %= len(self)
        e = int(np.searchsorted(self._offsets, k, side="right") - 1)
        return e, int(k - self._offsets[e])

    def _maps(self, e: int) -> dict[str, Any]:
        if e not in self._open:
            path = self.paths[e]
            with np.load(path, allow_pickle=False) as z:
                small = {k: np.array(z[k]) for k in ("poses", "actions", "collisions")}
            small.update({k: mmap_npz_member(path, k) for k in ("rgb", "depth")})
            self._open[e] = small
        return self._open[e]

    def intrinsics(self, e: int = 0) -> Intrinsics:
        """The camera of episode ``e``."""
        return self.specs[e].camera.intrinsics

    def __getitem__(self, k: int) -> Pair:
        e, i = self.locate(k)
        m = self._maps(e)
        frames = [
            Frame(np.array(m["rgb"][j]), np.array(m["depth"][j]), float(j), m["poses"][j].copy()) for j in (i, i + 1)
        ]
        motion = invert(m["poses"][i]) @ m["poses"][i + 1]
        return Pair(
            frames[0],
            frames[1],
            Action(int(m["actions"][i])),
            motion,
            transform_to_planar(motion),
            e,
            i,
            bool(m["collisions"][i]),
        )

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_open"] = {}  # maps are reopened in the receiving process
        return state
