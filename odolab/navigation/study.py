"""Navigation over many episodes and odometers: one Ray task per (odometer, episode), each result
saved as it finishes (a rerun does only what is missing); the tables and figures are
:mod:`odolab.navigation.report`'s.

Files under the output folder: ``config.json`` (what the results were made with; another config is
refused) and ``episodes/<odometer>/<episode>.json`` (one run each, with its paths and its ``key``: a
digest of everything the run depends on, :meth:`NavTask.key`). A saved run is reused only when its
key is the task's (a file without one, from an older version, when its odometer, episode, split,
seed and weights are the task's and its step count fits ``max_steps``) and its fields agree with
each other (:func:`row_problem`); any other is run again, and named on the console. Every file is
written through :func:`odolab.io.owned.owned_path`: never through a symbolic link.
"""

from __future__ import annotations

import hashlib
import json
import re
import reprlib
import sys
from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from odolab.config import SEED_RANGE, check, setting
from odolab.core.parallel import Execution, fan_out
from odolab.io.atomic import write_text_atomic
from odolab.io.inputs import read_input_json
from odolab.io.owned import check_owned_path, owned_path
from odolab.navigation.agent import PolicyConfig
from odolab.sim.episodes import EpisodeSpec
from odolab.sim.scenes import MAX_EPISODE_STEPS


@dataclass(frozen=True)
class Setting:
    """One setting a folder's results were made with, in the library's words: ``text`` follows the
    setting's name ``setting`` (``"seed"``, ``"(0 there, 1 now)"``), or stands alone (``setting`` None:
    ``"options of icp (...)"``)."""

    setting: str | None
    text: str

    def named(self, names: Mapping[str, str] | None = None) -> str:
        """The setting worded with ``names`` (e.g. a command line's options: ``{"seed": "--seed"}``)."""
        if self.setting is None:
            return self.text
        return f"{(names or {}).get(self.setting, self.setting)} {self.text}"


class RunFolderError(ValueError):
    """A folder (or a file in it) where navigation cannot keep its results. ``problem`` names it;
    ``advice`` says what to do, ``{folder}`` standing for whatever named the folder. A folder of
    results made with other settings lists them (``changes``) and, when some policy
    values would make this run the folder's, those (``to_match``). :meth:`named` words it with a
    command line's option and setting names; ``str()`` with the library's own."""

    def __init__(
        self, problem: str, advice: str, changes: tuple[Setting, ...] = (), to_match: tuple[Setting, ...] = ()
    ) -> None:
        self.problem, self.advice, self.changes, self.to_match = problem, advice, changes, to_match
        super().__init__(self.named("output folder"))

    def named(self, folder: str, settings: Mapping[str, str] | None = None) -> str:
        """The message with the folder called ``folder`` and the settings called ``settings``."""
        problem = self.problem
        if self.changes:
            problem += f" ({', '.join(c.named(settings) for c in self.changes)})"
        match = " ".join(m.named(settings) for m in self.to_match)
        return (
            f"{problem}; " + (f"to add to it, pass {match}; or " if match else "") + self.advice.format(folder=folder)
        )


@dataclass(frozen=True)
class NavEpisodes:
    """Which episodes a navigation run drives: the first ``episodes`` of a split from ``seed``, at most
    ``max_steps`` actions each."""

    episodes: int = setting(10, range=(1, 10_000), doc="episodes")
    seed: int = setting(0, range=SEED_RANGE, doc="episode seed")
    max_steps: int = setting(
        MAX_EPISODE_STEPS, range=(1, MAX_EPISODE_STEPS), doc="actions per episode at most (the Challenge's: 500)"
    )

    def __post_init__(self) -> None:
        check(self)

    def specs(self, split: str, **spec: Any) -> list[EpisodeSpec]:
        """The episodes of ``split``; ``spec``: the other :class:`EpisodeSpec` fields (noise, scenes, family)."""
        return [
            EpisodeSpec(split=split, index=i, seed=self.seed, max_steps=self.max_steps, **spec)
            for i in range(self.episodes)
        ]


