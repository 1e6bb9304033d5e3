"""Shared command-line plumbing: user mistakes become one line on stderr and exit code 2.

Every numeric option takes its kind, range, help and default from a config field
(:func:`add_setting`, :func:`setting_type`), parsed by :func:`number`, which refuses NaN and
infinity; output paths are checked by :func:`check_output_dir` and
:func:`check_output_file` *before* any work starts, so a run never ends on an unwritable path.
"""

from __future__ import annotations

import argparse
import contextlib
import errno
import math
import os
import re
import shlex
import signal
import sys
import tempfile
import threading
from collections.abc import Callable, Iterable, Sequence
from pathlib import Path
from typing import NoReturn

from odolab.cli.help_text import PlainHelp
from odolab.config import MAX_NUMBER_CHARS
from odolab.core.parallel import Execution
from odolab.io.lock import FolderLock

#: What argparse takes for a negative number rather than an option: -3, -.5, -1e3, -inf, -nan.
_NEGATIVE_NUMBER = re.compile(r"^-(\d+\.?\d*|\.\d+)([eE][-+]?\d+)?$|^-(inf|infinity|nan)$", re.IGNORECASE)


def _typed(text: str) -> str:
    """What the user typed, as an error line quotes it: an over-long number by its length."""
    return f"{text[:12]!r}... ({len(text)} characters)" if len(text) > MAX_NUMBER_CHARS else repr(text)


class UsageError(Exception):
    """A mistake in the user's input (bad argument, unreadable file...). The message names it."""


class ArgumentParser(PlainHelp):
    """argparse whose mistakes raise :class:`UsageError` (so :func:`run_cli` prints one line), and
    which takes options only as spelled in full (``--ep`` is not ``--episodes``)."""

    def __init__(self, *args, **kwargs) -> None:
        kwargs.setdefault("allow_abbrev", False)
        super().__init__(*args, **kwargs)
        # a value such as -1e3 or -inf is a (wrong) number for the option before it, not an unknown option
        self._negative_number_matcher = _NEGATIVE_NUMBER

    def error(self, message: str) -> None:  # type: ignore[override]
        # argparse says "argument --x: <type's message>"; ours already start with the option's name
        match = re.fullmatch(r"argument ([^:]+): (\S+) (.*)", message, flags=re.DOTALL)
        if match and match.group(2).rstrip(":") in match.group(1).split("/"):
            message = f"{match.group(2)} {match.group(3)}"
        raise UsageError(message)


def number(
    name: str, kind: type = int, minimum: float | None = None, maximum: float | None = None
) -> Callable[[str], float]:
    """An argparse ``type`` parsing ``kind`` (int or float) in ``[minimum, maximum]`` (either bound
    may be None); the error names the option: ``--episodes must be >= 1, got 0``. NaN and infinity
    are always refused."""
    show = (lambda v: str(int(v))) if kind is int else (lambda v: f"{v:g}")

    def parse(text: str):
        noun = "an integer" if kind is int else "a number"
        if len(text) > MAX_NUMBER_CHARS:
            bound = f" in [{show(minimum)}, {show(maximum)}]" if None not in (minimum, maximum) else ""
            raise argparse.ArgumentTypeError(f"{name} must be {noun}{bound}, got {_typed(text)}")
        try:
            if "_" in text or not text.isascii():  # Python reads "1_0" as 10 and "５" as 5: a typo, not a number
                raise ValueError(text)
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{name} must be {noun}, got {text!r}") from None
        if not math.isfinite(value):
            raise argparse.ArgumentTypeError(f"{name} must be a finite number, got {text}")
        if minimum is not None and value < minimum:
            bound = f"in [{show(minimum)}, {show(maximum)}]" if maximum is not None else f">= {show(minimum)}"
            raise argparse.ArgumentTypeError(f"{name} must be {bound}, got {text}")
        if maximum is not None and value > maximum:
            bound = f"in [{show(minimum)}, {show(maximum)}]" if minimum is not None else f"<= {show(maximum)}"
            raise argparse.ArgumentTypeError(f"{name} must be {bound}, got {text}")
        return value

    return parse


