"""Real RGB-D recordings in the TUM RGB-D benchmark's folder layout, as an odolab ``Sequence``.

Layout (Sturm et al., IROS 2012): ``rgb.txt`` and ``depth.txt`` list ``timestamp path`` per
line (``#`` comments; paths relative to the folder), ``groundtruth.txt`` holds
``timestamp tx ty tz qx qy qz qw`` (``T_world_cam``, read by
:func:`odolab.io.tum.read_tum_trajectory`). Colour images are 8-bit, depth images 16-bit PNG with
metres = value / 5000 (0 = no reading), registered to the colour image.

A frame is an RGB image, the depth image nearest in time and the ground-truth sample nearest in
time, each within ``max_time_diff`` seconds (:func:`odolab.io.tum.associate`); frames without
all three are left out and counted (:attr:`TumSequence.dropped`). When the folder is read every
image of a kept frame is decoded once and checked (readable, colour 8-bit, depth 16-bit single
channel, the camera's size, inside the folder), so a bad file is found before any odometer runs;
frames are decoded again when asked for. Every problem raises
:class:`~odolab.io.errors.FileFormatError` naming the file, the line and what is wrong.

Other recordings in the same layout may store depth at another scale (many store millimetres:
``depth_scale=1000``) and come from another camera (``intrinsics``).
:meth:`TumSequence.depth_warning` says when the depth's median is implausible for the scale
(outside :data:`PLAUSIBLE_MEDIAN_DEPTH`), the sign of a wrong scale.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass
from pathlib import Path

import cv2
import numpy as np

from odolab.core.trajectory import Trajectory
from odolab.core.types import Action, Frame, Intrinsics
from odolab.io.errors import FileFormatError
from odolab.io.inputs import not_regular
from odolab.io.textfiles import read_lines
from odolab.io.tum import associate, read_tum_trajectory

__all__ = [
    "PLAUSIBLE_MEDIAN_DEPTH",
    "TUM_CAMERAS",
    "TUM_DEPTH_SCALE",
    "TumSequence",
    "UnknownCameraError",
    "load_tum_sequence",
    "tum_camera_for",
]

#: Depth PNG value per metre.
TUM_DEPTH_SCALE = 5000.0
#: Accepted depth scales (PNG value per metre): from 1 (metres) to 10^6 (micrometres).
DEPTH_SCALE_RANGE = (1.0, 1e6)
#: Median depth (m) of an RGB-D recording indoors: beyond this the depth scale is likely wrong
#: (a depth camera reads little nearer than 0.5 m, and its readings thin out beyond 4-5 m; TUM's
#: sequences have medians of 1-3 m, so TUM depth read as millimetres is 5-15 m, millimetres read
#: as TUM depth 0.2-0.6 m).
PLAUSIBLE_MEDIAN_DEPTH = (0.5, 5.0)
#: Frames whose depth the median is taken over (evenly spaced).
MEDIAN_FRAMES = 10


class UnknownCameraError(ValueError):
    """The folder's name names no TUM camera and no intrinsics were given."""


#: The benchmark's published pinhole intrinsics of its three Kinects (640x480, no undistortion).
TUM_CAMERAS: dict[str, Intrinsics] = {
    "freiburg1": Intrinsics(517.3, 516.5, 318.6, 255.3, 640, 480),
    "freiburg2": Intrinsics(520.9, 521.0, 325.1, 249.7, 640, 480),
    "freiburg3": Intrinsics(535.4, 539.2, 320.1, 247.6, 640, 480),
}

_CAMERA_IN_NAME = re.compile(r"(?:freiburg|fr)_?([123])(?![0-9])", re.IGNORECASE)


@dataclass(frozen=True)
class _Listed:
    """One image named in ``rgb.txt`` / ``depth.txt``: where, when, and which line said so."""

    timestamp: float
    path: Path
    list_file: Path
    line_no: int


@dataclass(frozen=True)
class _FrameFiles:
    """The files and ground truth that make one frame."""

    rgb: _Listed
    depth: _Listed
    gt_pose: np.ndarray