@dataclass(frozen=True)
class NavTask:
    """One closed-loop episode to run: odometer name and constructor options, episode, policy."""

    odometer: str
    options: dict
    spec: EpisodeSpec
    policy: PolicyConfig
    identity_digest: str | None = (
        None  # Odometer.identity_digest: a retrained model's or changed setting's episodes rerun
    )

    def key(self) -> str:
        """SHA-256 of everything the run's result depends on: odometer, its options and weights,
        the whole episode spec (split, index, seed, max_steps, noise, camera) and the policy."""
        doc = {
            "odometer": self.odometer,
            "options": self.options,
            "weights": self.identity_digest,  # the key saved results were made with
            "spec": self.spec.record(),
            "policy": self.policy.record(),
        }
        return hashlib.sha256(json.dumps(doc, sort_keys=True, default=repr).encode()).hexdigest()


def run_task(task: NavTask) -> dict[str, Any]:
    """Run one task (in a Ray worker or here): a plain-data row with the outcome and the paths."""
    from odolab.navigation.episode import navigate
    from odolab.odometry.odometer import load_odometer

    run = navigate(task.spec, load_odometer(task.odometer, **task.options), task.policy)
    o = run.outcome
    return {
        "odometer": task.odometer,
        "episode": task.spec.index,
        "split": task.spec.split,
        "seed": task.spec.seed,
        "d0": o.d0,
        "d_end": o.d_end,
        "path": o.path,
        "stopped": o.stopped,
        "steps": o.steps,
        "collisions": o.collisions,
        "success": o.success,
        "spl": o.spl,
        "soft_spl": o.soft_spl,
        "failed_steps": run.failed_steps,
        "errors": list(run.errors),  # why steps failed (not checked on reading: a note, no number)
        "weights": task.identity_digest,
        "goal": list(run.goal),
        "true_xy": run.true_xy.round(4).tolist(),
        "believed_xy": run.believed_xy.round(4).tolist(),
        "max_steps": task.spec.max_steps,
        "key": task.key(),
    }


def _safe(name: str) -> str:
    """A folder name for an odometer name; names that differ only in other characters (a space in
    ``fused(a, b)``) still get different folders (a short hash of the exact name is appended)."""
    clean = re.sub(r"[^A-Za-z0-9_.-]", "_", name)
    return clean if clean == name else f"{clean}-{hashlib.sha1(name.encode()).hexdigest()[:8]}"


#: The layout of a run folder (``config.json`` and the episode files); a folder of another format is
#: refused, and is run again once deleted.
FORMAT = 1

ROW_KEYS = (
    "odometer",
    "episode",
    "split",
    "seed",
    "d0",
    "d_end",
    "path",
    "stopped",
    "steps",
    "collisions",
    "success",
    "spl",
    "soft_spl",
    "failed_steps",
    "goal",
    "true_xy",
    "believed_xy",
)


def _number(v: Any, low: float = -np.inf, high: float = np.inf) -> bool:
    """A finite int or float in [low, high] (NaN and infinities fail)."""
    return isinstance(v, (int, float)) and not isinstance(v, bool) and bool(np.isfinite(v)) and low <= v <= high


def _path(v: Any) -> bool:
    """(x, y) rows of finite JSON numbers (not text, not bools), no step longer than the runner's
    bound on a step (:data:`odolab.running.runner.MAX_STEP_TRANSLATION`)."""
    from odolab.running.runner import MAX_STEP_TRANSLATION

    if (
        not isinstance(v, list)
        or not v
        or not all(isinstance(p, list) and len(p) == 2 and all(map(_number, p)) for p in v)
    ):
        return False
    a = np.asarray(v, np.float64)
    return bool(np.isfinite(a).all()) and (
        len(a) < 2 or float(np.abs(np.diff(a, axis=0)).max()) <= MAX_STEP_TRANSLATION
    )