def setting_type(name: str, cls: type, field: str) -> Callable[[str], float]:
    """An argparse ``type`` for config field ``field`` of ``cls`` (an :func:`odolab.config.setting`
    with a range): a number of its kind in its range, so the option and the config file take the
    same values; the error names the option as :func:`number`'s do: ``--depth-noise must be in [0, 10], got 11``."""
    from odolab.config import in_range, number_kind, range_text

    kind = number_kind(cls, field)
    parse_number = number(name, kind)

    def parse(text: str):
        try:
            value = parse_number(text)
        except argparse.ArgumentTypeError:  # not a number of the field's kind: say which numbers it takes
            noun = "an integer" if kind is int else "a finite number"
            raise argparse.ArgumentTypeError(
                f"{name} must be {noun} in {range_text(cls, field)}, got {_typed(text)}"
            ) from None
        if not in_range(cls, field, value):
            raise argparse.ArgumentTypeError(f"{name} must be in {range_text(cls, field)}, got {text}")
        return value

    return parse


def setting_help(cls: type, field: str, default: object = None) -> str:
    """``--help`` text for an option of config field ``field``: its description, range and default
    (the field's own unless ``default`` is given)."""
    from odolab.config import describe

    row = next(s for s in describe(cls) if s.name == field)
    shown = row.value if default is None else default
    return f"{row.doc}, {row.range} (default {f'{shown:g}' if isinstance(shown, float) else shown})"


def field_default(cls: type, field: str) -> object:
    """The default value of config field ``field`` of ``cls``."""
    from odolab.config import describe

    return next(s.value for s in describe(cls) if s.name == field)


def add_setting(ap: argparse.ArgumentParser, option: str, cls: type, field: str, *, metavar: str | None = None) -> None:
    """Add ``option`` for config field ``field`` of ``cls`` (an :func:`odolab.config.setting` with a
    range): its type, range, help and default all come from the field, so the option and the library
    take the same values."""
    default = field_default(cls, field)
    ap.add_argument(
        option,
        type=setting_type(option, cls, field),
        default=default,
        metavar=metavar,
        help=setting_help(cls, field, default),
    )


def add_odometer_option(ap: argparse.ArgumentParser, example: str) -> None:
    """``--odometer-option NAME.key=value`` (repeatable, into a list): one odometer's constructor
    option; ``example`` ends the help, e.g. ``icp.max_depth=4.0``."""
    ap.add_argument(
        "--odometer-option",
        action="append",
        default=[],
        metavar="NAME.key=value",
        help=f"constructor option of one odometer, e.g. {example}",
    )


def add_scene_options(ap: argparse.ArgumentParser, family: bool = True) -> None:
    """``--scene-family`` (procedural scenes; with ``family``), or ``--scenes``, ``--scene-up`` and
    ``--scene-unit``: episodes in mesh files (:func:`scenes_of`)."""
    from odolab.sim.free_scenes import FAMILIES
    from odolab.sim.mesh_scenes import SceneFiles

    if family:
        ap.add_argument(
            "--scene-family",
            choices=FAMILIES,
            default="boxes",
            help="procedural scenes: boxes (axis-aligned rooms, exactly Manhattan; the default) or free (rooms "
            "at other angles, furniture at any yaw, point lights: docs/simulator.md#scene-families)",
        )
    ap.add_argument(
        "--scenes",
        type=path_arg("--scenes"),
        default=None,
        metavar="PATH",
        help="run the episodes in mesh files instead of procedural scenes: a GLB/glTF, PLY or OBJ file, or a "
        "folder of them (split by their digests: docs/simulator.md#scenes-from-mesh-files)",
    )
    ap.add_argument("--scene-up", choices=("y", "z"), default="y", help="--scenes: the files' up axis (default y)")
    ap.add_argument(
        "--scene-unit",
        type=setting_type("--scene-unit", SceneFiles, "unit"),
        default=field_default(SceneFiles, "unit"),
        metavar="M",
        help=f"--scenes: {setting_help(SceneFiles, 'unit')}",
    )


