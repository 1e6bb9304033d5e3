"""Training data for learned odometers: simulator episodes rendered once, resized to the training
resolution and stored as memory-mappable shards, with random access to frame pairs and windows.

Make a data set (Ray tasks, one shard of a few episodes each; resumable: finished shards are kept)::

    python -m odolab.training_data --split train --episodes 1200 --width 170 --height 96 --out data/vo/train

A folder holds ``dataset.json`` (the config and, per shard, its file and counts) and the shards
``shard-<index>-<digest>.npz``: uncompressed ``.npz`` files (members mapped in place, see
:mod:`odolab.io.npz_mmap`) with, for the F frames of its episodes in order,

* ``rgb`` (F, h, w, 3) uint8 and ``depth_mm`` (F, h, w) uint16 millimetres (0 = no reading),
  resized by :func:`resize_frame` (the function learned odometers apply to their input at run time);
* with ``clean_depth`` set, ``clean_depth_mm`` (F, h, w) uint16: the simulator's noiseless depth of
  the same frames, resized the same way (the target of a depth corrector);
* ``poses`` (F, 4, 4) ``T_world_cam``; ``actions`` (F,) int8: the action taken after the frame,
  -1 on an episode's last frame; ``collisions`` (F,) bool; ``episode`` (F,) int32 episode index.

:class:`TrainingData` opens a folder and hands out batches of pairs (``frame f -> f + 1`` of one
episode) or windows of consecutive frames, reading only the frames asked for. No torch here.

Each shard's CRC-32 (of the whole file) is written in ``dataset.json`` when the shard is made, and
checked the first time a :class:`TrainingData` object maps the shard's frames (once per shard and
process: one read of the file, which the frames are read from anyway); a shard whose entry has no
``crc32`` is checked against its zip archive's own CRC-32 of each array instead. A damaged shard
raises :class:`DamagedShardError` naming it. Shard names read from ``dataset.json`` must be plain
file names inside the folder (a manifest naming ``../x`` or an absolute path is refused, never
read or deleted).
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import re
import sys
import zipfile
import zlib
from collections.abc import Iterator
from collections.abc import Sequence as Seq
from dataclasses import asdict, dataclass
from pathlib import Path

import cv2
import numpy as np
from tqdm.auto import tqdm

from odolab.config import SEED_RANGE, build, check, setting
from odolab.core.geometry import invert, transform_to_planar
from odolab.core.parallel import Execution, fan_out
from odolab.core.types import MOTION_ACTIONS, Action, Intrinsics
from odolab.io.atomic import atomic_open, write_bytes_atomic
from odolab.io.npz_mmap import NpzRows
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec, NoiseConfig, render_frames, rollout
from odolab.sim.free_scenes import FAMILIES
from odolab.sim.mesh_scenes import SceneFiles
from odolab.sim.scenes import MAX_EPISODE_STEPS, SPLITS

__all__ = [
    "DamagedShardError",
    "DataConfig",
    "TrainingData",
    "file_crc32",
    "make_training_data",
    "resize_frame",
    "verify_shard",
]

FORMAT = 1
MANIFEST = "dataset.json"
#: Largest episode index a shard stores (its ``episode`` column is int32).
MAX_EPISODE_INDEX = 2**31 - 1
#: Documented ranges of the integer settings (a data set of more episodes is several folders).
MAX_EPISODES = 1_000_000
MAX_EPISODES_PER_SHARD = 1000
_CAMERA = CameraSpec()
_ARRAYS = ("rgb", "depth_mm", "poses", "actions", "collisions", "episode")


class DamagedShardError(ValueError):
    """A shard whose bytes are not those written when it was made (a flipped byte, a cut copy)."""


def file_crc32(path: str | os.PathLike, chunk: int = 1 << 24) -> int:
    """The CRC-32 (:func:`zlib.crc32`) of the file's bytes, read ``chunk`` bytes at a time."""
    crc = 0
    with open(path, "rb") as f:
        while block := f.read(chunk):
            crc = zlib.crc32(block, crc)
    return crc


