"""Study: KITTI's relative errors on long routes. An agent tours goal after goal through a large
floor plan of the simulator until it has travelled the route's length; every odometer runs on every
route, and its integrated path is scored as KITTI's odometry benchmark scores one.

    python -m studies.kitti_style [--scale ci|cpu|paper] [--out reports/kitti-style] [--ray-address ADDR] [--redraw]

A route (odolab.sim.routes) has the episodes' laws: the challenge's actuation noise, collisions that stop
the agent at contact, Habitat's greedy shortest-path follower, RGB and Redwood depth noise; each
next goal is drawn from the route's seed among the navigable points within a set geodesic distance
of the agent, on a floor plan larger than an episode's, or, crossing a long building, ahead of the
agent along it (end_to_end_ratio: the median over 100 m segments of the distance between a segment's
ends over its length; near 0 where routes fold back and t_rel reads loop geometry more than drift). t_rel and r_rel follow KITTI's devkit:
segments of 100, 200, ..., 800 m of true path start at every 10th frame, the translation error (%)
and rotation error (deg per 100 m) of each are divided by its length and averaged over every
segment of every route; a route holds the lengths shorter than itself. ATE is the RMSE of the
position error with no alignment (every path starts at the true pose) and after an SE(3) fit; drift
is the final position error per 100 m travelled; dx, dz, dyaw the per-step error as used (x 1e-2), dx_bias, dz_bias, dyaw_bias its signed mean.
"""

from __future__ import annotations

import functools
import hashlib
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

import numpy as np

from odolab.config import check, setting
from odolab.core.metrics import KITTI_LENGTHS
from studies import framework

if TYPE_CHECKING:
    from odolab.sim.routes import RouteSpec

#: The folder under ``<out>`` of the trajectory files (the units write them, beside their results).
TRAJECTORIES = "trajectories"
#: KITTI's segment lengths (m), as whole numbers; a route holds those shorter than itself.
LENGTHS = tuple(int(L) for L in KITTI_LENGTHS)
#: What each route's files are: the TUM and KITTI formats, as ``odolab.compare`` writes them.
FORMATS = ("tum", "kitti")
_ROUTE_NAME = re.compile(r"(train|val|test)-s\d+-r\d{3,}")
_FILE_NAME = re.compile(r"[A-Za-z0-9_.+-]+")


# ------------------------------------------------------------------------------------ definition


@dataclass(frozen=True)
class Scale:
    """A scale's parameters (``studies/kitti_style.toml``): ``routes`` routes (indices 0, 1, ...) of
    ``split`` from ``seed``, each ending when ``length`` m are travelled, through a floor plan
    ``scene_scale`` times an episode's sides, each next goal ``min_leg``-``max_leg`` m (geodesic)
    from the agent, seen by a ``camera`` of (width, height) pixels; the ``odometers``."""

    split: Literal["train", "val", "test"] = setting(doc="the split whose scenes the routes run through")
    seed: int = setting(range=(0, 2**31 - 1), doc="the routes' seed")
    routes: int = setting(range=(1, 1000), doc="routes")
    length: float = setting(range=(1.0, 100_000.0), doc="metres travelled per route")
    scene_scale: float = setting(range=(1.0, 10.0), doc="the floor plan's sides over an episode's")
    min_leg: float = setting(range=(0.5, 1000.0), doc="the next goal's least geodesic distance, m")
    max_leg: float = setting(range=(0.5, 1000.0), doc="the next goal's greatest geodesic distance, m")
    camera: tuple[int, int] = setting(range=(16, 4096), doc="[width, height] in pixels")
    odometers: tuple[str, ...] = setting(min_items=1, distinct=True, doc="the odometers, by name")
    building: float = setting(0.0, range=(0.0, 2000.0), doc="a long building's length, m (0: rooms)")

    def __post_init__(self) -> None:
        check(self)
        if len(self.camera) != 2:
            raise ValueError(f"camera must be [width, height], got {list(self.camera)}")
        self.specs()  # RouteSpec names its field: "max_leg: expected ..., got ..."

    def specs(self) -> list[RouteSpec]:
        """The routes' specs (the challenge's noise, the camera's other settings as an episode's)."""
        from odolab.sim.camera import CameraSpec
        from odolab.sim.routes import RouteSpec

        camera = CameraSpec(width=self.camera[0], height=self.camera[1])
        return [
            RouteSpec(
                split=self.split,
                index=k,
                seed=self.seed,
                length=self.length,
                scene_scale=self.scene_scale,
                min_leg=self.min_leg,
                max_leg=self.max_leg,
                camera=camera,
                building=self.building,
            )
            for k in range(self.routes)
        ]