def scenes_of(args: argparse.Namespace, argv: Sequence[str] | None):
    """The mesh scenes of ``args.split`` that ``--scenes`` names, every file read and made a scene
    (:func:`odolab.sim.mesh_scenes.scene_files`), or None without ``--scenes`` (where ``argv``, the
    command's arguments, may not name the other scene options); a bad file is one ``UsageError`` line."""
    if args.scenes is None:
        given = given_options(argv, ["--scene-up", "--scene-unit"])
        if given:
            raise UsageError(
                f"{given[0]} is for --scenes (mesh files); without it the episodes run in procedural scenes"
            )
        return None
    if given_options(argv, ["--scene-family"]):
        raise UsageError(f"--scene-family {args.scene_family} is for procedural scenes; --scenes runs mesh files")
    from odolab.sim.mesh_scenes import MeshError, scene_files

    try:
        return scene_files(args.scenes, getattr(args, "split", "test"), args.scene_up, args.scene_unit)
    except MeshError as exc:
        raise UsageError(f"--scenes {exc}") from None


def scene_words(args: argparse.Namespace) -> str:
    """``--scenes`` and its settings, or ``--scene-family`` but the default, as command-line words
    ("" for neither), for a report's command."""
    if args.scenes is None:
        family = getattr(args, "scene_family", "boxes")
        return "" if family == "boxes" else f" --scene-family {family}"
    return f" --scenes {shlex.quote(str(args.scenes))} --scene-up {args.scene_up} --scene-unit {args.scene_unit:.17g}"


def pinhole(name: str = "--intrinsics") -> Callable[[str], tuple[float, float, float, float]]:
    """An argparse ``type`` for a camera's pinhole ``fx,fy,cx,cy`` (pixels): four finite numbers,
    the focal lengths positive; the error names the option and what it got."""

    def parse(text: str) -> tuple[float, float, float, float]:
        parts = [p.strip() for p in text.split(",")]
        try:
            values = [float(p) for p in parts]
        except ValueError:
            values = []
        if len(values) != 4 or not all(math.isfinite(v) for v in values):
            raise argparse.ArgumentTypeError(f"{name} must be four numbers fx,fy,cx,cy (pixels), got {text!r:.80}")
        if min(values[:2]) <= 0:
            raise argparse.ArgumentTypeError(f"{name}: the focal lengths fx, fy must be positive, got {text!r:.80}")
        fx, fy, cx, cy = values
        return fx, fy, cx, cy

    return parse


def given_options(argv: Sequence[str] | None, options: Iterable[str]) -> list[str]:
    """The ``options`` that appear in ``argv`` (``--opt value`` or ``--opt=value``; None: the
    process's own arguments): what the user typed, as opposed to a default equal to it."""
    used = {a.split("=", 1)[0] for a in (sys.argv[1:] if argv is None else argv) if a.startswith("--")}
    return [o for o in options if o in used]


def _describe(exc: OSError) -> str:
    return (exc.strerror or str(exc)).lower()


#: The longest name of one folder or file, in bytes, that common file systems hold (ext4, XFS,
#: btrfs, tmpfs, APFS: 255), and the longest path the system takes (Linux's PATH_MAX, its NUL included).
NAME_MAX = 255
PATH_MAX = 4096