def _sane(row: dict) -> bool:
    """Values a real run can have: success 0/1, stopped a bool, SPL and SoftSPL in [0, 1], distances >= 0
    (d_end may be inf off the navigable space), counts >= 0, paths as finite (x, y) rows, one more than
    the steps, the believed one starting on the true start."""
    return (
        row["success"] in (0, 1)
        and not isinstance(row["success"], bool)
        and isinstance(row["stopped"], bool)
        and _number(row["spl"], 0, 1)
        and _number(row["soft_spl"], 0, 1)
        and (_number(row["d_end"], 0) or row["d_end"] == np.inf)
        and _number(row["d0"], 0)
        and _number(row["path"], 0)
        and all(
            isinstance(row[k], int) and not isinstance(row[k], bool) and row[k] >= 0
            for k in ("steps", "collisions", "failed_steps")
        )
        and _path(row["true_xy"])
        and _path(row["believed_xy"])
        and len(row["true_xy"]) == row["steps"] + 1
        and len(row["believed_xy"]) == len(row["true_xy"])
        and row["believed_xy"][0] == row["true_xy"][0]
        and _path([row["goal"]])
    )


def _same(value: Any, want: int) -> bool:
    """``value`` is the int ``want`` (not ``true`` for 1, not ``1.0``)."""
    return type(value) is int and value == want


#: Metres a path length may differ from the one of its saved positions, per step (they are rounded
#: to 0.1 mm: each step's length moves by at most sqrt(2) x 0.1 mm).
PATH_ROUNDING = 1.5e-4


def _close(a: float, b: float) -> bool:
    """``a`` and ``b`` equal but for float rounding (relative 1e-9)."""
    return abs(a - b) <= 1e-9 * max(1.0, abs(a), abs(b))


def row_problem(row: dict, task: NavTask) -> str | None:
    """Why a sane saved ``row`` (:func:`_sane`) is not ``task``'s result, or its fields contradict
    each other; None when it is. Its odometer, episode, split, seed and weights must be the task's,
    and its ``key``, when it has one (an older version's rows have none), the task's. The
    step count must fit ``task``'s ``max_steps`` (an episode ends at STOP, before the limit, or at
    the limit), success must follow from STOP and the final distance, SPL and SoftSPL from the
    distances and the path, and the path from the positions."""
    from odolab.navigation.metrics import SUCCESS_DISTANCE, path_length

    spec = task.spec
    if not (
        row["odometer"] == task.odometer
        and _same(row["episode"], spec.index)
        and row["split"] == spec.split
        and _same(row["seed"], spec.seed)
        and row.get("weights") == task.identity_digest
    ):
        return "made for another odometer, episode, split, seed, model file or setting"
    if "max_steps" in row and row["max_steps"] != spec.max_steps:
        return f"made with --max-steps {row['max_steps']!r}, not {spec.max_steps}"
    if "key" in row and row["key"] != task.key():
        return (
            "made with other settings (its key differs: odometer options, episode noise, camera or scenes, or policy)"
        )
    steps, stopped = row["steps"], row["stopped"]
    if steps > spec.max_steps:
        return f"{steps} steps, above --max-steps {spec.max_steps}"
    if not stopped and steps != spec.max_steps:
        return f"not stopped after {steps} steps, below --max-steps {spec.max_steps}"
    if stopped and steps == spec.max_steps:
        return f"stopped after {steps} steps, where --max-steps {spec.max_steps} ends an episode without STOP"
    success = float(stopped and row["d_end"] < SUCCESS_DISTANCE)
    if row["success"] != success:
        return (
            f"success {row['success']} with stopped {str(stopped).lower()} and {row['d_end']:.2f} m left "
            f"(success needs STOP within {SUCCESS_DISTANCE} m)"
        )
    efficiency = row["d0"] / max(row["d0"], row["path"])
    if not _close(row["spl"], success * efficiency):
        return f"spl {row['spl']} where success and the distances give {success * efficiency}"
    soft = max(0.0, 1.0 - row["d_end"] / row["d0"]) * efficiency
    if not _close(row["soft_spl"], soft):
        return f"soft_spl {row['soft_spl']} where the distances give {soft}"
    walked = path_length(np.asarray(row["true_xy"], np.float64))
    if abs(row["path"] - walked) > PATH_ROUNDING * max(steps, 1) + 1e-9:
        return f"path {row['path']} m where its positions give {walked:.4f} m"
    if row["failed_steps"] > steps or row["collisions"] > steps:
        return f"more failed steps or collisions than its {steps} steps"
    return None