def route_label(spec: RouteSpec) -> str:
    """A route unit's name: ``"route test-s0-r000"``."""
    return f"route {spec.name}"


def run_label(odometer: str, spec: RouteSpec) -> str:
    """An odometer unit's name: ``"icp on test-s0-r000"``."""
    return f"{odometer} on {spec.name}"


def route_units(scale: Scale) -> list[framework.Unit]:
    """One unit per route (its motion and ground truth); the key is the route's spec and its digest
    (which holds the simulator's version)."""
    return [framework.Unit(route_label(s), {"route": s.to_dict(), "route_key": s.key()}) for s in scale.specs()]


def run_units_of(scale: Scale, identity: dict[str, str | None]) -> list[framework.Unit]:
    """One unit per (odometer, route); the key adds the odometer and its identity digest."""
    return [
        framework.Unit(
            run_label(odo, s),
            {"odometer": odo, "identity": identity[odo], "route": s.to_dict(), "route_key": s.key()},
        )
        for odo in scale.odometers
        for s in scale.specs()
    ]


# ------------------------------------------------------------------------------------ units


def file_name(odometer: str) -> str:
    """An odometer's trajectory file name without suffix, as ``odolab.compare`` names it
    (:func:`odolab.reporting.report.file_stem`: ``fused(a,b)`` -> ``fused_a_b_``, one file per name)."""
    from odolab.reporting.report import file_stem

    return file_stem(odometer)


def _sha256(path: Path) -> str | None:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest()
    except OSError:
        return None


def write_trajectory(out: Path, route: str, name: str, poses: np.ndarray) -> dict[str, str]:
    """``<out>/trajectories/<route>/<name>.tum`` (``T_world_cam``, frame i at i s) and ``.kitti``
    (poses in the first camera's frame) of ``poses`` (N, 4, 4) m, as ``odolab.compare`` writes them;
    returns each file's SHA-256 by format."""
    from odolab.core.geometry import invert
    from odolab.core.trajectory import Trajectory
    from odolab.io.kitti import write_kitti_poses
    from odolab.io.owned import owned_path
    from odolab.io.tum import write_tum_trajectory

    paths = {f: owned_path(out, f"{TRAJECTORIES}/{route}/{name}.{f}") for f in FORMATS}
    write_tum_trajectory(paths["tum"], Trajectory(np.arange(len(poses), dtype=float), poses))
    write_kitti_poses(paths["kitti"], Trajectory(None, invert(poses[0]) @ poses))
    return {f: _sha256(p) or "" for f, p in paths.items()}


def _xy(points: np.ndarray) -> list[list[float]]:
    """World (x, y) m rounded to 1 cm: the paths the figures draw."""
    return np.round(np.asarray(points, float)[:, :2], 2).tolist()


def _finite(v: float) -> float | None:
    return float(v) if math.isfinite(v) else None  # JSON has no NaN


def route_result(key: dict[str, Any], out: Path) -> dict[str, Any]:
    """One route's motion (no images): its statistics, goals and path, and its ground truth written
    as ``groundtruth.{tum,kitti}``. ``net_share``: per KITTI segment length the route holds, the mean
    straight-line distance between a segment's ends over its length (1 on a straight drive);
    ``building``: the long building's length (m; 0: a floor plan)."""
    from odolab.core.metrics import path_lengths
    from odolab.core.types import Action
    from odolab.reporting.report import GROUND_TRUTH_FILE
    from odolab.sim.routes import RouteSpec, tour

    spec = RouteSpec.from_dict(key["route"])
    route = tour(spec)
    poses = route.camera_poses(spec.camera.mount_height)
    lengths, net = net_shares(poses)
    return {
        "route": spec.name,
        "scene_seed": route.scene_seed,
        "scene_scale": route.scene_scale,
        "steps": len(route.actions),
        "length_m": float(path_lengths(poses[:, :3, 3])[-1]),
        "forward_share": float(np.mean([a == Action.MOVE_FORWARD for a in route.actions])),
        "collision_share": float(np.mean(route.collisions)),
        "goals": _xy(np.array(route.goals)),
        "reached": route.reached,
        "net_share": {str(L): float(net[lengths == L].mean()) for L in LENGTHS if np.any(lengths == L)},
        "building": float(spec.building),
        "path": _xy(poses[:, :3, 3]),
        "files": write_trajectory(out, spec.name, GROUND_TRUTH_FILE, poses),
    }