def check_path_length(text: str, option: str) -> None:
    """``argparse.ArgumentTypeError`` naming ``option`` when a name in path ``text`` is longer than
    :data:`NAME_MAX` bytes or the whole path than :data:`PATH_MAX` - 1: no file system could hold it,
    and every use of it would end in "File name too long"."""
    total = len(os.fsencode(text))
    if total >= PATH_MAX:
        raise argparse.ArgumentTypeError(
            f"{option}: expected a path of at most {PATH_MAX - 1} bytes, got one of {total} bytes "
            f"({text[:40]!r}...); choose a shorter path"
        )
    for part in Path(text).parts:
        size = len(os.fsencode(part))
        if size > NAME_MAX:
            raise argparse.ArgumentTypeError(
                f"{option}: expected folder and file names of at most {NAME_MAX} bytes, got one of {size} "
                f"bytes ({part[:40]!r}...); choose a shorter name"
            )


def path_arg(option: str) -> Callable[[str], Path]:
    """An argparse ``type`` for a path: an empty string is refused (it would mean the current
    folder), and so is a name no file system holds (:func:`check_path_length`)."""

    def parse(text: str) -> Path:
        if not text.strip():
            raise argparse.ArgumentTypeError(f"{option} is empty; give a path")
        check_path_length(text, option)
        return Path(text)

    return parse


def file_arg(option: str) -> Callable[[str], Path]:
    """An argparse ``type`` for an output file's path: :func:`path_arg`, and a path ending in a
    slash (a folder's name, which ``Path`` would silently drop) is refused."""

    def parse(text: str) -> Path:
        path = path_arg(option)(text)
        if text.endswith(("/", os.sep)):
            raise argparse.ArgumentTypeError(f"{option} {text}: ends in '/', a folder's name; give a file name")
        return path

    return parse


def execution_of(args: argparse.Namespace) -> Execution:
    """Where a command's fan-out work runs, from its ``--ray-address``, ``--serial`` and ``--quiet``
    (an option the command lacks counts as not given)."""
    return Execution(
        ray_address=getattr(args, "ray_address", None),
        parallel=not getattr(args, "serial", False),
        progress=not getattr(args, "quiet", False),
    )


def check_ray_option(address: str | None, serial: bool = False, *, starts_ray: bool = True) -> None:
    """A command line's ``--ray-address``, checked before any work and before any folder is made:
    :class:`UsageError` with one line when it is malformed or unreachable, or given with ``--serial``
    (no Ray then). Without it, the ``RAY_ADDRESS`` variable, which Ray heeds as it would the option,
    is checked alike (:func:`check_ray_environment`), unless the run starts no Ray (``serial``, or
    ``starts_ray`` False: e.g. a study's ``--redraw``)."""
    from odolab.core.parallel import RayAddressError, check_ray_address

    if address is None:
        if starts_ray and not serial:
            check_ray_environment()
        return
    if serial:
        raise UsageError("--ray-address and --serial exclude each other (--serial runs without Ray); drop one")
    try:
        check_ray_address(address)
    except RayAddressError as exc:
        raise UsageError(exc.named("--ray-address")) from None


def check_ray_environment() -> None:
    """The ``RAY_ADDRESS`` environment variable, where Ray connects when given no ``--ray-address``:
    :class:`UsageError` with one line naming it when it is malformed or nothing answers there (Ray
    would hang or end in a traceback)."""
    from odolab.core.parallel import ENVIRONMENT, RayAddressError, check_environment_ray_address

    try:
        check_environment_ray_address()
    except RayAddressError as exc:
        raise UsageError(f"{exc.named(ENVIRONMENT)}; unset it for a local instance") from None