def verify_shard(path: Path, entry: dict) -> None:
    """:class:`DamagedShardError` unless shard ``path`` holds the bytes its manifest ``entry``'s
    ``crc32`` says; an entry without one is checked
    against the zip archive's CRC-32 of each member."""
    advice = "delete it and run the python -m odolab.training_data command again"
    expected = entry.get("crc32")
    if expected is not None:
        if isinstance(expected, bool) or not isinstance(expected, int):
            raise DamagedShardError(
                f"{path}: its crc32 in {MANIFEST} must be an integer, got {expected!r:.40}; {advice}"
            )
        got = file_crc32(path)
        if got != expected:
            raise DamagedShardError(
                f"{path}: damaged: its CRC-32 is {got:08x}, but {expected:08x} was written with "
                f"it in {MANIFEST}; {advice}"
            )
        return
    try:
        with zipfile.ZipFile(path) as archive:
            bad = archive.testzip()
    except (OSError, zipfile.BadZipFile, zlib.error, EOFError) as exc:
        raise DamagedShardError(f"{path}: damaged ({exc}); {advice}") from None
    if bad is not None:
        raise DamagedShardError(f"{path}: damaged: array {bad} does not match the CRC-32 stored with it; {advice}")


def resize_frame(rgb: np.ndarray, depth: np.ndarray, width: int, height: int) -> tuple[np.ndarray, np.ndarray]:
    """An RGB-D frame resized to ``width`` x ``height`` (intrinsics: :meth:`Intrinsics.resized`).

    RGB: area average (``cv2.INTER_AREA``). Depth (m, 0 = no reading): the area average of the valid
    readings, where at least half of the area is valid, else 0, so holes neither shrink to nothing nor
    blend into their neighbours. Returns (h, w, 3) uint8 and (h, w) float32.
    """
    if rgb.shape[:2] == (height, width) and depth.shape == (height, width):
        return np.asarray(rgb, np.uint8), np.asarray(depth, np.float32)
    small_rgb = cv2.resize(np.ascontiguousarray(rgb), (width, height), interpolation=cv2.INTER_AREA)
    depth = np.asarray(depth, np.float32)
    valid = (depth > 0).astype(np.float32)
    total = cv2.resize(depth, (width, height), interpolation=cv2.INTER_AREA)
    share = cv2.resize(valid, (width, height), interpolation=cv2.INTER_AREA)
    small_depth = np.where(share >= 0.5, total / np.maximum(share, 1e-6), 0.0).astype(np.float32)
    return small_rgb, small_depth