def score(gt_poses: np.ndarray, est_poses: np.ndarray) -> dict[str, Any]:
    """KITTI's errors, ATE and drift of integrated ``est_poses`` against ``gt_poses`` (N, 4, 4),
    computed by ``odolab.evaluate``'s library on the poses its KITTI files hold: t_rel %, r_rel
    deg/100 m, per segment length the segments and their summed errors (m/m, rad/m), ATE (m) with no
    alignment and SE(3)-aligned, the path length (m) and the final position error per 100 m (m)."""
    from odolab.core.geometry import invert
    from odolab.core.metrics import ate, path_lengths
    from odolab.core.trajectory import Trajectory
    from odolab.running.scoring import evaluate_trajectory, pair_trajectories

    gt = Trajectory(None, invert(gt_poses[0]) @ gt_poses)
    est = Trajectory(None, invert(est_poses[0]) @ est_poses)
    ev = evaluate_trajectory(gt, est, pair_trajectories(gt, est, "index"), align="none")
    k = ev.kitti
    segments = {
        str(int(L)): [
            int(np.sum(k.length == L)),
            float(k.t_err[k.length == L].sum()),
            float(k.r_err[k.length == L].sum()),
        ]
        for L in LENGTHS
        if np.any(k.length == L)
    }
    try:
        aligned: float | None = float(ate(ev.gt_poses, ev.est_poses, "se3").rmse)
    except ValueError:  # a degenerate path (every position on a line): no rigid fit
        aligned = None
    length = float(path_lengths(gt_poses[:, :3, 3])[-1])
    final = float(np.linalg.norm(est_poses[-1, :3, 3] - gt_poses[-1, :3, 3]))
    return {
        "t_rel": _finite(k.t_rel),
        "r_rel": _finite(k.r_rel),
        "segments": segments,
        "ate_m": float(ev.ate.rmse),
        "ate_se3_m": aligned,
        "length_m": length,
        "drift_per_100m": 100.0 * final / length if length > 0 else None,
    }


def run_result(key: dict[str, Any], out: Path) -> dict[str, Any]:
    """One odometer on one route: the route's frames rendered as the runner asks for them, the
    integrated path scored (:func:`score`), the per-step error as used (x 1e-2), failures and speed,
    and the trajectory written as ``<odometer>.{tum,kitti}``."""
    from odolab.odometry.action_prior import ActionPrior
    from odolab.reporting.pipeline import load_odometers
    from odolab.running.runner import run_sequence
    from odolab.running.summary import summarize
    from odolab.sim.routes import RouteFrames, RouteSpec, tour

    spec = RouteSpec.from_dict(key["route"])
    name = key["odometer"]
    result = run_sequence(load_odometers([name])[name], RouteFrames(spec, tour(spec)), name, ActionPrior.shipped())
    row = summarize([result])[0]
    return {
        "route": spec.name,
        "odometer": name,
        **score(result.gt_poses, result.poses),
        "dx": float(row.dx),
        "dz": float(row.dz),
        "dyaw": float(row.dyaw),
        "dx_bias": float(row.dx_bias),
        "dz_bias": float(row.dz_bias),
        "dyaw_bias": float(row.dyaw_bias),
        "steps": int(row.steps),
        "failures": int(row.failures),
        "step_seconds": float(result.step_seconds.sum()),
        "reference": bool(row.reference),
        "path": _xy(result.poses[:, :3, 3]),
        "files": write_trajectory(out, spec.name, file_name(name), result.poses),
    }


# ------------------------------------------------------------------------------------ saved results


def _num(v: Any, low: float = 0.0) -> bool:
    """A finite number >= ``low`` (not a bool)."""
    try:
        return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= low
    except OverflowError:
        return False


def _path_ok(path: Any) -> bool:
    return isinstance(path, list) and len(path) >= 2 and all(isinstance(p, list) and len(p) == 2 for p in path)


def _files_ok(value: dict[str, Any], name: str, out: Path, check_files: bool) -> bool:
    """The result's files are named by their digests; with ``check_files`` each must still be there."""
    files = value.get("files")
    if not (isinstance(files, dict) and set(files) == set(FORMATS) and all(isinstance(d, str) for d in files.values())):
        return False
    if not (
        isinstance(value.get("route"), str) and _ROUTE_NAME.fullmatch(value["route"]) and _FILE_NAME.fullmatch(name)
    ):
        return False
    folder = out / TRAJECTORIES / value["route"]
    return not check_files or all(_sha256(folder / f"{name}.{f}") == d for f, d in files.items())