def check_report_dir(path: Path, option: str, manifest: str = "manifest.txt") -> None:
    """:func:`check_output_dir`, and refuse a folder holding files that no odolab run wrote there
    (no ``manifest`` file): a report must not overwrite a user's own files. A symbolic link
    anywhere inside is refused too (odolab writes and deletes nothing through a link), as are
    pipes and devices: found now, not when the results are written after the whole run. A folder
    inside another run's folder is refused too (:func:`check_not_nested`)."""
    check_not_nested(path, option)
    if path.is_dir() and not (path / manifest).is_file() and any(path.iterdir()):
        if (path / manifest).is_dir():
            raise UsageError(
                f"{option} {path}: its {manifest} is a folder, where odolab keeps a file; remove it or "
                f"choose another {option}"
            )
        owner = folder_owner(path)
        if owner is not None:
            raise UsageError(f"{option} {path}: is {owner}; choose another {option}")
        raise UsageError(
            f"{option} {path}: holds files odolab did not write (no {manifest}); choose a new or empty folder"
        )
    if path.is_dir():  # found now, not when the report is written after the whole run
        for entry in sorted(Path(root) / name for root, dirs, files in os.walk(path) for name in dirs + files):
            if entry.is_symlink() and not entry.exists():
                raise UsageError(f"{option} {path}: {entry.relative_to(path)} is a link to nothing; remove it")
            if entry.is_symlink():
                raise UsageError(
                    f"{option} {path}: {entry.relative_to(path)}: expected a file or folder of an "
                    f"odolab run, found a symbolic link to {os.readlink(entry)} (nothing is written "
                    f"through a link); remove the link or choose another {option}"
                )
            if entry.exists() and not entry.is_file() and not entry.is_dir():
                raise UsageError(
                    f"{option} {path}: {entry.relative_to(path)} is not a regular file "
                    "(a device, pipe or socket); remove it"
                )
    check_output_dir(path, option)


def check_not_nested(path: Path, option: str, own: Path | None = None) -> None:
    """:class:`UsageError` when folder ``path`` lies inside another run's folder (one of its real
    parents, links followed, is a command's: :func:`folder_owner`): that run owns what lies within it.
    ``own`` is the folder of this same run, which may hold it (a training's states in its reports)."""
    mine = os.path.realpath(own) if own is not None else None
    for parent in Path(os.path.realpath(path)).parents:
        if str(parent) == mine:
            continue
        owner = folder_owner(parent) if parent.is_dir() else None
        if owner is not None:
            raise UsageError(f"{option} {path}: lies inside {owner}, {parent}; choose a folder outside it")


#: Folders of commands told apart by their manifest's first line (``# odolab compare``), in words.
_OWNERS = {
    "compare": "a comparison report folder (python -m odolab.compare)",
    "simcard": "a simulator card folder (python -m odolab.simcard)",
}


def folder_owner(path: Path) -> str | None:
    """Which odolab command's folder ``path`` is, in words ("a navigation results folder (python -m
    odolab.navigate)"), told by the file that command keeps there: a ``manifest.txt`` naming its
    owner (compare, simcard, a study), navigation's ``config.json``, a training's ``training.json``
    or the training data's ``dataset.json``; None when it has none of them."""
    from odolab.io.inputs import read_input_json
    from odolab.reporting.report import manifest_owner
    from odolab.sim.training_data import MANIFEST as DATASET

    said = manifest_owner(path)
    if said is not None and said.startswith("study "):
        from odolab.cli.study import STUDIES

        study = said.removeprefix("study ").strip()
        module = STUDIES[study][0] if study in STUDIES else f"studies.{study}"
        return f"the report folder of study {study} (python -m {module})"
    if said is not None:
        return _OWNERS.get(said, f"a folder of odolab {said}")
    for name, keys, words in (
        ("config.json", ("format", "episodes"), "a navigation results folder (python -m odolab.navigate)"),
        (
            "training.json",
            ("command", "stages"),
            "a training's report folder (python -m odolab.learned.robust_vo.train or odolab.learned.deepvo.train)",
        ),
        (DATASET, ("format", "shards"), "a training data folder (python -m odolab.training_data)"),
    ):
        try:
            doc = read_input_json(path / name, name) if (path / name).is_file() else None
        except ValueError:  # unreadable: not recognised
            doc = None
        if isinstance(doc, dict) and all(k in doc for k in keys):
            return words
    return None