class TumSequence:
    """A TUM RGB-D recording as an :class:`odolab.odometry.odometer.Sequence` (frames decoded lazily).

    ``seq[i]`` is a :class:`~odolab.odometry.odometer.Frame`: ``rgb`` (H, W, 3) uint8 in RGB order,
    ``depth`` (H, W) float32 metres (0 = no reading), ``timestamp`` (s, the colour image's) and
    ``gt_pose`` ``T_world_cam`` (4x4, the nearest ground-truth sample). ``action(i)`` is always
    None (real data has no discrete actions); ``collisions`` is None (unknown).
    """

    collisions = None

    def __init__(
        self,
        root: Path,
        intrinsics: Intrinsics,
        frames: list[_FrameFiles],
        dropped: dict[str, int] | None = None,
        depth_scale: float = TUM_DEPTH_SCALE,
    ) -> None:
        self.root = root
        self.intrinsics = intrinsics
        #: Depth PNG value per metre.
        self.depth_scale = float(depth_scale)
        self._frames = frames
        #: Colour images left out, by reason: ``"no depth"`` (no depth image within the time
        #: limit) and ``"no ground truth"`` (no ground-truth sample within it).
        self.dropped = dict(dropped or {"no depth": 0, "no ground truth": 0})

    def check_images(self) -> None:
        """Decode every image once and check it (see the module docstring); raises
        :class:`~odolab.io.errors.FileFormatError` naming the first bad file."""
        for f in self._frames:
            self._read_rgb(f.rgb)
            self._read_depth(f.depth)

    def __len__(self) -> int:
        return len(self._frames)

    def median_depth(self) -> float | None:
        """The median (m) of the valid depth readings of up to :data:`MEDIAN_FRAMES` evenly spaced
        frames (the median of their medians), or None when none has a reading."""
        picks = np.unique(np.linspace(0, len(self._frames) - 1, min(MEDIAN_FRAMES, len(self._frames))).astype(int))
        medians = []
        for k in picks:
            depth = self._read_depth(self._frames[k].depth)
            valid = depth[depth > 0]
            if valid.size:
                medians.append(float(np.median(valid)))
        return float(np.median(medians)) if medians else None

    def depth_warning(self) -> str | None:
        """A sentence when :meth:`median_depth` is outside :data:`PLAUSIBLE_MEDIAN_DEPTH` (the depth
        scale is likely wrong, e.g. millimetres read at TUM's 5000 per metre), else None."""
        median = self.median_depth()
        low, high = PLAUSIBLE_MEDIAN_DEPTH
        if median is None or low <= median <= high:
            return None
        raw = median * self.depth_scale
        guess = next(
            (s for s in (1000.0, TUM_DEPTH_SCALE, 1.0) if low <= raw / s <= high and s != self.depth_scale), None
        )
        hint = (
            f" At {guess:g} per metre{' (millimetres)' if guess == 1000.0 else ''} it would be {raw / guess:.2f} m."
            if guess is not None
            else ""
        )
        return (
            f"{self.root}: the depth's median is {median:.2f} m at a depth scale of {self.depth_scale:g} PNG "
            f"values per metre, implausible for an RGB-D camera indoors (expected {low:g}-{high:g} m): "
            f"is the scale right?{hint}"
        )

    @property
    def name(self) -> str:
        """The folder's name, e.g. ``rgbd_dataset_freiburg1_xyz``."""
        return self.root.name

    def __repr__(self) -> str:
        return f"TumSequence({str(self.root)!r}, {len(self)} frames)"

    def __getitem__(self, i: int) -> Frame:
        f = self._frames[self._index(i)]
        return Frame(
            rgb=self._read_rgb(f.rgb),
            depth=self._read_depth(f.depth),
            timestamp=f.rgb.timestamp,
            gt_pose=f.gt_pose.copy(),
        )

    def action(self, i: int) -> Action | None:
        """None: a real recording has no discrete actions."""
        self._index(i)
        return None

    def gt_pose(self, i: int) -> np.ndarray:
        """``T_world_cam`` (4x4, metres) of frame ``i`` from the nearest ground-truth sample."""
        return self._frames[self._index(i)].gt_pose.copy()

    @property
    def timestamps(self) -> np.ndarray:
        """Frame times (N,), seconds (the colour images' timestamps)."""
        return np.array([f.rgb.timestamp for f in self._frames])

    def ground_truth(self) -> Trajectory:
        """The frames' ground-truth poses ``T_world_cam`` with the frames' timestamps."""
        return Trajectory(self.timestamps, np.stack([f.gt_pose for f in self._frames]))

    def _index(self, i: int) -> int:
        n = len(self._frames)
        if not isinstance(i, (int, np.integer)):
            raise TypeError(f"TumSequence indices must be integers, not {type(i).__name__}")
        if not -n <= i < n:
            raise IndexError(f"frame {i} out of range for a sequence of {n} frames")
        return int(i) % n

    def _check_size(self, listed: _Listed, shape: tuple[int, ...], kind: str) -> None:
        w, h = self.intrinsics.width, self.intrinsics.height
        if shape[:2] != (h, w):
            raise _image_error(listed, f"{kind} image is {shape[1]}x{shape[0]}, the camera's is {w}x{h}")

    def _read_rgb(self, listed: _Listed) -> np.ndarray:
        bgr = cv2.imread(str(listed.path), cv2.IMREAD_COLOR)
        if bgr is None:
            raise _image_error(listed, "cannot be read as an image")
        self._check_size(listed, bgr.shape, "colour")
        return np.ascontiguousarray(bgr[:, :, ::-1])

    def _read_depth(self, listed: _Listed) -> np.ndarray:
        raw = cv2.imread(str(listed.path), cv2.IMREAD_UNCHANGED)
        if raw is None:
            raise _image_error(listed, "cannot be read as an image")
        if raw.ndim != 2 or raw.dtype != np.uint16:
            kind = f"{raw.shape[2]}-channel " if raw.ndim == 3 else ""
            raise _image_error(listed, f"depth must be a 16-bit single-channel image, got {kind}{raw.dtype}")
        self._check_size(listed, raw.shape, "depth")
        return raw.astype(np.float32) / np.float32(self.depth_scale)