def valid_route(value: Any, out: Path, check_files: bool = True) -> bool:
    """Whether a saved value has :func:`route_result`'s shape (and, with ``check_files``, its files)."""
    from odolab.reporting.report import GROUND_TRUTH_FILE

    return (
        isinstance(value, dict)
        and type(value.get("scene_seed")) is int
        and _num(value.get("scene_scale"), 1.0)
        and type(value.get("steps")) is int
        and all(_num(value.get(k)) for k in ("length_m", "forward_share", "collision_share"))
        and type(value.get("reached")) is int
        and isinstance(value.get("net_share"), dict)
        and all(k in map(str, LENGTHS) and _num(v) for k, v in value["net_share"].items())
        and isinstance(value.get("goals"), list)
        and _path_ok(value.get("path"))
        and len(value["path"]) == value["steps"] + 1
        and _files_ok(value, GROUND_TRUTH_FILE, out, check_files)
    )


def valid_run(value: Any, out: Path, check_files: bool = True) -> bool:
    """Whether a saved value has :func:`run_result`'s shape (and, with ``check_files``, its files)."""
    if not (isinstance(value, dict) and isinstance(value.get("odometer"), str)):
        return False
    numbers = ("ate_m", "length_m", "dx", "dz", "dyaw", "step_seconds")
    signed = ("dx_bias", "dz_bias", "dyaw_bias")
    maybe = ("t_rel", "r_rel", "ate_se3_m", "drift_per_100m")
    segments = value.get("segments")
    return (
        all(_num(value.get(k)) for k in numbers)
        and all(_num(value.get(k), -math.inf) for k in signed)
        and all(value.get(k) is None or _num(value.get(k)) for k in maybe)
        and all(type(value.get(k)) is int for k in ("steps", "failures"))
        and isinstance(value.get("reference"), bool)
        and isinstance(segments, dict)
        and all(
            k in map(str, LENGTHS) and isinstance(s, list) and len(s) == 3 and type(s[0]) is int and s[0] > 0
            and _num(s[1]) and _num(s[2])
            for k, s in segments.items()
        )
        and _path_ok(value.get("path"))
        and len(value["path"]) == value["steps"] + 1
        and _files_ok(value, file_name(value["odometer"]), out, check_files)
    )  # fmt: skip


# ------------------------------------------------------------------------------------ table


def pooled(results: list[dict[str, Any]]) -> dict[str, Any]:
    """KITTI's pooling over routes: every segment of every route counts once; t_rel %, r_rel
    deg/100 m overall and per length (``t_rel_<L>m``), and the segments."""
    out: dict[str, Any] = {"segments": 0}
    n = t = r = 0.0
    for L in LENGTHS:
        got = [res["segments"][str(L)] for res in results if str(L) in res["segments"]]
        if got:
            nl, tl, rl = (sum(g[i] for g in got) for i in range(3))
            out[f"t_rel_{L}m"] = 100.0 * tl / nl
            out[f"r_rel_{L}m"] = math.degrees(rl / nl) * 100.0
            n, t, r = n + nl, t + tl, r + rl
    out["segments"] = int(n)
    out["t_rel"] = 100.0 * t / n if n else float("nan")
    out["r_rel"] = math.degrees(r / n) * 100.0 if n else float("nan")
    return out


def _mean(values: list[float | None]) -> float:
    got = [v for v in values if v is not None]
    return float(np.mean(got)) if got else float("nan")


def summary_row(odometer: str, route: str, results: list[dict[str, Any]]) -> dict[str, Any]:
    """A table row of ``results`` (one odometer on one or more routes): KITTI's errors pooled, ATE and
    drift per 100 m averaged over the routes, the per-step error and failures over all steps."""
    steps = sum(r["steps"] for r in results)
    seconds = sum(r["step_seconds"] for r in results)
    return {
        "odometer": odometer,
        "route": route,
        "routes": len(results),
        "length_m": sum(r["length_m"] for r in results),
        "steps": steps,
        **pooled(results),
        "ate_m": _mean([r["ate_m"] for r in results]),
        "ate_se3_m": _mean([r["ate_se3_m"] for r in results]),
        "drift_per_100m": _mean([r["drift_per_100m"] for r in results]),
        **{c: sum(r[c] * r["steps"] for r in results) / steps if steps else float("nan") for c in PER_STEP},
        "failure_share": sum(r["failures"] for r in results) / steps if steps else float("nan"),
        "fps": steps / seconds if seconds > 0 and not any(r["reference"] for r in results) else float("nan"),
    }


#: The per-step columns (x 1e-2, as used, pooled over steps): absolute error, then the bias (signed mean).
PER_STEP = ("dx", "dz", "dyaw", "dx_bias", "dz_bias", "dyaw_bias")