def check_no_dotdot_after_link(path: Path, option: str) -> None:
    """:class:`UsageError` when a ``..`` in ``path`` follows a symbolic link: the system takes it to
    the parent of the link's target, not to the folder holding the link, so ``a/link/../z`` would be
    written wherever the link points."""
    parts = Path(path).parts
    for i, part in enumerate(parts):
        if part == ".." and i and Path(*parts[:i]).is_symlink():
            link = Path(*parts[:i])
            raise UsageError(
                f"{option} {path}: expected a path whose '..' steps back from a folder, found '..' after "
                f"the link {link}, which leads to {os.path.realpath(path)}; write the path without '..'"
            )


def check_folder_path(path: Path, option: str) -> None:
    """:class:`UsageError` naming ``option`` for a path that cannot be a folder (a file, a link to
    nothing, a ``..`` after a link: :func:`check_no_dotdot_after_link`), without making anything:
    what a command checks of every output folder before it makes the first."""
    check_no_dotdot_after_link(path, option)
    if path.is_symlink() and not path.exists():
        raise UsageError(
            f"{option} {path}: is a link to nothing (or a loop of links), not a folder; "
            f"remove it or choose another {option}"
        )
    if path.exists() and not path.is_dir():
        raise UsageError(f"{option} {path}: is a file, not a folder")


def check_output_dir(path: Path, option: str) -> None:
    """Create folder ``path`` if needed and prove it writable, or raise :class:`UsageError` naming
    ``option`` (e.g. a path that is a file, or a read-only location, or a ``..`` after a link:
    :func:`check_folder_path`)."""
    check_folder_path(path, option)
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.NamedTemporaryFile(dir=path, prefix=".write-test"):
            pass
    except OSError as exc:
        raise UsageError(f"{option} {path}: not a writable folder ({_describe(exc)})") from None


def check_cache_dir(path: Path, option: str) -> None:
    """:func:`check_output_dir` for a cache a run reads and adds to: a folder that exists but cannot
    be written is accepted (it is read; what it lacks is made and kept in memory, said once by the
    cache), a file, a link to nothing, a ``..`` after a link or a folder that cannot be made is
    refused (:class:`UsageError` naming ``option``)."""
    check_no_dotdot_after_link(path, option)
    if path.is_dir() and os.access(path, os.R_OK | os.X_OK) and not os.access(path, os.W_OK):
        return  # read-only: read, not refused
    check_output_dir(path, option)


def hold_folder(path: Path, option: str) -> FolderLock:
    """Hold folder ``path`` (made by the checks before) for this run, or :class:`UsageError` naming
    ``option`` when another odolab run holds it (:func:`odolab.io.lock.lock_folder`): two runs never
    write one folder at once. Release it (``with``) when the run's writing is done."""
    from odolab.io.lock import FolderInUseError, lock_folder

    try:
        return lock_folder(path)
    except FolderInUseError as exc:
        raise UsageError(exc.named(option)) from None
    except OSError as exc:
        raise UsageError(f"{option} {path}: cannot be opened to hold it for this run ({_describe(exc)})") from None


