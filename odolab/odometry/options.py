"""Per-odometer options (a checkpoint path, a device, a parameter), passed to the constructor.

From the command line, ``NAME.key=value`` (``NAME`` as given to ``--odometers``, which may itself
contain dots and a colon: the key is what follows the *last* dot before ``=``). The value is read
as a TOML value when it is one (``3``, ``0.5``, ``true``, ``"text"``, ``[1, 2]``) and as plain text
otherwise (``runs/tiny.pt``). From a TOML file (read with :mod:`tomllib`, never evaluated)::

    [odometers."examples.tiny_learned:TinyLearnedOdometer"]
    checkpoint = "runs/tiny.pt"

Command-line options override the file's. Every problem raises :class:`OptionError` with one line
naming the option and what was expected.
"""

from __future__ import annotations

import difflib
import inspect
import numbers
import os
from collections.abc import Callable, Iterable, Mapping
from typing import Any

import numpy as np

from odolab.config import ConfigError, toml_value
from odolab.io.tomlfile import read_toml

__all__ = [
    "OptionError",
    "check_options",
    "merge_options",
    "naming_the_file",
    "parse_assignments",
    "read_options_file",
    "whole_number",
    "without_defaults",
]

Options = dict[str, dict[str, Any]]


class OptionError(ValueError):
    """A per-odometer option that cannot be used; the message is one line naming it."""


def parse_assignments(assignments: Iterable[str]) -> Options:
    """``["NAME.key=value", ...]`` -> ``{NAME: {key: value}}`` (see the module docstring)."""
    out: Options = {}
    for text in assignments:
        target, eq, value = text.partition("=")
        name, dot, key = target.strip().rpartition(".")
        if not eq or not dot or not name or not key.isidentifier():
            raise OptionError(f"--odometer-option {text!r}: expected NAME.key=value, e.g. icp.max_depth=4.0")
        if key in out.get(name, {}):  # the last would win silently: which one was meant is unknown
            raise OptionError(f"--odometer-option {target.strip()} is given twice")
        try:
            out.setdefault(name, {})[key] = toml_value(value.strip())
        except ConfigError as exc:
            raise OptionError(f"--odometer-option {target.strip()}: {exc}") from None
    return out


def read_options_file(path: str | os.PathLike) -> Options:
    """The ``[odometers.NAME]`` tables of a TOML file (other top-level keys are an error)."""
    try:
        doc = read_toml(path, "options file")
    except ValueError as exc:
        raise OptionError(str(exc)) from None
    extra = sorted(set(doc) - {"odometers"})
    if extra:
        raise OptionError(f"{path}: unknown top-level key {extra[0]!r}; expected only [odometers.NAME] tables")
    tables = doc.get("odometers", {})
    if not isinstance(tables, dict):
        raise OptionError(f"{path}: odometers must be a table ([odometers.NAME] sections), got {tables!r}")
    for name, table in tables.items():
        if not isinstance(table, dict):
            raise OptionError(f"{path}: odometers.{name} must be a table of options, got {table!r}")
    return {name: dict(table) for name, table in tables.items()}


def merge_options(*layers: Mapping[str, Mapping[str, Any]]) -> Options:
    """Later layers override earlier ones, key by key."""
    out: Options = {}
    for layer in layers:
        for name, table in layer.items():
            out.setdefault(name, {}).update(table)
    return out


def check_options(name: str, factory: Callable[..., Any], options: Mapping[str, Any]) -> None:
    """Refuse keys ``factory``'s signature does not accept (unless it takes ``**kwargs``)."""
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):  # a builtin without a signature: let the call decide
        return
    if any(p.kind is inspect.Parameter.VAR_KEYWORD for p in params.values()):
        return
    accepted = [
        p
        for p, v in params.items()
        if v.kind in (inspect.Parameter.POSITIONAL_OR_KEYWORD, inspect.Parameter.KEYWORD_ONLY)
    ]
    for key, value in options.items():
        if key not in accepted:
            near = difflib.get_close_matches(str(key), accepted, n=2)
            hint = f" (did you mean {' or '.join(map(repr, near))}?)" if near else ""
            raise OptionError(
                f"odometer {name!r} has no option {key!r}{hint}; it accepts: {', '.join(accepted) or 'no options'}"
            )
        parts = _simple_parts(params[key].annotation)
        if parts and not any(_fits(value, p) for p in parts):
            want = " or ".join(_SIMPLE[p][1] for p in parts)
            raise OptionError(f"odometer {name!r} option {key}: expected {want}, got {value!r}")


def naming_the_file(message: str, config: str | os.PathLike | None, cli: bool) -> str:
    """An odometer-loading error ``message`` led by where its options came from when a file was read
    (``config``; ``cli``: whether ``--odometer-option`` gave some too), so that cutting a long message
    short cannot drop the file's name."""
    if config is None or "option" not in message:
        return message
    return f"options from --config {config}{' and --odometer-option' if cli else ''}: {message}"


def whole_number(name: str, value: Any, lo: int, hi: int) -> int:
    """``value`` as an int in [lo, hi] (numpy integers too); ``ValueError`` naming ``name``, the range
    and the value for anything else: a bool, 2.5, nan, "3"."""
    if isinstance(value, numbers.Integral) and not isinstance(value, (bool, np.bool_)) and lo <= int(value) <= hi:
        return int(value)
    raise ValueError(f"{name} must be an integer in [{lo}, {hi}], got {value!r}")


def without_defaults(factory: Callable[..., Any], options: Mapping[str, Any]) -> dict[str, Any]:
    """``options`` less those that equal ``factory``'s own default (``relock_views=5`` where 5 is the
    default; ``1`` and ``1.0`` are equal, ``true`` and ``1`` are not): what a folder of results records,
    so that naming a default is not a change of settings."""
    try:
        params = inspect.signature(factory).parameters
    except (TypeError, ValueError):
        return dict(options)

    def is_default(key: str, value: Any) -> bool:
        p = params.get(key)
        if p is None or p.default is inspect.Parameter.empty or isinstance(p.default, bool) != isinstance(value, bool):
            return False
        try:
            return bool(p.default == value)
        except Exception:  # noqa: BLE001 - an array's ambiguous truth value: not a default
            return False

    return {k: v for k, v in options.items() if not is_default(k, v)}


#: Annotation -> (accepted Python types, words for the error). bool is never a number here.
_SIMPLE = {
    "float": ((numbers.Real,), "a number"),
    "int": ((numbers.Integral,), "an integer"),
    "str": ((str,), "text"),
    "bool": ((bool, np.bool_), "true or false"),
}


def _fits(value: Any, part: str) -> bool:
    """numpy's scalars count as the numbers they are (``np.float32(0.5)``, ``np.int64(3)``)."""
    return isinstance(value, _SIMPLE[part][0]) and (part == "bool" or not isinstance(value, (bool, np.bool_)))


def _simple_parts(annotation: Any) -> list[str]:
    """The simple types (``float``, ``int``, ``str``, ``bool``) an annotation allows, ``| None``
    ignored; empty for anything else (the constructor then checks its own arguments)."""
    if isinstance(annotation, type):
        annotation = annotation.__name__
    if not isinstance(annotation, str):
        return []
    parts = [p.strip() for p in annotation.split("|") if p.strip() != "None"]
    return parts if parts and all(p in _SIMPLE for p in parts) else []