def net_shares(poses: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """KITTI's segments of a path of (N, 4, 4) poses: each segment's length (m) and the straight-line
    distance between its ends over that length (1 on a straight drive)."""
    from odolab.core.metrics import kitti_relative_errors

    k = kitti_relative_errors(poses, poses)
    return k.length, np.linalg.norm(poses[k.last, :3, 3] - poses[k.first, :3, 3], axis=1) / k.length


def end_to_end_ratio(path: list[list[float]]) -> float:
    """The median over a route's 100 m segments (KITTI's, of its true path: world x, y m) of the
    straight-line distance between a segment's ends over its path length: near 1 a route that goes
    somewhere, near 0 one that folds back (where t_rel measures loop geometry more than drift); NaN
    for a route shorter than 100 m."""
    lengths, net = net_shares(_poses(path))
    return float(np.median(net[lengths == 100])) if np.any(lengths == 100) else float("nan")


#: The columns of the pooled rows' 95 % intervals over routes (Student's t over the per-route values).
ROUTE_CI = ("t_rel", "r_rel", "drift_per_100m")


def table(scale: Scale, runs: dict[str, Any], routes: dict[str, Any] | None = None) -> list[dict[str, Any]]:
    """Rows odometer x route: each odometer's routes pooled ("all"), then route by route. Each row has
    the route's ``end_to_end_ratio`` (:func:`end_to_end_ratio`; pooled: the median of the routes'),
    and the pooled rows 95 % intervals over routes of t_rel, r_rel and drift (``<column>_ci``)."""
    from odolab.core.stats import mean_ci

    ratio = {
        s.name: end_to_end_ratio(routes[route_label(s)]["path"])
        for s in scale.specs()
        if route_label(s) in (routes or {})
    }
    rows = []
    for odo in scale.odometers:
        mine = [(s.name, runs[run_label(odo, s)]) for s in scale.specs() if run_label(odo, s) in runs]
        if mine:
            each = [
                summary_row(odo, name, [r]) | {"end_to_end_ratio": ratio.get(name, float("nan"))} for name, r in mine
            ]
            pooled_row = summary_row(odo, "all", [r for _, r in mine])
            pooled_row["end_to_end_ratio"] = (
                float(np.median([ratio[n] for n, _ in mine])) if all(n in ratio for n, _ in mine) else float("nan")
            )
            for c in ROUTE_CI:
                ci = mean_ci(np.array([e[c] for e in each], float))
                pooled_row[f"{c}_ci"] = f"[{ci.low:.2f}, {ci.high:.2f}]" if math.isfinite(ci.low) else ""
            rows += [pooled_row, *each]
    return rows


def held_lengths(rows: list[dict[str, Any]]) -> list[int]:
    """KITTI's segment lengths some route holds (m)."""
    return [L for L in LENGTHS if any(f"t_rel_{L}m" in r for r in rows)]


def columns(rows: list[dict[str, Any]]) -> list[str]:
    """The table's columns: the per-length t_rel of the lengths held."""
    per_length = [f"t_rel_{L}m" for L in held_lengths(rows)]
    return [
        "odometer", "route", "routes", "length_m", "end_to_end_ratio", "steps", "segments", "t_rel", "t_rel_ci",
        "r_rel", "r_rel_ci", *per_length, "ate_m", "ate_se3_m", "drift_per_100m", "drift_per_100m_ci", *PER_STEP,
        "failure_share", "fps",
    ]  # fmt: skip


def _spearman(a: list[float], b: list[float]) -> float:
    """Spearman's rank correlation of two equally long lists (NaN with fewer than 3 pairs or no spread)."""
    pairs = [(x, y) for x, y in zip(a, b) if math.isfinite(x) and math.isfinite(y)]
    if len(pairs) < 3:
        return float("nan")
    from scipy.stats import spearmanr

    rho = spearmanr([p[0] for p in pairs], [p[1] for p in pairs]).statistic
    return float(rho)


def findings(rows: list[dict[str, Any]], routes: list[dict[str, Any]]) -> list[str]:
    """The paper has no KITTI-style table: which lengths the routes hold (against KITTI's), who drifts
    least, and whether the per-step error (the paper's measure) orders the odometers as t_rel and
    r_rel do."""
    from odolab.reporting.report import counted

    held = held_lengths(rows)
    said = ", ".join(f"{L}" for L in held) or "none"
    out = [
        (
            "The paper (Zhao et al., ICCV 2021) has no KITTI-style table: it reports per-step errors and "
            "navigation, on episodes of 1-30 m; there are no paper numbers to agree or differ with."
        ),
        (
            f"Segment lengths held (m): {said}, of KITTI's 100-800 m; a route holds the lengths shorter than "
            "itself. t_rel and r_rel pool these lengths; KITTI's own figures pool all eight (of road drives), so the "
            "two compare in kind, not number for number."
        ),
    ]
    if routes:
        lengths = [r["length_m"] for r in routes]
        out.append(
            f"Routes: {len(routes)}, {min(lengths):.0f}-{max(lengths):.0f} m, {np.mean([r['steps'] for r in routes]):.0f} "
            f"steps on average, {100 * np.mean([r['collision_share'] for r in routes]):.1f} % of steps collided "
            f"(episodes: 7-8 %), {counted(sum(r['reached'] for r in routes), 'goal')} reached."
        )
        net = {L: [r["net_share"][str(L)] for r in routes if str(L) in r["net_share"]] for L in held}
        out.append(
            "A segment's ends lie, on average, "
            + ", ".join(f"{100 * np.mean(v):.0f} % ({L} m)" for L, v in net.items() if v)
            + " of its length apart (on a straight drive: 100 %). A segment's translation error is the distance "
            "between its true and its estimated displacement, so a heading error moves a short displacement "
            "little: routes whose segments end near their start show less t_rel than a straight drive with the "
            "same heading drift would; r_rel does not depend on it."
        )
    overall = [r for r in rows if r["route"] == "all" and math.isfinite(r["t_rel"])]
    if overall:
        best_t = min(overall, key=lambda r: r["t_rel"])
        best_r = min(overall, key=lambda r: r["r_rel"])
        out.append(
            f"Lowest t_rel: {best_t['odometer']} ({best_t['t_rel']:.2f} %); lowest r_rel: {best_r['odometer']} "
            f"({best_r['r_rel']:.2f} deg/100 m)."
        )
        rho_t = _spearman([r["t_rel"] for r in overall], [r["dx"] + r["dz"] for r in overall])
        rho_r = _spearman([r["r_rel"] for r in overall], [r["dyaw"] for r in overall])
        out.append(
            f"Rank correlation over the {len(overall)} odometers: t_rel with the per-step translation error "
            f"(dx + dz) {rho_t:+.2f}, r_rel with the per-step heading error (dyaw) {rho_r:+.2f} (1: the same "
            "order; '+nan': fewer than 3 odometers)."
        )
    return out


# ------------------------------------------------------------------------------------ figures


def draw_errors(rows: list[dict[str, Any]], path: Path) -> None:
    """Bars of t_rel and r_rel per odometer (all routes pooled, a dot per route), and t_rel per
    segment length, one line per odometer."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from odolab.io.atomic import save_figure_atomic

    overall = [r for r in rows if r["route"] == "all"]
    names = [r["odometer"] for r in overall]
    fig, axes = plt.subplots(1, 3, figsize=(16, 0.45 * len(overall) + 2.8))
    y = np.arange(len(overall))
    for ax, key, label in ((axes[0], "t_rel", "t_rel (%)"), (axes[1], "r_rel", "r_rel (deg / 100 m)")):
        ax.barh(y, [r[key] for r in overall], color="tab:blue", alpha=0.8, label="all routes (KITTI's pooling)")
        for k, name in enumerate(names):
            per = [r[key] for r in rows if r["odometer"] == name and r["route"] != "all"]
            ax.plot(per, [k] * len(per), "o", color="k", ms=3, label="one route" if k == 0 else None)
        ax.set_yticks(y, names if ax is axes[0] else [""] * len(names))
        ax.invert_yaxis()
        ax.set_xlabel(label)
        ax.grid(axis="x", alpha=0.3)
    held = held_lengths(rows)
    for k, r in enumerate(overall):
        axes[2].plot(held, [r.get(f"t_rel_{L}m", np.nan) for L in held], "o-", color=f"C{k % 10}", label=r["odometer"])
    axes[2].set_xlabel("segment length (m)")
    axes[2].set_ylabel("t_rel (%)")
    axes[2].set_xticks(held)
    axes[2].grid(alpha=0.3)
    axes[2].legend(fontsize=7, loc="best")
    fig.suptitle("KITTI's relative errors on the long routes (segments of the lengths the routes hold)")
    fig.legend(*axes[0].get_legend_handles_labels(), loc="lower left", ncol=2, fontsize=8, frameon=False)
    fig.tight_layout(rect=(0, 0.08, 1, 1))
    save_figure_atomic(fig, path)
    plt.close(fig)


def _poses(xy: list[list[float]]) -> np.ndarray:
    """(N, 4, 4) poses at the saved (x, y) m, for the top-down figure (which draws positions only)."""
    p = np.tile(np.eye(4), (len(xy), 1, 1))
    p[:, :2, 3] = np.asarray(xy, float)
    return p


#: The families a route figure gives a panel each (:func:`family`), in order.
FAMILIES = ("references", "classical", "learned", "composites")


def family(odometer: str) -> str:
    """The panel an odometer is drawn in: ``composites`` (fused, denoised, ... : a name with
    parentheses), ``learned`` (robust-vo, deepvo), ``references`` (the action prior) or ``classical``."""
    if "(" in odometer:
        return "composites"
    if odometer in ("robust-vo", "deepvo"):
        return "learned"
    return "references" if odometer in ("action-prior", "ground-truth") else "classical"


def draw_route(route: dict[str, Any], runs: list[tuple[str, dict[str, Any]]], names: list[str], path: Path) -> None:
    """Top-down figure of one route, one panel per odometer family (:data:`FAMILIES`) with the true
    path (black) and the floor plan in each: world x, y in m; each odometer keeps its colour
    (:func:`odolab.reporting.report.trajectory_style`) in every route's figure."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from odolab.io.atomic import save_figure_atomic
    from odolab.reporting.report import FloorPlan, draw_floor_plan, trajectory_style
    from odolab.sim.scenes import generate_scene

    gt = np.asarray(route["path"], float)
    building = float(route.get("building", 0.0))
    scene = generate_scene(route["scene_seed"], scale=route["scene_scale"], length=building or None)
    panels = [f for f in FAMILIES if any(family(n) == f for n, _ in runs)] or ["references"]  # no run: the route
    everything = np.concatenate([gt] + [np.asarray(r["path"], float) for _, r in runs])
    lo, hi = everything.min(axis=0) - 2.0, everything.max(axis=0) + 2.0
    wide = building > 0 or (hi[0] - lo[0]) > 2 * (hi[1] - lo[1])
    size = (16, 2.2 * len(panels) + 1.2) if wide else (5.2 * len(panels), 6.2)
    fig, axes = plt.subplots(*((len(panels), 1) if wide else (1, len(panels))), figsize=size, squeeze=False)
    drawn = [n for n in names if n != "ground-truth"]
    for ax, fam in zip(axes.ravel(), panels):
        draw_floor_plan(ax, FloorPlan(scene.free, scene.origin, scene.resolution), aspect="auto")
        ax.plot(gt[:, 0], gt[:, 1], "k-", lw=2.2, label="ground truth", zorder=3)
        for name, r in runs:
            if family(name) != fam:
                continue
            p = np.asarray(r["path"], float)
            color, _ = trajectory_style(drawn.index(name))
            ax.plot(p[:, 0], p[:, 1], "-", lw=1.3, color=color, label=name, zorder=4)
            ax.plot(p[-1, 0], p[-1, 1], "s", ms=6, color=color, markeredgecolor="k", markeredgewidth=0.6, zorder=5)
        ax.plot(gt[0, 0], gt[0, 1], "o", ms=8, color="w", markeredgecolor="k", markeredgewidth=1.5, zorder=6)
        ax.set_xlim(lo[0], hi[0])
        ax.set_ylim(lo[1], hi[1])
        if not wide:
            ax.set_aspect("equal", adjustable="box")
        ax.set_title(fam, fontsize=10, loc="left")
        ax.set_xlabel("world x (m)")
        ax.set_ylabel("world y (m)")
        ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.0, 1.0) if wide else (0.0, -0.15), frameon=False)
    stretched = " (x and y drawn to different scales: the building is long)" if wide else ""
    fig.suptitle(f"Route {route['route']}, {len(gt) - 1} steps: true path (black) and each odometer's{stretched}")
    fig.tight_layout()
    save_figure_atomic(fig, path)
    plt.close(fig)