def check_output_file(path: Path, option: str, suffixes: Iterable[str] | None = None) -> None:
    """Check that file ``path`` can be written (its folder exists and is writable, it is not a
    folder, device, pipe or socket; a symbolic link to a file is written through, a link to nothing
    is refused: writing through it would create its target wherever it points) and, when
    ``suffixes`` is given, that its extension is one of them; else :class:`UsageError` naming
    ``option``. Nothing is left behind."""
    path = Path(path)
    check_no_dotdot_after_link(path, option)
    if path.is_symlink() and not path.exists():  # writing through it would create its target anywhere
        raise UsageError(
            f"{option} {path}: is a link to nothing ({os.readlink(path)} does not exist, or a loop of "
            f"links), not a file; remove it or choose another {option}"
        )
    if path.is_dir():
        raise UsageError(f"{option} {path}: is a folder, not a file")
    if path.exists() and not path.is_file():
        raise UsageError(f"{option} {path}: is not a regular file (a device, pipe or socket)")
    if suffixes is not None:
        allowed = sorted(s.lower().lstrip(".") for s in suffixes)
        use = f"use one of {', '.join('.' + s for s in allowed)}"
        targets = [(path, "")]
        if path.is_symlink():  # through a link its target is what would be replaced
            target = Path(os.path.realpath(path))
            targets.append((target, f"links to {target}, "))
        for named, shown in targets:
            if not named.suffix:  # ".json" alone is a hidden file's name with no extension
                raise UsageError(
                    f"{option} {path}: {shown}{named.name!r} has no file extension; {use} "
                    f"after a name (e.g. out.{allowed[0]})"
                )
            if named.suffix.lower().lstrip(".") not in allowed:
                raise UsageError(f"{option} {path}: {shown}unknown file type {named.suffix!r}; {use}")
    folder = path.parent if str(path.parent) else Path(".")
    if folder.exists() and not folder.is_dir():
        raise UsageError(f"{option} {path}: {folder} is a file, not a folder")
    if not folder.is_dir():
        raise UsageError(f"{option} {path}: folder {folder} does not exist")
    try:
        with tempfile.NamedTemporaryFile(dir=folder, prefix=".write-test"):
            pass
    except OSError as exc:
        raise UsageError(f"{option} {path}: cannot write in {folder} ({_describe(exc)})") from None


def check_replaceable(path: Path, option: str, ours: Callable[[Path], bool], what: str) -> None:
    """:class:`UsageError` when file ``path`` exists (links followed) and ``ours(path)`` says it is
    not ``what`` (in words: "a bench JSON file"): a command replaces only a file of its own kind,
    never a model, a recipe or another command's output given by mistake."""
    path = Path(path)
    if not path.is_file():
        return
    try:
        mine = ours(path)
    except (OSError, ValueError, UnicodeDecodeError):
        mine = False
    if not mine:
        raise UsageError(
            f"{option} {path}: expected a new file or {what} to replace, found a file of another kind; "
            f"choose another {option}"
        )


#: Longest error message printed whole; a 20,000-character name a user pasted is not echoed back.
MAX_ERROR_CHARS = 400