@dataclass(frozen=True)
class DataConfig:
    """What a training-data folder holds: episodes ``first .. first + episodes - 1`` of ``split``
    from ``seed`` (at most ``max_steps`` actions each), frames resized to ``width`` x ``height`` px."""

    split: str = setting("train", doc=f"episode split: one of {', '.join(SPLITS)}")
    episodes: int = setting(1200, range=(1, MAX_EPISODES), doc="episodes in the data set")
    seed: int = setting(0, range=SEED_RANGE, doc="seed of the episodes")
    first: int = setting(0, range=(0, MAX_EPISODE_INDEX), doc="index of the first episode")
    max_steps: int = setting(500, range=(1, MAX_EPISODE_STEPS), doc="at most this many actions per episode")
    width: int = setting(170, range=(1, _CAMERA.width), doc="stored frame width, px (resized from the camera's)")
    height: int = setting(96, range=(1, _CAMERA.height), doc="stored frame height, px")
    episodes_per_shard: int = setting(8, range=(1, MAX_EPISODES_PER_SHARD), doc="episodes per shard file")
    noise: NoiseConfig = setting(default_factory=NoiseConfig, doc="noise multipliers of the episodes")
    clean_depth: bool = setting(False, doc="also store the noiseless depth (clean_depth_mm), for depth correctors")

    def __post_init__(self) -> None:
        check(self)
        if self.split not in SPLITS:
            raise ValueError(f"split must be one of {', '.join(SPLITS)}, got {self.split!r}")
        if self.first > MAX_EPISODE_INDEX - self.episodes + 1:
            raise ValueError(
                f"first must be in [0, {MAX_EPISODE_INDEX - self.episodes + 1}] (the last episode's index "
                f"at most 2^31 - 1), got {self.first}"
            )

    @property
    def specs(self) -> list[EpisodeSpec]:
        """The episodes, in procedural scenes."""
        return self.episode_specs()

    def episode_specs(self, scenes: SceneFiles | None = None, family: str = "boxes") -> list[EpisodeSpec]:
        """The episodes, in mesh ``scenes`` (:func:`odolab.sim.mesh_scenes.scene_files`) or, with
        None, in procedural scenes of ``family``."""
        return [
            EpisodeSpec(
                split=self.split,
                index=self.first + i,
                seed=self.seed,
                max_steps=self.max_steps,
                noise=self.noise,
                scenes=scenes,
                family=family,
            )
            for i in range(self.episodes)
        ]

    @property
    def intrinsics(self) -> Intrinsics:
        """The camera of the stored (resized) frames."""
        return CameraSpec().intrinsics.resized(self.width, self.height)

    def require_size(self, width: int, height: int, resized: bool = False) -> None:
        """``ValueError`` unless the frames are ``width`` x ``height`` px (what a model takes); with
        ``resized``, frames at least that large also do (the trainer resizes them on load with
        :func:`resize_frame`, as the odometer resizes the camera's frames)."""
        if (self.width, self.height) == (width, height):
            return
        if resized and self.width >= width and self.height >= height:
            return
        wanted = f"at least {width} x {height}" if resized else f"{width} x {height}"
        raise ValueError(f"{self.split} data is {self.width} x {self.height} px but the model takes {wanted}")

    def folder(self, root: str | os.PathLike) -> Path:
        """The conventional folder of this data under ``root``:
        ``<split>-<episodes>-s<seed>-<width>x<height>``, ``-clean`` added with ``clean_depth`` (a folder
        made otherwise is refused on use)."""
        suffix = "-clean" if self.clean_depth else ""
        return Path(root) / f"{self.split}-{self.episodes}-s{self.seed}-{self.width}x{self.height}{suffix}"

    def shard_specs(self, scenes: SceneFiles | None = None, family: str = "boxes") -> list[list[EpisodeSpec]]:
        """The episodes of each shard (:meth:`episode_specs`)."""
        specs, k = self.episode_specs(scenes, family), self.episodes_per_shard
        return [specs[i : i + k] for i in range(0, len(specs), k)]

    def shard_name(self, index: int, specs: list[EpisodeSpec]) -> str:
        """File name of shard ``index``; its digest changes with the simulator and the resolution."""
        parts = [FORMAT, self.width, self.height, [s.key() for s in specs]]
        blob = json.dumps(parts + ["clean_depth"] if self.clean_depth else parts)
        return f"shard-{index:05d}-{hashlib.sha256(blob.encode()).hexdigest()[:12]}.npz"

    @classmethod
    def from_dict(cls, doc: dict, source: str) -> DataConfig:
        """Inverse of ``asdict`` (:func:`odolab.config.build`); ``ValueError`` names ``source`` and the bad field."""
        return build(cls, doc, source)


def _depth_mm(depth: np.ndarray) -> np.ndarray:
    """Depth (m) as uint16 millimetres (0 = no reading; clipped at 65.535 m)."""
    return np.round(depth * 1000.0).clip(0, 65535).astype(np.uint16)


def _render_shard(job: tuple[DataConfig, list[EpisodeSpec]]) -> dict[str, np.ndarray]:
    """Render the episodes of one shard and resize their frames (a Ray task)."""
    cfg, specs = job
    names = _ARRAYS + (("clean_depth_mm",) if cfg.clean_depth else ())
    parts: dict[str, list[np.ndarray]] = {name: [] for name in names}
    for spec in specs:
        motion = rollout(spec)
        for _, clean_depth, rgb, depth in render_frames(spec, motion):
            small_rgb, small_depth = resize_frame(rgb, depth, cfg.width, cfg.height)
            parts["rgb"].append(small_rgb[None])
            parts["depth_mm"].append(_depth_mm(small_depth)[None])
            if cfg.clean_depth:
                _, small_clean = resize_frame(rgb, clean_depth, cfg.width, cfg.height)
                parts["clean_depth_mm"].append(_depth_mm(small_clean)[None])
        n = len(motion.states)
        parts["poses"].append(motion.camera_poses(spec.camera.mount_height).astype(np.float64))
        parts["actions"].append(np.array([a.value for a in motion.actions] + [-1], np.int8))
        parts["collisions"].append(np.concatenate([np.array(motion.collisions, bool), [False]]))
        parts["episode"].append(np.full(n, spec.index, np.int32))
    return {name: np.concatenate(v) for name, v in parts.items()}