def tum_camera_for(folder: str | os.PathLike) -> Intrinsics | None:
    """The TUM camera named in a folder's name (``freiburg1``, ``fr2``...), or None."""
    match = _CAMERA_IN_NAME.search(Path(folder).resolve().name)
    return TUM_CAMERAS[f"freiburg{match.group(1)}"] if match else None


def load_tum_sequence(
    path: str | os.PathLike,
    intrinsics: Intrinsics | tuple[float, float, float, float] | None = None,
    max_time_diff: float = 0.02,
    check_images: bool = True,
    depth_scale: float = TUM_DEPTH_SCALE,
) -> TumSequence:
    """Read the TUM RGB-D folder ``path`` (see the module docstring) as a :class:`TumSequence`.

    ``intrinsics``: the camera, or its pinhole ``(fx, fy, cx, cy)`` in pixels (the image size is
    then the first colour image's); by default the TUM camera named in the folder's name
    (:class:`UnknownCameraError` when it names none).
    ``max_time_diff``: seconds allowed between a colour image and its depth image and between a
    frame and its ground-truth sample (TUM's ``associate.py`` uses 0.02).
    ``check_images``: decode and check every image now (:meth:`TumSequence.check_images`).
    ``depth_scale``: depth PNG value per metre (TUM: 5000; millimetres: 1000), in
    :data:`DEPTH_SCALE_RANGE`.
    """
    root = Path(path)
    if not root.is_dir():
        raise FileNotFoundError(f"{root}: no such folder (expected a TUM RGB-D sequence)")
    low, high = DEPTH_SCALE_RANGE
    if (
        isinstance(depth_scale, bool)
        or not isinstance(depth_scale, (int, float, np.number))
        or not math.isfinite(depth_scale)
        or not low <= depth_scale <= high
    ):
        raise ValueError(
            f"depth_scale must be a number of PNG values per metre in [{low:g}, {high:g}], got {depth_scale!r:.40}"
        )
    if intrinsics is not None and not isinstance(intrinsics, Intrinsics):
        intrinsics = tuple(intrinsics)
        if len(intrinsics) != 4 or not all(
            isinstance(v, (int, float, np.number)) and not isinstance(v, bool) and math.isfinite(v) for v in intrinsics
        ):
            raise ValueError(
                f"intrinsics must be an Intrinsics or four finite numbers (fx, fy, cx, cy), got {intrinsics!r:.80}"
            )
        if min(intrinsics[:2]) <= 0:
            raise ValueError(
                f"intrinsics: the focal lengths fx, fy must be positive, got {intrinsics[0]:g}, {intrinsics[1]:g}"
            )
    if intrinsics is None:
        intrinsics = tum_camera_for(root)
        if intrinsics is None:
            raise UnknownCameraError(
                f"{root}: cannot tell the camera from the folder name (no 'freiburg1/2/3' or "
                f"'fr1/2/3' in it); give its intrinsics=..., e.g. odolab.io.tum_rgbd.TUM_CAMERAS['freiburg1'] "
                "or (fx, fy, cx, cy)"
            )
    rgb = _read_list(root / "rgb.txt")
    if not isinstance(intrinsics, Intrinsics):  # the pinhole alone: the size is the images'
        first = cv2.imread(str(rgb[0].path), cv2.IMREAD_COLOR)
        if first is None:
            raise _image_error(rgb[0], "cannot be read as an image")
        fx, fy, cx, cy = (float(v) for v in intrinsics)
        w, h = int(first.shape[1]), int(first.shape[0])
        if not (0 <= cx <= w and 0 <= cy <= h):
            raise ValueError(
                f"intrinsics: the principal point (cx, cy) must lie in the {w} x {h} images, got ({cx:g}, {cy:g})"
            )
        if not all(0.05 * size <= f <= 20 * size for f, size in ((fx, w), (fy, h))):
            raise ValueError(
                f"intrinsics: focal lengths fx, fy of {fx:g}, {fy:g} pixels are implausible for "
                f"{w} x {h} images (expected 0.05 to 20 times the image width and height)"
            )
        intrinsics = Intrinsics(fx, fy, cx, cy, w, h)
    depth = _read_list(root / "depth.txt")
    gt = read_tum_trajectory(root / "groundtruth.txt")

    i_rgb, i_depth = associate(
        np.array([r.timestamp for r in rgb]), np.array([d.timestamp for d in depth]), max_time_diff
    )
    if len(i_rgb) == 0:
        raise FileFormatError(root, None, f"no colour image has a depth image within {max_time_diff} s")
    rgb_t = np.array([rgb[i].timestamp for i in i_rgb])
    i_pair, i_gt = associate(rgb_t, gt.timestamps, max_time_diff)
    if len(i_pair) == 0:
        raise FileFormatError(
            root,
            None,
            f"no frame has a ground-truth pose within {max_time_diff} s (frames {rgb_t[0]:.3f}-{rgb_t[-1]:.3f} s, "
            f"ground truth {gt.timestamps[0]:.3f}-{gt.timestamps[-1]:.3f} s)",
        )
    frames = [_FrameFiles(rgb[i_rgb[k]], depth[i_depth[k]], gt.poses[g]) for k, g in zip(i_pair, i_gt)]
    dropped = {"no depth": len(rgb) - len(i_rgb), "no ground truth": len(i_rgb) - len(i_pair)}
    seq = TumSequence(root, intrinsics, frames, dropped, float(depth_scale))
    if check_images:
        seq.check_images()
    return seq