# ------------------------------------------------------------------------------------ main


def check_folder(out: Path) -> None:
    """Refuse an ``out`` whose trajectory folder is a link or a file."""
    from odolab.cli import UsageError
    from odolab.io.owned import UnsafeOutputError, check_owned_folder

    try:
        check_owned_folder(out, TRAJECTORIES)
    except UnsafeOutputError as exc:
        raise UsageError(f"--out {out}: {exc}") from None


def intro(scale_name: str, scale: Scale, rows: list[dict[str, Any]], note: str) -> list[str]:
    """The report's opening paragraphs: what is measured, at which scale, and where the files are."""
    held = ", ".join(map(str, held_lengths(rows))) or "none"
    return [
        " ".join(__doc__.split("\n\n")[2].split()),
        (
            f"Scale {scale_name}: {scale.routes} route(s) of {scale.length:g} m ({scale.split} split, seed {scale.seed}) "
            + (
                f"across buildings {scale.building:g} m long (an episode's plan width x {scale.scene_scale:g}), "
                "each goal ahead along it, "
                if scale.building
                else f"through floor plans of {scale.scene_scale:g} x an episode's sides, "
            )
            + f"goals {scale.min_leg:g}-"
            f"{scale.max_leg:g} m apart; camera {scale.camera[0]} x {scale.camera[1]} px. Segment lengths held: "
            f"{held} m. Rows: each odometer over all routes (route 'all'), then route by route; t_rel in %, r_rel in "
            f"deg/100 m, ATE in m, drift in m per 100 m travelled, dx dz dyaw x 1e-2 (m, m, rad) and their signed means (the bias, which integrates into drift), fps in steps/s.{note}"
        ),
        (
            f"Trajectories: {TRAJECTORIES}/<route>/<odometer>.tum (world frame, frame i at i s) and .kitti (first "
            f"camera's frame), beside groundtruth.tum and .kitti. 'python -m odolab.evaluate "
            f"{TRAJECTORIES}/<route>/groundtruth.kitti {TRAJECTORIES}/<route>/<odometer>.kitti' prints a row's "
            "t_rel, r_rel and ate_se3_m; with --align none, its ate_m. evo reads the same files. The folder "
            "keeps the files of every route and odometer ever computed into it, as results/ keeps their results; "
            "this table's are the routes and odometers above."
        ),
    ]