def read_row(
    path: Path, task: NavTask, rejected: list[Path] | None = None, reasons: dict[Path, str] | None = None
) -> dict | None:
    """A saved result if it is whole, consistent and belongs to ``task``; None if it is missing,
    damaged or not ``task``'s (:func:`row_problem`), so that the episode is run again (such a file
    is appended to ``rejected`` and its reason put in ``reasons``, for the caller's note)."""
    if path.is_symlink():  # navigate writes no links; writing the rerun's result would go through it
        raise RunFolderError(
            f"{path} is a symbolic link where an episode's result file belongs", "delete it or choose another {folder}"
        )
    if not path.exists():
        return None
    if path.is_dir():  # a note and a rerun would end in "Is a directory" when the result is written
        raise RunFolderError(
            f"{path} is a folder where an episode's result file belongs", "delete it or choose another {folder}"
        )
    if not path.is_file():  # a pipe or device (or a link to one): the rerun's result could not replace it
        raise RunFolderError(
            f"{path} is not a regular file (a pipe, device or link to one) where an episode's result file belongs",
            "delete it or choose another {folder}",
        )
    try:
        row = read_input_json(path, "navigation result")  # size-capped, duplicate keys refused
        missing = [k for k in ROW_KEYS if k not in row] if isinstance(row, dict) else ["every field"]
        problem = (
            f"missing {', '.join(missing[:3])}"
            if missing
            else "values no run can have"
            if not _sane(row)
            else row_problem(row, task)
        )
    except ValueError:  # damaged, not a regular file, too large, or numbers too long to read
        problem = "not a readable result file"
    except (TypeError, KeyError):  # a field of an unexpected type reached a comparison
        problem = "values no run can have"
    if problem is not None:
        if rejected is not None:
            rejected.append(path)
        if reasons is not None:
            reasons[path] = problem
        return None
    return row


def _episode_changes(saved: Any, episodes: list[dict]) -> list[Setting]:
    """Which settings (``episodes``, ``seed``, ``split``, ``max_steps``) make ``episodes`` differ from a
    folder's saved ones."""
    if saved == episodes:
        return []
    if not isinstance(saved, list) or not saved or not all(isinstance(e, dict) for e in saved):
        return [Setting(None, f"the episodes ({reprlib.repr(saved)} there, not a list of episodes)")]
    said = [Setting("episodes", f"({len(saved)} there, {len(episodes)} now)")] if len(saved) != len(episodes) else []
    for key in ("seed", "split", "max_steps"):
        if saved[0].get(key) != episodes[0].get(key):
            said.append(Setting(key, f"({saved[0].get(key)} there, {episodes[0].get(key)} now)"))
    return said or [Setting(None, "the episodes' noise, camera or scenes")]


def _completed(policy: Any) -> Any:
    """A recorded policy (a folder's, or this run's) with the parameters :meth:`PolicyConfig.record`
    leaves out at their defaults, so that both are compared parameter by parameter."""
    return PolicyConfig.completed(policy) if isinstance(policy, dict) else policy


def _differing(saved: dict, policy: dict) -> list[str]:
    """The parameters, sorted, whose value or kind differ between a folder's saved policy and ``policy``
    (one only one of them records included)."""
    return [
        k
        for k in sorted(set(saved) | set(policy))
        if k not in saved or k not in policy or saved[k] != policy[k] or type(saved[k]) is not type(policy[k])
    ]