def _action_counts(actions: np.ndarray) -> dict[str, int]:
    return {a.label: int(np.sum(actions == a.value)) for a in MOTION_ACTIONS}


#: The file name of every shard (:meth:`DataConfig.shard_name`).
_SHARD_NAME = re.compile(r"shard-[0-9]{5,}-[0-9a-f]{12}\.npz")


def _is_shard_name(name: object) -> bool:
    """Whether ``name`` is a shard's plain file name (no folder, no ``..``, no absolute path)."""
    return isinstance(name, str) and _SHARD_NAME.fullmatch(name) is not None


def _read_manifest(root: Path) -> dict | None:
    path = root / MANIFEST
    if not path.exists():
        return None
    try:
        doc = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError) as exc:
        raise ValueError(f"{path}: not a readable training-data manifest ({exc})") from None
    if (
        not isinstance(doc, dict)
        or doc.get("format") != FORMAT
        or not isinstance(doc.get("shards"), dict)
        or not isinstance(doc.get("config"), dict)
    ):
        raise ValueError(
            f"{path}: not an odolab training-data manifest of format {FORMAT} (no config or shards); "
            "delete it, or choose another folder"
        )
    bad = next((name for name in doc["shards"] if not _is_shard_name(name)), None)
    if bad is not None:
        raise ValueError(
            f"{path}: field shards: expected shard file names like shard-00000-<12 hex digits>.npz inside "
            f"{root}, got {bad!r:.120}; restore the file, or make the data anew in another folder"
        )
    return doc


def make_training_data(
    cfg: DataConfig,
    root: str | os.PathLike,
    *,
    scenes: SceneFiles | None = None,
    family: str = "boxes",
    execution: Execution = Execution(),
) -> dict:
    """Render the shards of ``cfg`` that ``root`` lacks (as Ray tasks), each written atomically as it
    finishes, with ``dataset.json`` updated after each: an interrupted run resumes where it stopped.
    The episodes run in mesh ``scenes`` (:func:`odolab.sim.mesh_scenes.scene_files`; the manifest's
    ``scenes`` holds their digests and reading settings) or, with None, in procedural scenes of
    ``family`` (the manifest's ``family``, written when not ``boxes``).
    A folder made with another config or other scenes is refused (``ValueError`` naming the
    differing fields). One process at a time makes a folder: another one waits for it
    (:func:`making`), then finds the shards made. Returns the manifest."""

    root = Path(root)
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise ValueError(f"{root}: cannot make the data folder ({exc.strerror or exc})") from None
    with making(root):
        return _make(cfg, root, scenes, family, execution)


#: The lock file a process making a data folder holds (:func:`making`).
LOCK = ".making.lock"