def study_config() -> framework.StudyConfig:
    """``studies/kitti_style.toml`` (``ValueError`` names the file and field)."""
    return framework.load_study("kitti_style")


def run(args) -> int:
    """The study as its command line (:mod:`odolab.cli.study`) asks; 0 when its report is written."""
    from odolab.cli import UsageError, execution_of
    from odolab.reporting.report import counted

    try:
        config = study_config()
        scale = framework.scale_params(config, args.scale, Scale)
        identity = framework.identities(config, args.scale, scale.odometers)
    except ValueError as exc:
        raise UsageError(str(exc)) from None
    out = args.out or framework.default_out(config)
    _held = framework.check_options(args, out, config)  # this run's hold on out, kept until main returns
    check_folder(out)
    out = out.resolve()  # the units run elsewhere (Ray workers): the path they write under is absolute
    execution = execution_of(args)
    store = framework.ResultStore(out / "results")
    check = not args.redraw
    routes = framework.run_units(
        functools.partial(route_result, out=out),
        route_units(scale),
        store,
        redraw=args.redraw,
        execution=execution,
        valid=functools.partial(valid_route, out=out, check_files=check),
    )
    runs = framework.run_units(
        functools.partial(run_result, out=out),
        run_units_of(scale, identity),
        store,
        redraw=args.redraw,
        execution=execution,
        valid=functools.partial(valid_run, out=out, check_files=check),
    )
    outcome = framework.Outcome(
        results={**routes.results, **runs.results},
        computed=[*routes.computed, *runs.computed],
        missing=[*routes.missing, *runs.missing],
        seconds=routes.seconds + runs.seconds,
    )
    framework.require_results(outcome, out, args.scale)
    rows = table(scale, runs.results, routes.results)
    route_rows = [routes.results[route_label(s)] for s in scale.specs() if route_label(s) in routes.results]
    figures = {
        "kitti-errors.png": (
            "t_rel and r_rel per odometer, and t_rel per segment length",
            lambda p: draw_errors(rows, p),
        )
    }
    for s in scale.specs():
        if route_label(s) in routes.results:
            mine = [(o, runs.results[run_label(o, s)]) for o in scale.odometers if run_label(o, s) in runs.results]
            figures[f"route-{s.name}.png"] = (
                (
                    f"Route {s.name}, top-down (world x, y in m), a panel per family of odometers: the true path "
                    "(black) and each odometer's integrated path"
                    + (" (x and y to different scales)" if s.building else " over the floor plan (grey: obstacles)")
                    + "; circle: start, squares: ends"
                ),
                functools.partial(draw_route, routes.results[route_label(s)], mine, list(scale.odometers)),
            )
    report = framework.Report(
        title=config.title,
        intro=intro(args.scale, scale, rows, framework.outcome_note(outcome)),
        columns=columns(rows),
        rows=rows,
        figures=figures,
        findings=findings(rows, route_rows),
        command=args.command,
        machine=framework.machines([routes, runs]),
        cpu_hours=outcome.seconds / 3600,
    )
    framework.write_report(report, out, owner=f"study {config.name}")
    print(framework.table_md(columns(rows)[:9], [r for r in rows if r["route"] == "all"]))
    print(f"({counted(len(routes.computed), 'route')} and {counted(len(runs.computed), 'odometer run')} computed)")
    framework.say_done(outcome, len(rows), out)
    return 0


if __name__ == "__main__":  # python -m studies.kitti_style: the command line is odolab.cli.study's
    import importlib

    study = importlib.import_module("odolab.cli.study")
    study.exit_process(study.command("kitti-style"))