def _policy_changes(saved: Any, policy: dict) -> list[Setting]:
    """Which ``policy`` parameters make ``policy`` differ from a folder's saved one."""
    if not isinstance(saved, dict):
        return (
            [Setting(None, f"the policy ({reprlib.repr(saved)} there, not a table of parameters)")]
            if saved != policy
            else []
        )
    differ = _differing(saved, policy)
    if not differ:
        return []
    short = reprlib.Repr()
    short.maxstring, short.maxother = 30, 30

    def said(k: str) -> str:
        there = f"{short.repr(saved[k])} there" if k in saved else "not recorded there"
        now = f"{policy[k]!r} now" if k in policy else "no such parameter now"
        return Setting("policy", f"{k} ({there}, {now})")

    return [said(k) for k in differ]


def _policy_to_match(saved: Any, policy: dict) -> list[Setting]:
    """The ``policy key=value`` changes that make ``policy`` the folder's saved one (none when the
    saved policy is not a plain set of this version's numeric parameters)."""
    if not isinstance(saved, dict):
        return []
    diff = _differing(saved, policy)
    if not diff or not all(
        k in saved and k in policy and type(saved[k]) is type(policy[k]) and type(saved[k]) in (int, float)
        for k in diff
    ):
        return []
    try:  # a hand-edited value out of range is not suggested
        PolicyConfig(**{**policy, **{k: saved[k] for k in diff}})
    except (TypeError, ValueError):
        return []
    return [Setting("policy", f"{k}={saved[k]!r}") for k in diff]


def _option_changes(odometer: str, saved: Any, options: dict) -> str:
    """Which constructor options of ``odometer`` differ from a folder's saved ones."""
    if not isinstance(saved, dict):
        return f"options of {odometer}"
    short = reprlib.Repr()
    short.maxstring, short.maxlist = 40, 6
    keys = sorted(k for k in set(saved) | set(options) if saved.get(k) != options.get(k))
    said = ", ".join(
        f"{k}: {short.repr(saved[k]) if k in saved else 'default'} there, "
        f"{short.repr(options[k]) if k in options else 'default'} now"
        for k in keys[:3]
    )
    return f"options of {odometer} ({said}{', ...' if len(keys) > 3 else ''})"


def result_path(out: Path, odometer: str, index: int) -> Path:
    return out / "episodes" / _safe(odometer) / f"{index:04d}.json"