def _read_list(path: Path) -> list[_Listed]:
    """Entries ``timestamp path`` of ``rgb.txt`` / ``depth.txt``, checked, in increasing time."""
    entries: list[_Listed] = []
    for no, line in enumerate(read_lines(path), start=1):
        text = line.strip()
        if not text or text.startswith("#"):
            continue
        fields = text.split()
        if len(fields) != 2:
            raise FileFormatError(path, no, f"expected 2 columns (timestamp path), got {len(fields)}")
        try:
            stamp = float(fields[0])
        except ValueError:
            raise FileFormatError(path, no, f"timestamp {fields[0]!r} is not a number") from None
        if not np.isfinite(stamp):
            raise FileFormatError(path, no, f"timestamp {fields[0]!r} is not finite")
        if entries and stamp <= entries[-1].timestamp:
            raise FileFormatError(
                path, no, f"timestamp {fields[0]} is not after the previous line's; times must increase"
            )
        if os.path.isabs(fields[1]) or os.path.normpath(fields[1]).split(os.sep)[0] == "..":
            raise FileFormatError(path, no, f"{fields[1]}: outside the sequence folder (paths must be relative to it)")
        image = path.parent / fields[1]
        problem = not_regular(image)  # only looked at: a pipe would block, /dev/zero never end
        if problem is not None:
            raise FileFormatError(path, no, f"{fields[1]}: {problem}")
        entries.append(_Listed(stamp, image, path, no))
    if not entries:
        raise FileFormatError(path, None, "lists no images (empty or only comments)")
    return entries


def _image_error(listed: _Listed, problem: str) -> FileFormatError:
    return FileFormatError(listed.path, None, f"{problem} (listed in {listed.list_file.name}, line {listed.line_no})")