def _capped(text: str) -> str:
    """``text`` on one line, cut to :data:`MAX_ERROR_CHARS` with the number of characters left out."""
    text = " ".join(text.splitlines())
    if len(text) <= MAX_ERROR_CHARS:
        return text
    return f"{text[:MAX_ERROR_CHARS]}... ({len(text) - MAX_ERROR_CHARS} more characters)"


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread (:func:`run_cli`) so that ``with`` blocks and ``finally``
    clauses run: temporary folders are removed, a partial file is not left behind."""


#: What a file system refuses a write for, whatever the command (errno -> what to do about it).
DISK_ERRORS = {
    errno.ENOSPC: "nothing half-written was left; free some space and run again",
    errno.EDQUOT: "nothing half-written was left; free some space or raise the quota and run again",
    errno.EFBIG: "this file system takes no file this large; write elsewhere",
    errno.EROFS: "choose a folder on a writable file system",
    errno.ENAMETOOLONG: "choose a shorter name",
}


def disk_error(exc: OSError) -> str | None:
    """One line for an ``OSError`` that a file system gave a write (:data:`DISK_ERRORS`: a full disk,
    a quota, a read-only file system, a name too long), naming the file when the error does
    (atomic writes name the file they were writing; nothing half-written is left); None for others."""
    if exc.errno not in DISK_ERRORS:
        return None
    what = (exc.strerror or str(exc)).lower()
    where = f"{exc.filename}: " if exc.filename is not None else ""
    return f"{where}{what}; {DISK_ERRORS[exc.errno]}"


def run_cli(main: Callable[[Sequence[str] | None], int | None], prog: str, argv: Sequence[str] | None = None) -> int:
    """Run ``main(argv)``; turn :class:`UsageError` and file errors into ``prog: error: ...`` + exit 2.
    Ctrl-C exits 130 and SIGTERM 143 (the shell's codes), each after the command's clean-up, also
    when a library swallowed the signal's exception and the command went on to its end."""
    in_main = threading.current_thread() is threading.main_thread()
    # the signals received: Ray re-raises the handler's exception as a bare Ctrl-C, and a library
    # may swallow it (Open3D's import does), so the exit code is taken from this list
    received: list[int] = []

    def on_signal(signum: int, frame: object) -> None:
        received.append(signum)
        raise Terminated() if signum == signal.SIGTERM else KeyboardInterrupt()

    def stopped() -> int:
        if signal.SIGTERM in received:
            print(f"{prog}: terminated", file=sys.stderr)
            return 143
        print(f"{prog}: interrupted", file=sys.stderr)
        return 130

    watched = (signal.SIGINT, signal.SIGTERM)
    previous = {s: signal.signal(s, on_signal) for s in watched} if in_main else {}
    from odolab.core.errors import InputError
    from odolab.core.memory import keep_freed_memory

    keep_freed_memory()  # freed blocks reused, not faulted in again (odolab.core.memory)

    try:
        code = int(main(argv) or 0)
    except (
        UsageError,
        InputError,  # a value found unusable only once work began: a Ray address, a scene with no episode
        FileNotFoundError,
        PermissionError,
        IsADirectoryError,
        NotADirectoryError,
    ) as exc:
        print(f"{prog}: error: {_capped(str(exc))}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return stopped()
    except BrokenPipeError:  # the reader of stdout went away (``... | head -1``): no traceback
        quiet_broken_pipe()
        return 141  # what a shell reports for a command ended by SIGPIPE
    except OSError as exc:
        said = disk_error(exc)
        if said is None:
            if received:
                return stopped()
            raise
        print(f"{prog}: error: {_capped(said)}", file=sys.stderr)
        return 2
    except Exception:
        if received:  # a swallowed signal that surfaced as another error
            return stopped()
        raise
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    return stopped() if received else code


def exit_process(code: int) -> NoReturn:
    """Leave the process with ``code``, as a command's entry point does. After Ctrl-C or SIGTERM
    (130, 143) at once: the command's clean-up ran as the signal's exception unwound it, and a
    thread the interruption left busy or holding a lock (the depth worker, Open3D's, Ray's) would
    otherwise hang the interpreter's exit or abort it in a C++ destructor. So too when an odometer
    call that ran past its time limit is still running (:func:`odolab.running.runner.calls_still_running`).
    Otherwise, where no thread but daemons is left, after the exit handlers (``atexit``) and with
    the output flushed, without the interpreter's teardown of every module (about a second of CPU
    once torch, Open3D and Ray are loaded, and nothing a finished command needs); with a
    thread still running, as Python exits, waiting for it."""
    runner = sys.modules.get("odolab.running.runner")  # never imported: no odometer call made
    if code in (130, 143) or (runner is not None and runner.calls_still_running()):
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        os._exit(code)
    if all(t.daemon or t is threading.main_thread() for t in threading.enumerate()):
        import atexit

        atexit._run_exitfuncs()  # what Python runs at exit before its teardown (Ray's shutdown, logging's flush)
        try:
            for stream in (sys.stdout, sys.stderr):
                if stream is not None:  # None: started with that stream closed
                    stream.flush()
        except (OSError, ValueError):  # a closed pipe or stream: Python's own exit reports it
            sys.exit(code)
        os._exit(code)
    sys.exit(code)


def quiet_broken_pipe() -> None:
    """Point stdout at /dev/null, so that Python's flush at exit does not report the broken pipe
    again (the recipe of Python's documentation on SIGPIPE)."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):
        pass  # stdout is not a file (a test's capture): nothing is flushed to a pipe at exit