def run_navigation(
    out: Path,
    tasks: list[NavTask],
    config: dict,
    *,
    execution: Execution = Execution(),
) -> list[dict]:
    """Run the tasks whose results ``out`` lacks; returns every task's row, in task order.
    :class:`RunFolderError` for a folder (or a file in it) that cannot take them: another's files,
    results made with other settings, a link or a file where a result belongs."""

    out.mkdir(parents=True, exist_ok=True)
    cfg_path = out / "config.json"
    if not cfg_path.exists() and any(out.iterdir()):
        raise RunFolderError(
            f"{out} holds files that odolab navigate did not write (no config.json)", "choose an empty or new {folder}"
        )
    if cfg_path.is_dir():
        raise RunFolderError(
            f"{cfg_path} is a folder where navigate keeps its config file", "remove it or choose another {folder}"
        )
    if cfg_path.exists():
        try:
            saved = read_input_json(cfg_path, "navigation config")  # its errors name the file
        except ValueError as exc:
            raise RunFolderError(str(exc), "delete it or choose another {folder}") from None
        problem = (
            "not a JSON object"
            if not isinstance(saved, dict)
            else "its 'options' is not a JSON object"
            if not isinstance(saved.get("options", {}), dict)
            else None
        )
        if problem:
            raise RunFolderError(f"{cfg_path}: not a navigation config ({problem})", "choose another {folder}")
        if saved.get("format") != FORMAT:
            made = f"of format {reprlib.repr(saved['format'])}" if "format" in saved else "with no format number"
            raise RunFolderError(
                f"{cfg_path}: navigation results {made}; this odolab writes format {FORMAT}",
                "delete the folder to run them again, or choose another {folder}",
            )
        missing = [k for k in ("episodes", "policy") if k not in saved]  # every format-1 config has both
        if missing:
            raise RunFolderError(
                f"{cfg_path}: not a whole navigation config (no {' and no '.join(map(repr, missing))} in it), "
                "so what its results were made with is unknown",
                "delete the folder to run them again, or choose another {folder}",
            )
        episodes = _episode_changes(saved.get("episodes"), config["episodes"])
        saved_policy, asked = (_completed(saved.get("policy")), _completed(config.get("policy")))
        policy = _policy_changes(saved_policy, asked)
        options = [
            Setting(None, _option_changes(n, saved["options"][n], o))
            for n, o in config["options"].items()
            if n in saved.get("options", {}) and saved["options"][n] != o
        ]
        if episodes or policy or options:
            match = [] if episodes or options else _policy_to_match(saved_policy, asked)
            raise RunFolderError(
                f"{out} holds navigation results made with other settings",
                "choose another {folder} or delete it",
                changes=tuple(episodes + policy + options),
                to_match=tuple(match),
            )
        config = {**config, "options": {**saved.get("options", {}), **config["options"]}}
    for folder in {result_path(out, t.odometer, t.spec.index).parent for t in tasks}:
        for p in (folder.parent, folder):  # checked before any episode runs, not when its result is written
            if p.exists() and not p.is_dir() and not p.is_symlink():
                raise RunFolderError(
                    f"{p} is a file where navigate keeps a folder of episode results",
                    "delete it or choose another {folder}",
                )
    check_owned_path(out, "config.json")  # no link on the way to any file this run writes
    for t in tasks:
        check_owned_path(out, result_path(out, t.odometer, t.spec.index).relative_to(out))
    write_text_atomic(owned_path(out, "config.json"), json.dumps(config, indent=1) + "\n")
    rejected: list[Path] = []
    reasons: dict[Path, str] = {}
    todo = [t for t in tasks if read_row(result_path(out, t.odometer, t.spec.index), t, rejected, reasons) is None]
    for folder in sorted({p.parent for p in rejected}):  # one line per odometer, not one per episode
        names = sorted(p.name for p in rejected if p.parent == folder)
        said = "; ".join(f"{n}: {reasons[folder / n]}" for n in names[:3]) + (
            f"; {len(names) - 3} more" if len(names) > 3 else ""
        )
        print(
            f"note: {len(names)} saved episode(s) in {folder} are damaged, inconsistent or belong to another run, "
            f"model file, calibration or setting; running them again ({said})",
            file=sys.stderr,
        )

    if len(todo) < len(tasks):  # a rerun: say what it keeps
        print(
            f"note: {len(tasks) - len(todo)} of {len(tasks)} episode(s) were saved in {out} already; "
            + (f"running the other {len(todo)}" if todo else "nothing to run"),
            file=sys.stderr,
        )

    def done(k: int, row: dict) -> None:
        write_text_atomic(
            owned_path(out, result_path(out, todo[k].odometer, todo[k].spec.index).relative_to(out)),
            json.dumps(row) + "\n",
        )

    fan_out(
        run_task,
        todo,
        on_result=done,
        execution=execution,
        desc="navigation episodes",
    )
    return [json.loads(result_path(out, t.odometer, t.spec.index).read_text(encoding="utf-8")) for t in tasks]


def config_doc(odometers: list[str], options: dict, specs: list[EpisodeSpec], policy: PolicyConfig) -> dict:
    """The folder's layout (``format``) and what the results depend on (compared with a folder's ``config.json`` before reuse: the same
    episodes and policy, and the same options for an odometer run before; new odometers may join)."""
    return {
        "format": FORMAT,
        "options": {n: options.get(n, {}) for n in odometers},
        "episodes": [s.record() for s in specs],
        "policy": policy.record(),
    }