@contextlib.contextmanager
def making(root: Path) -> Iterator[None]:
    """Hold the data folder ``root`` for making (an exclusive ``flock`` on its :data:`LOCK` file,
    released when the process ends however it ends); while another process holds it, say so on
    stderr and wait."""
    with open(root / LOCK, "a+b") as lock:
        try:
            fcntl.flock(lock, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except BlockingIOError:
            print(f"{root}: another process is making this data; waiting for it", file=sys.stderr, flush=True)
            fcntl.flock(lock, fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(lock, fcntl.LOCK_UN)


def _make(cfg: DataConfig, root: Path, scenes: SceneFiles | None, family: str, execution: Execution) -> dict:
    """:func:`make_training_data`'s work, with the folder held."""
    config = json.loads(json.dumps(asdict(cfg)))
    fresh = {"format": FORMAT, "config": config, "shards": {}}
    if scenes is not None:
        fresh["scenes"] = scenes.identity()
    if family != "boxes":
        fresh["family"] = family
    doc = _read_manifest(root) or fresh
    if (doc.get("scenes"), doc.get("family")) != (fresh.get("scenes"), fresh.get("family")):
        raise ValueError(
            f"{root} holds training data made in {_scenes_words(doc)}, not in {_scenes_words(fresh)} as asked; "
            "choose another folder (--out)"
        )
    with contextlib.suppress(ValueError, TypeError):  # a field added since the folder was made: its default
        doc["config"] = json.loads(json.dumps(asdict(DataConfig.from_dict(doc["config"], str(root / MANIFEST)))))
    if doc["config"] != config:
        diff = [
            f"{k} (folder {doc['config'].get(k)!r}, asked {v!r})"
            for k, v in config.items()
            if doc["config"].get(k) != v
        ]
        raise ValueError(
            f"{root} holds training data made with another config: {'; '.join(diff)}; choose another "
            "folder (a recipe's data_root, or --out)"
        )
    groups = cfg.shard_specs(scenes, family)
    names = [cfg.shard_name(i, g) for i, g in enumerate(groups)]
    todo = [i for i, name in enumerate(names) if name not in doc["shards"] or not (root / name).exists()]

    def write_manifest() -> None:
        write_bytes_atomic(root / MANIFEST, json.dumps(doc, indent=1).encode())

    def done(k: int, arrays: dict[str, np.ndarray]) -> None:
        i = todo[k]
        with atomic_open(root / names[i], "wb") as f:
            np.savez(f, **arrays)
        doc["shards"][names[i]] = {
            "index": i,
            "episodes": len(groups[i]),
            "frames": len(arrays["actions"]),
            "pairs": _action_counts(arrays["actions"]),
            "crc32": file_crc32(root / names[i]),
        }
        write_manifest()

    for orphan in root.glob(".shard-*.tmp"):  # a shard being written when a run was killed
        orphan.unlink(missing_ok=True)
    write_manifest()
    fan_out(
        _render_shard,
        [(cfg, groups[i]) for i in todo],
        on_result=done,
        execution=execution,
        desc=f"{cfg.split} shards",
    )
    stale = set(doc["shards"]) - set(names)
    for name in stale:  # shards of an older simulator: dropped from the manifest and deleted
        doc["shards"].pop(name)
        if _is_shard_name(name):  # only a plain shard file of this folder, never a path read from the file
            (root / name).unlink(missing_ok=True)
    write_manifest()
    return doc


def _scenes_words(doc: dict) -> str:
    """A manifest's ``scenes`` (:meth:`SceneFiles.identity`) or ``family`` in words."""
    identity = doc.get("scenes")
    if identity is None:
        return f"procedural scenes of the {doc.get('family', 'boxes')} family"
    if not isinstance(identity, dict) or not isinstance(identity.get("digests"), list):
        return f"unknown scenes ({identity!r:.60})"
    digests = [str(d)[:12] for d in identity["digests"]]
    shown = ", ".join(digests[:3]) + (", ..." if len(digests) > 3 else "")
    return f"mesh scenes of digests {shown} (up {identity.get('up')}, unit {identity.get('unit')})"


class TrainingData:
    """A training-data folder, opened for random access (maps are opened lazily per process).

    ``pairs``: (P,) global frame indices f such that (f, f + 1) is a pair of one episode;
    ``pair_actions`` (P,) :class:`Action` values; ``pair_planar`` (P, 3) true ``(dx, dz, dyaw)``;
    ``pair_motion`` (P, 4, 4) true ``T_prev_cur``; ``pair_collisions`` (P,) bool; per frame,
    ``poses`` (F, 4, 4) true ``T_world_cam`` and ``episode`` (F,) episode index.
    """

    def __init__(self, root: str | os.PathLike) -> None:
        self.root = Path(root)
        doc = _read_manifest(self.root)
        if doc is None:
            raise ValueError(f"{self.root}: no {MANIFEST}; make the data first (python -m odolab.training_data ...)")
        self.config = DataConfig.from_dict(doc["config"], str(self.root / MANIFEST))
        #: The mesh scenes the episodes ran in, as their digests (no files), or None: procedural scenes.
        self.scenes = (
            None if doc.get("scenes") is None else SceneFiles.recorded(doc["scenes"], str(self.root / MANIFEST))
        )
        #: The procedural scene family (:data:`odolab.sim.free_scenes.FAMILIES`).
        self.family = doc.get("family", "boxes")
        if self.family not in FAMILIES:
            raise ValueError(
                f"{self.root / MANIFEST}: field family: expected one of {', '.join(FAMILIES)}, got {self.family!r:.40}"
            )
        groups = self.config.shard_specs(self.scenes, self.family)
        expected = [self.config.shard_name(i, g) for i, g in enumerate(groups)]
        missing = [n for n in expected if n not in doc["shards"] or not (self.root / n).exists()]
        listed = [n for n in doc["shards"] if (self.root / n).exists()]
        if missing and listed and not set(listed) & set(expected):
            raise ValueError(
                f"{self.root / MANIFEST}: its config does not describe the shards it lists (their names "
                f"come from the config: e.g. {listed[0]} there, {expected[0]} for this config): it was "
                "changed after the data were made; restore it, or make the data anew in another folder"
            )
        if missing:
            raise ValueError(
                f"{self.root}: {len(missing)} of {len(expected)} shards missing (e.g. {missing[0]}); "
                "run the same python -m odolab.training_data command again to finish it"
            )
        self.shards = expected
        #: Per shard, its manifest entry (its CRC-32 among others), checked on first use.
        self._entries = [doc["shards"][n] if isinstance(doc["shards"][n], dict) else {} for n in expected]
        small = []
        for name in self.shards:
            try:
                with np.load(self.root / name, allow_pickle=False) as z:
                    small.append({k: np.array(z[k]) for k in ("poses", "actions", "collisions", "episode")})
            except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile, zlib.error) as exc:
                raise ValueError(
                    f"{self.root / name}: unreadable shard ({exc}); delete it and run the "
                    "python -m odolab.training_data command again"
                ) from None
        sizes = np.array([len(s["actions"]) for s in small])
        self._start = np.concatenate([[0], np.cumsum(sizes)]).astype(np.int64)
        actions = np.concatenate([s["actions"] for s in small])
        poses = np.concatenate([s["poses"] for s in small])
        self.poses = poses  # (F, 4, 4) T_world_cam of every frame
        self.episode = np.concatenate([s["episode"] for s in small])
        self.pairs = np.flatnonzero(actions >= 0).astype(np.int64)
        self.pair_actions = actions[self.pairs].astype(np.int64)
        self.pair_motion = invert(poses[self.pairs]) @ poses[self.pairs + 1]
        self.pair_planar = np.stack([transform_to_planar(m) for m in self.pair_motion])
        self.pair_collisions = np.concatenate([s["collisions"] for s in small])[self.pairs]
        self._maps: dict[int, dict[str, np.ndarray]] = {}
        self._verified: set[int] = set()  # shards checked; kept in copies (loader workers check nothing again)

    @property
    def intrinsics(self) -> Intrinsics:
        return self.config.intrinsics

    def __len__(self) -> int:
        return len(self.pairs)

    def counts(self) -> dict[str, int]:
        """Pairs per action label."""
        return _action_counts(self.pair_actions)

    def select(self, actions: Seq[Action] | None = None) -> np.ndarray:
        """Indices into the pair arrays of the pairs whose action is in ``actions`` (all if None)."""
        if actions is None:
            return np.arange(len(self.pairs))
        return np.flatnonzero(np.isin(self.pair_actions, [a.value for a in actions]))

    def verify(self, progress: bool = False) -> None:
        """Check every shard not yet checked (:func:`verify_shard`): one read of the whole data, so
        that copies of this object (a trainer's loader workers) need not check again."""
        for s in tqdm(
            [s for s in range(len(self.shards)) if s not in self._verified],
            desc="checking shards",
            unit="shard",
            disable=not progress,
            leave=False,
        ):
            verify_shard(self.root / self.shards[s], self._entries[s])
            self._verified.add(s)

    def _shard(self, s: int) -> dict[str, NpzRows]:
        """The frame arrays of shard ``s``, opened for reading rows; the first time in this object
        (and process), after :func:`verify_shard`. Rows are read one ``pread`` each, without
        readahead: the data may be larger than memory and are read in random order."""
        if s not in self._maps:
            path = self.root / self.shards[s]
            if s not in self._verified:
                verify_shard(path, self._entries[s])
                self._verified.add(s)
            members = ("rgb", "depth_mm") + (("clean_depth_mm",) if self.config.clean_depth else ())
            self._maps[s] = {k: NpzRows(path, k) for k in members}
        return self._maps[s]

    def _locate(self, frame_indices: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(shard, row within the shard) of global frames."""
        shard = np.searchsorted(self._start, frame_indices, side="right") - 1
        return shard, frame_indices - self._start[shard]

    def frames(self, frame_indices: np.ndarray, size: tuple[int, int] | None = None) -> tuple[np.ndarray, np.ndarray]:
        """RGB (N, h, w, 3) uint8 and depth (N, h, w) float32 metres of global frames, in order; with
        ``size`` = (w, h), each frame resized to it by :func:`resize_frame` (None: as stored)."""
        frame_indices = np.asarray(frame_indices, np.int64).ravel()
        w, h = size or (self.config.width, self.config.height)
        rgb = np.empty((len(frame_indices), h, w, 3), np.uint8)
        depth = np.empty((len(frame_indices), h, w), np.float32)
        for k, (s, row) in enumerate(zip(*self._locate(frame_indices))):
            m = self._shard(int(s))
            rgb[k], depth[k] = resize_frame(
                m["rgb"].read(int(row)), m["depth_mm"].read(int(row)) * np.float32(0.001), w, h
            )
        return rgb, depth

    def clean_depths(self, frame_indices: np.ndarray) -> np.ndarray:
        """The simulator's noiseless depth (N, h, w) float32 metres (0 = no reading) of global frames,
        as stored; ``ValueError`` when the data were made without ``clean_depth``."""
        if not self.config.clean_depth:
            raise ValueError(f"{self.root}: made without clean_depth = true; it holds no noiseless depth")
        frame_indices = np.asarray(frame_indices, np.int64).ravel()
        out = np.empty((len(frame_indices), self.config.height, self.config.width), np.float32)
        for k, (s, row) in enumerate(zip(*self._locate(frame_indices))):
            out[k] = self._shard(int(s))["clean_depth_mm"].read(int(row)) * np.float32(0.001)
        return out

    def prefetch(self, frame_indices: np.ndarray) -> None:
        """Start reading global frames that :meth:`frames` will be asked for soon (the disk reads them
        while the caller computes; see :meth:`NpzRows.advise`)."""
        shard, rows = self._locate(np.unique(np.asarray(frame_indices, np.int64).ravel()))
        for s in np.unique(shard):
            m = self._shard(int(s))
            for arr in m.values():
                arr.advise(rows[shard == s])

    def pair_batch(self, idx: np.ndarray) -> dict[str, np.ndarray]:
        """Pairs ``idx`` (indices into the pair arrays): ``rgb`` (B, 2, h, w, 3) uint8, ``depth``
        (B, 2, h, w) float32 m, ``action`` (B,) Action values, ``planar`` (B, 3), ``motion`` (B, 4, 4)."""
        idx = np.asarray(idx, np.int64)
        f = self.pairs[idx]
        rgb, depth = self.frames(np.stack([f, f + 1], axis=1))
        b = len(idx)
        return {
            "rgb": rgb.reshape(b, 2, *rgb.shape[1:]),
            "depth": depth.reshape(b, 2, *depth.shape[1:]),
            "action": self.pair_actions[idx],
            "planar": self.pair_planar[idx],
            "motion": self.pair_motion[idx],
        }

    def windows(self, length: int) -> np.ndarray:
        """Indices into the pair arrays of the pairs that start ``length - 1`` consecutive pairs of one
        episode (windows of ``length`` frames), e.g. for recurrent models."""
        if length < 2:
            raise ValueError(f"a window has at least 2 frames, got {length}")
        f = self.pairs
        ok = np.ones(len(f), bool)
        for j in range(1, length - 1):
            nxt = np.searchsorted(f, f + j)
            ok &= (nxt < len(f)) & (f[np.minimum(nxt, len(f) - 1)] == f + j)
        return np.flatnonzero(ok)

    def __getstate__(self) -> dict:
        state = self.__dict__.copy()
        state["_maps"] = {}
        return state
