"""The one way to configure: frozen dataclasses whose fields carry their valid range and a one-line
description, built from TOML (read with :mod:`tomllib`, never evaluated) plus ``key=value`` changes,
checked by one function and printed from the same source.

A field declares itself with :func:`setting`::

    @dataclass(frozen=True)
    class Example:
        cell: float = setting(0.05, range=(0.02, 1.0), doc="map cell edge, m")
        stride: int = setting(4, range=(1, 64), doc="every n-th depth pixel")

        def __post_init__(self) -> None:
            check(self)  # every field with a range: a number of its kind, inside it

- :func:`check` refuses a value that is not a number of the field's kind (an ``int`` field wants a
  whole number; a bool, text or NaN is no number) or lies outside its range, with one line:
  ``cell must be a number in [0.02, 1], got 'x'`` or ``cell must be in [0.02, 1], got 5.0``; numpy
  scalars become Python's, ``-0.0`` becomes ``0.0``. A field annotated with ``Literal[...]`` takes
  its choices (``precision: Literal["fp32", "bf16"]``: ``precision must be one of 'fp32', 'bf16',
  got 'fp16'``); with a range too, a choice or a number (``workers: int | Literal["auto"]``:
  ``workers must be 'auto' or in [0, 64], got -1``).
- :func:`build` (:func:`from_toml` for a file, whose top-level ``base = "other.toml"`` starts from
  another document) builds a config from a dict, checking names and types; :class:`ConfigError`
  names the file and the field.
- :func:`assign` applies ``key=value`` changes (``heading_tolerance=30``) to a config.
- :func:`describe` lists every field with its value, range (or choices) and description (what
  reports and ``--help`` print).

The field metadata does not enter ``dataclasses.asdict``, equality or pickling: a config's
contents, and every digest or identity made from them, do not depend on it.
"""

from __future__ import annotations

import copy
import dataclasses
import functools
import math
import numbers
import os
import re
import reprlib
import types
import typing
from collections.abc import Iterable
from typing import Any, TypeVar

import numpy as np
import tomllib

from odolab.core.errors import InputError
from odolab.io.tomlfile import read_toml as read_toml_document

__all__ = [
    "SEED_RANGE",
    "ChangeError",
    "ConfigError",
    "Setting",
    "assign",
    "build",
    "change_document",
    "check",
    "choices",
    "describe",
    "from_toml",
    "in_range",
    "number_kind",
    "range_text",
    "read_toml",
    "setting",
    "toml_value",
    "valid_text",
]

T = TypeVar("T")

#: Longest chain of ``base =`` files one TOML document may start from.
MAX_BASE_CHAIN = 16
#: Deepest nesting of tables that two documents of a ``base =`` chain are merged through.
MAX_TABLE_DEPTH = 32
#: Longest ``key=value`` value read as a number: no setting needs 40 digits (Python refuses 4300).
MAX_NUMBER_CHARS = 40

#: The range of every seed setting: seeds feed numpy's SeedSequence; 2^32 - 1 keeps them portable.
SEED_RANGE = (0, 2**32 - 1)

_RANGE, _OPEN, _DOC, _LIST = "odolab.range", "odolab.open", "odolab.doc", "odolab.list"


class ConfigError(ValueError):
    """A config that cannot be used; the message names the file and field."""


class ChangeError(ConfigError):
    """A ``path=value`` change (:func:`change_document`) that cannot be applied; the message starts
    with the item."""


# ---------------------------------------------------------------------------------------- fields


def setting(
    default: Any = dataclasses.MISSING,
    *,
    range: tuple[float, float] | None = None,
    doc: str = "",
    open_low: bool = False,
    open_high: bool = False,
    default_factory: Any = dataclasses.MISSING,
    min_items: int = 0,
    distinct: bool = False,
) -> Any:
    """A dataclass field with its valid range ``(low, high)`` (closed, unless ``open_low`` /
    ``open_high``; None: no range) and a one-line description ``doc``. For a list field
    (``tuple[int, ...]``) the range holds for each item, and ``min_items`` and ``distinct`` (no
    value twice) for the list."""
    metadata: dict[str, Any] = {_DOC: doc}
    if range is not None:
        low, high = range
        metadata[_RANGE] = (low, high)
        metadata[_OPEN] = (bool(open_low), bool(open_high))
    if min_items or distinct:
        metadata[_LIST] = (int(min_items), bool(distinct))
    return dataclasses.field(default=default, default_factory=default_factory, metadata=metadata)


def _field(cls_or_config: Any, name: str) -> dataclasses.Field:
    for f in dataclasses.fields(cls_or_config):
        if f.name == name:
            return f
    raise KeyError(name)


def _type_parts(f: dataclasses.Field) -> list[str]:
    """``"int | None"`` -> ``["int", "None"]`` (the annotation as written, or its type's name)."""
    kind = f.type if isinstance(f.type, str) else getattr(f.type, "__name__", str(f.type))
    return [p.strip() for p in str(kind).split("|")]


def _item_type(f: dataclasses.Field) -> str | None:
    """``"int, ..."`` for a field annotated ``tuple[int, ...]`` (a list field); None for any other."""
    if not isinstance(f.type, str) and typing.get_origin(f.type) in (tuple, list):
        return ", ".join(getattr(a, "__name__", str(a)) for a in typing.get_args(f.type))
    first = _type_parts(f)[0]
    return first[first.index("[") + 1 : -1] if first.startswith(("tuple[", "list[")) else None


def _whole(f: dataclasses.Field) -> bool:
    parts = _type_parts(f) if _item_type(f) is None else [p.strip() for p in _item_type(f).split(",")]
    return "int" in parts and "float" not in parts


def _show(bound: float) -> str:
    """A range's end as a user may type it: ``64``, ``1000000``, ``0.001``."""
    if isinstance(bound, int) or (math.isfinite(bound) and bound.is_integer() and abs(bound) < 1e15):
        return f"{int(bound):d}"
    return f"{bound:g}"


def _quoted(value: Any) -> str:
    """``value`` as an error line quotes it: at most 80 characters, a huge integer by its size
    (Python prints none of over 4300 digits)."""
    if isinstance(value, numbers.Integral) and not isinstance(value, bool) and abs(int(value)).bit_length() > 256:
        return f"an integer of about {int(abs(int(value)).bit_length() * math.log10(2)) + 1} digits"
    return f"{value!r:.80}"


def range_text(cls_or_config: Any, name: str) -> str:
    """``[1, 1000000]``, ``(0, 1]``: the range of field ``name`` as a user may type its ends."""
    f = _field(cls_or_config, name)
    (low, high), (open_low, open_high) = f.metadata[_RANGE], f.metadata[_OPEN]
    return f"{'(' if open_low else '['}{_show(low)}, {_show(high)}{')' if open_high else ']'}"


def number_kind(cls_or_config: Any, name: str) -> type:
    """``int`` for a field (or a list field's items) of whole numbers, else ``float``."""
    return int if _whole(_field(cls_or_config, name)) else float


def in_range(cls_or_config: Any, name: str, value: float) -> bool:
    """Whether number ``value`` lies in field ``name``'s range (NaN never does)."""
    f = _field(cls_or_config, name)
    (low, high), (open_low, open_high) = f.metadata[_RANGE], f.metadata[_OPEN]
    return low <= value <= high and not (open_low and value == low) and not (open_high and value == high)


def _noun(f: dataclasses.Field) -> str:
    return "a whole number" if _whole(f) else "a number"


@functools.cache
def _choices_of(cls: type) -> dict[str, tuple[Any, ...]]:
    """Field name -> the values its ``Literal[...]`` annotation allows (in a union too); fields
    without one are left out, as are all of a class whose annotations do not resolve at run time."""
    try:
        hints = typing.get_type_hints(cls)
    except (NameError, TypeError):
        return {}
    out: dict[str, tuple[Any, ...]] = {}
    for f in dataclasses.fields(cls):
        annotation = hints.get(f.name)
        options = [annotation] if typing.get_origin(annotation) is typing.Literal else []
        if typing.get_origin(annotation) in (typing.Union, types.UnionType):
            options = [a for a in typing.get_args(annotation) if typing.get_origin(a) is typing.Literal]
        values = tuple(v for option in options for v in typing.get_args(option))
        if values:
            out[f.name] = values
    return out


def choices(cls_or_config: Any, name: str) -> tuple[Any, ...]:
    """The values field ``name``'s ``Literal[...]`` annotation allows; ``()`` for a field without one."""
    return _choices_of(cls_or_config if isinstance(cls_or_config, type) else type(cls_or_config)).get(name, ())


def _is_choice(value: Any, options: tuple[Any, ...]) -> bool:
    """Whether ``value`` is one of ``options``, of its kind too (``True`` is no ``1``, ``1.0`` no ``1``)."""
    return any(
        (type(value) is type(c) or isinstance(value, str) and isinstance(c, str)) and value == c for c in options
    )


def _choices_text(options: tuple[Any, ...]) -> str:
    """``'auto'`` or ``one of 'fp32', 'bf16'``."""
    return repr(options[0]) if len(options) == 1 else f"one of {', '.join(map(repr, options))}"


def valid_text(cls_or_config: Any, name: str) -> str:
    """What field ``name`` takes as a user may type it: ``[1, 64]``, ``one of 'fp32', 'bf16'``,
    ``'auto' or [0, 64]``; ``""`` for a field with neither range nor choices."""
    f = _field(cls_or_config, name)
    parts = [_choices_text(c)] if (c := choices(cls_or_config, name)) else []
    if _RANGE in f.metadata:
        parts.append(range_text(cls_or_config, name))
    return " or ".join(parts)


def check(config: Any, prefix: str = "") -> None:
    """``ValueError`` (led by ``prefix``, e.g. ``"stage 'f': "``) for the first field of ``config``
    with a range whose value is not a number of its kind or lies outside it, or with ``Literal[...]``
    choices whose value is none of them (nor, with a range too, such a number); each number is
    stored as a Python ``int`` or ``float``; a list field's items are checked one by one
    (``seeds[1] must be ...``), and its length and repeats as its setting says. Call it from
    ``__post_init__``."""
    for f in dataclasses.fields(config):
        if _item_type(f) is not None:
            _check_items(config, f, prefix)
            continue
        options = choices(config, f.name)
        if _RANGE not in f.metadata and not options:
            continue
        value = getattr(config, f.name)
        if value is None and "None" in _type_parts(f) or options and _is_choice(value, options):
            continue
        if _RANGE not in f.metadata:
            raise ValueError(f"{prefix}{f.name} must be {_choices_text(options)}, got {_quoted(value)}")
        either = f"{_choices_text(options)} or " if options else ""  # 'auto' or in [0, 64]
        whole = _whole(f)
        if (
            isinstance(value, (bool, np.bool_))
            or not isinstance(value, numbers.Integral if whole else numbers.Real)
            or (not isinstance(value, numbers.Integral) and math.isnan(value))
        ):
            raise ValueError(
                f"{prefix}{f.name} must be {either}{_noun(f)} in {range_text(config, f.name)}, got {_quoted(value)}"
            )
        given = value  # quoted as the caller wrote it (numpy's scalars as Python's)
        try:
            value = int(value) if whole else float(value) + 0.0  # numpy's scalars as Python's; -0.0 as 0.0
        except OverflowError:  # an integer past float's range: out of every range
            raise ValueError(
                f"{prefix}{f.name} must be {either}in {range_text(config, f.name)}, got {_quoted(value)}"
            ) from None
        object.__setattr__(config, f.name, value)
        if not in_range(config, f.name, value):
            raise ValueError(
                f"{prefix}{f.name} must be {either}in {range_text(config, f.name)}, got {_quoted(given if type(given) in (int, float) else value)}"
            )


def _check_items(config: Any, f: dataclasses.Field, prefix: str) -> None:
    """:func:`check` for a list field: its length, its repeats and each item's range."""
    value = getattr(config, f.name)
    if value is None and "None" in _type_parts(f):
        return
    if not isinstance(value, (tuple, list)):
        raise ValueError(f"{prefix}{f.name} must be a list, got {value!r:.80}")
    min_items, distinct = f.metadata.get(_LIST, (0, False))
    if len(value) < min_items:
        raise ValueError(
            f"{prefix}{f.name} must hold at least {min_items} item{'s' * (min_items > 1)}, got {list(value)!r:.80}"
        )
    if distinct and len(set(value)) != len(value):
        raise ValueError(f"{prefix}{f.name} must hold no value twice, got {list(value)!r:.80}")
    if _RANGE not in f.metadata:
        return
    whole = _whole(f)
    for k, item in enumerate(value):
        if (
            isinstance(item, (bool, np.bool_))
            or not isinstance(item, numbers.Integral if whole else numbers.Real)
            or not in_range(config, f.name, item)
        ):
            raise ValueError(
                f"{prefix}{f.name}[{k}] must be {_noun(f)} in {range_text(config, f.name)}, got {_quoted(item)}"
            )


@dataclasses.dataclass(frozen=True)
class Setting:
    """One field of a config as :func:`describe` lists it: ``range`` is what it takes
    (:func:`valid_text`: ``[1, 64]``, ``one of 'fp32', 'bf16'``, ``'auto' or [0, 64]``), ``""`` for a
    field with neither range nor choices."""

    name: str
    value: Any
    range: str
    doc: str


def describe(config: Any) -> list[Setting]:
    """Every field of ``config`` (a dataclass or its class, which gives the defaults), in order,
    with its value, range (or choices) and description: what ``--help`` and reports print."""
    out = []
    for f in dataclasses.fields(config):
        if isinstance(config, type):
            if f.default is not dataclasses.MISSING:
                value = f.default
            elif f.default_factory is not dataclasses.MISSING:
                value = f.default_factory()
            else:
                value = None
        else:
            value = getattr(config, f.name)
        out.append(Setting(f.name, value, valid_text(config, f.name), f.metadata.get(_DOC, "")))
    return out


# ---------------------------------------------------------------------------------- TOML -> config


def read_toml(path: str | os.PathLike, _seen: tuple[str, ...] = ()) -> dict[str, Any]:
    """The TOML document at ``path``; :class:`ConfigError` when missing or malformed.

    A top-level ``base = "other.toml"`` (relative to this file) starts from that document: tables
    are merged key by key, anything else (numbers, strings, lists such as ``[[stages]]``) replaces
    the base's value. So a variant of a recipe states only what it changes. Beside ``base``, a
    top-level ``changes = ["path=value", ...]`` is applied to the merged document in order, as
    ``--set`` would (:func:`change_document`: ``stages.forward.epochs=3`` changes one entry of an
    array of tables without restating the array). A chain of more than :data:`MAX_BASE_CHAIN`
    bases is refused.
    """
    if len(_seen) >= MAX_BASE_CHAIN:
        raise ConfigError(
            f"{path}: reached through a chain of {len(_seen)} base files (from {_seen[0]}); at most {MAX_BASE_CHAIN}"
        )
    doc = _read_toml_file(path)
    base = doc.pop("base", None)
    if base is None:
        return doc
    if not isinstance(base, str) or not base:
        raise ConfigError(f"{path}: base must be the path of another TOML file, got {base!r}")
    base_path = _base_path(path, base)
    if os.path.abspath(base_path) in _seen or os.path.abspath(path) == os.path.abspath(base_path):
        raise ConfigError(f"{path}: base {base!r} leads back to itself")
    if not os.path.isfile(base_path):
        raise ConfigError(f"{path}: its base {base!r} is not a file ({base_path})")
    changes = doc.pop("changes", [])
    if not isinstance(changes, list) or not all(isinstance(c, str) for c in changes):
        raise ConfigError(f'{path}: changes: expected a list of "path=value" strings, got {changes!r}')
    merged = read_toml(base_path, (*_seen, os.path.abspath(path)))
    try:
        return change_document(_merge(merged, doc), changes)
    except ChangeError as exc:
        raise ConfigError(f"{path}: changes: {exc}") from None
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


def _base_path(path: str | os.PathLike, base: str) -> str:
    """Where ``base = "..."`` in file ``path`` points: beside the file itself, not beside a link to it."""
    return os.path.join(os.path.dirname(os.path.realpath(path)), base)


def _merge(base: dict[str, Any], over: dict[str, Any], where: str = "", depth: int = 0) -> dict[str, Any]:
    """``over`` merged into ``base`` table by table; :class:`ConfigError` past :data:`MAX_TABLE_DEPTH` levels."""
    if depth > MAX_TABLE_DEPTH:
        raise ConfigError(f"{where}: tables nested more than {MAX_TABLE_DEPTH} deep")
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = _merge(out[key], value, f"{where}.{key}" if where else key, depth + 1)
        else:
            out[key] = value
    return out


def _read_toml_file(path: str | os.PathLike) -> dict[str, Any]:
    try:
        return read_toml_document(path, "config file")
    except ValueError as exc:
        raise ConfigError(str(exc)) from None


def _check(value: Any, annotation: Any, where: str) -> Any:
    origin = typing.get_origin(annotation)
    if annotation is Any:
        return value
    if origin in (typing.Union, types.UnionType):
        options = [o for o in typing.get_args(annotation) if o is not type(None)]
        if value is None and len(options) < len(typing.get_args(annotation)):
            return None
        if len(options) == 1:  # X | None: X's own message says what is wrong
            return _check(value, options[0], where)
        for option in options:
            try:
                return _check(value, option, where)
            except ConfigError:
                continue
        raise ConfigError(f"{where}: expected {annotation}, got {value!r}")
    if origin is typing.Literal:
        if value not in typing.get_args(annotation):
            raise ConfigError(
                f"{where}: expected one of {', '.join(map(repr, typing.get_args(annotation)))}, got {value!r}"
            )
        return value
    if origin in (tuple, list):
        if not isinstance(value, (list, tuple)):
            raise ConfigError(f"{where}: expected a list, got {value!r}")
        args = typing.get_args(annotation)
        item = args[0] if args else Any
        return tuple(_check(v, item, f"{where}[{k}]") for k, v in enumerate(value))
    if dataclasses.is_dataclass(annotation):
        if not isinstance(value, dict):
            raise ConfigError(f"{where}: expected a table, got {value!r}")
        return build(annotation, value, where)
    if annotation is float:
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            raise ConfigError(f"{where}: expected a number, got {value!r}")
        return float(value)
    if annotation is int:
        if isinstance(value, bool) or not isinstance(value, int):
            raise ConfigError(f"{where}: expected an integer, got {value!r}")
        return value
    if annotation in (bool, str) and not isinstance(value, annotation):
        raise ConfigError(f"{where}: expected {annotation.__name__}, got {value!r}")
    return value


def build(cls: type[T], doc: dict[str, Any], where: str) -> T:
    """Build dataclass ``cls`` from ``doc``, checking names and types; ``where`` prefixes errors."""
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise ConfigError(
            f"{where}: unknown field(s) {', '.join(unknown)}; expected some of {', '.join(sorted(known))}"
        )
    required = {
        f.name
        for f in dataclasses.fields(cls)
        if f.init and f.default is dataclasses.MISSING and f.default_factory is dataclasses.MISSING
    }
    missing = sorted(required - set(doc))
    if missing:
        raise ConfigError(f"{where}: missing field(s) {', '.join(missing)}")
    values = {k: _check(v, hints[k], _at(where, k)) for k, v in doc.items()}
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


_FIELD_PATH = re.compile(r"[A-Za-z_]\w*(\[\d+\])*(\.[A-Za-z_]\w*(\[\d+\])*)*")


def _at(where: str, name: str) -> str:
    """``where`` followed by field ``name``: ``file: a.b.name`` below a field path (``file: a.b``),
    else ``where: name`` (a file's top, or any other place such as ``file: row 3's recipe``)."""
    if not where:
        return name
    _, sep, tail = where.rpartition(": ")
    return f"{where}.{name}" if sep and _FIELD_PATH.fullmatch(tail) else f"{where}: {name}"


def from_toml(cls: type[T], path: str | os.PathLike, changes: Iterable[str] = ()) -> T:
    """Read ``path``, apply ``changes`` (:func:`change_document`: ``model.width=341``) and build
    ``cls`` from it (see :func:`build`). A value refused only because of a change raises
    :class:`ChangeError` naming that change (``'seed=abc': seed: expected an integer, got 'abc'``);
    one refused in the file's ``base =`` chain names the file that brought it in."""
    changes = list(changes)
    doc = read_toml(path)
    changed = change_document(doc, changes)  # a malformed change: ChangeError naming it
    try:
        return build(cls, changed, str(path))
    except ConfigError as exc:
        said = _said(exc, path)
        if not _builds(cls, doc, path):  # the file itself is refused: name the file that brought the value in
            source = _source(cls, path, said)
            if source == str(path):
                raise exc from None
            raise ConfigError(f"{source}: {said} (a base of {path})") from None
        raise ChangeError(f"{_SHORT.repr(_culprit(cls, doc, changes, said, path))}: {said}") from None


def _said(exc: ConfigError, path: str | os.PathLike) -> str:
    """The message of ``exc`` without the file ``path`` it starts with."""
    return str(exc).removeprefix(f"{path}.").removeprefix(f"{path}: ")


def _builds(cls: type, doc: dict[str, Any], path: str | os.PathLike) -> bool:
    """Whether ``cls`` can be built from ``doc``."""
    try:
        build(cls, doc, str(path))
    except ConfigError:
        return False
    return True


def _culprit(cls: type, doc: dict[str, Any], changes: list[str], said: str, path: str | os.PathLike) -> str:
    """The change of ``changes`` that the refusal ``said`` is about: the only one without which the
    document builds; else the last whose path the message names (:func:`_blamed`); else them all."""
    alone = []
    for k, item in enumerate(changes):
        try:
            if _builds(cls, change_document(doc, changes[:k] + changes[k + 1 :]), path):
                alone.append(item)
        except ChangeError:
            continue
    if len(alone) == 1:
        return alone[0]
    return _blamed(said, changes, change_document(doc, changes)) or "; ".join(changes)


def _source(cls: type, path: str | os.PathLike, said: str) -> str:
    """The file of ``path``'s ``base =`` chain that brought in the value the refusal ``said`` is
    about: the deepest base that is refused with the same words on its own; ``path`` when none is."""
    chain, current = [str(path)], str(path)
    while len(chain) <= MAX_BASE_CHAIN:
        try:
            base = _read_toml_file(current).get("base")
        except ConfigError:
            break
        if not isinstance(base, str) or not base:
            break
        current = _base_path(current, base)
        chain.append(current)
    for file in reversed(chain[1:]):
        try:
            build(cls, read_toml(file), file)
        except ConfigError as exc:
            if _said(exc, file) == said:
                return file
    return str(path)


def _blamed(said: str, changes: list[str], doc: dict[str, Any]) -> str | None:
    """The last of ``changes`` whose path the message ``said`` (``field.path: ...``, a list entry
    as ``stages[0]``) is about; a change that enters a list by an entry's name (``stages.forward``)
    is matched by that entry's position in ``doc``, the changed document."""
    field = said.partition(":")[0].strip().replace("[", ".").replace("]", "")
    for item in reversed(changes):
        path = ".".join(_positions([k.strip() for k in item.partition("=")[0].split(".")], doc))
        if path == field or path.startswith(f"{field}.") or field.startswith(f"{path}."):
            return item
    return None


def _positions(keys: list[str], doc: Any) -> list[str]:
    """``keys`` (a change's path) with each list entry named by its ``name`` given by its position."""
    out, node = [], doc
    for key in keys:
        if isinstance(node, list):
            named = [k for k, e in enumerate(node) if isinstance(e, dict) and e.get("name") == key]
            key = str(named[0]) if len(named) == 1 and not key.isdigit() else key
            node = node[int(key)] if key.isdigit() and int(key) < len(node) else None
        else:
            node = node.get(key) if isinstance(node, dict) else None
        out.append(key)
    return out


_SHORT = reprlib.Repr()
_SHORT.maxstring = 60


def change_document(doc: dict[str, Any], items: Iterable[str]) -> dict[str, Any]:
    """A copy of TOML document ``doc`` with ``path=value`` changes, each applied in turn.

    ``path`` is dotted: a table's key (``seed``, ``model.width``; a missing key or table is added,
    and :func:`build` then checks the name against the config); an array of tables is entered by
    position from 0 or by an entry's ``name`` (``stages.0.lr``, ``stages.forward.lr``). ``value``
    is a TOML value (``341``, ``1e-4``, ``true``, ``"text"``, ``[1, 2]``) or else plain text.
    :class:`ChangeError` names the item for a malformed one or a path through a value that is not
    a table (``seed.x``) or past an array's end."""
    out = copy.deepcopy(doc)
    short = _SHORT
    for item in items:
        path, sep, text = item.partition("=")
        keys = [k.strip() for k in path.split(".")]
        if not sep or not all(keys):
            raise ChangeError(f"{short.repr(item)}: expected path=value, e.g. model.width=341 or stages.0.lr=1e-4")
        node: Any = out
        for depth, key in enumerate(keys[:-1]):
            where = ".".join(keys[: depth + 1])
            if isinstance(node, list):
                node = _entry(node, key, where, short.repr(item))
            elif isinstance(node, dict):
                node = node.setdefault(key, {})
            else:
                raise ChangeError(f"{short.repr(item)}: {'.'.join(keys[:depth])} is a value, not a table")
        last = keys[-1]
        if isinstance(node, list):
            raise ChangeError(f"{short.repr(item)}: {'.'.join(keys)} names an entry of a list, not a value in it")
        if not isinstance(node, dict):
            raise ChangeError(f"{short.repr(item)}: {'.'.join(keys[:-1])} is a value, not a table")
        node[last] = _toml_value(text.strip())
    return out


def _entry(entries: list, key: str, where: str, shown: str) -> Any:
    """The entry of an array of tables that ``key`` names: a position from 0, or an entry's ``name``."""
    if key.isdigit() and key.isascii():
        if int(key) < len(entries):
            return entries[int(key)]
        raise ChangeError(f"{shown}: {where}: the list has {len(entries)} entries (0 to {len(entries) - 1})")
    named = [e for e in entries if isinstance(e, dict) and e.get("name") == key]
    if len(named) == 1:
        return named[0]
    names = [str(e.get("name")) for e in entries if isinstance(e, dict) and "name" in e]
    raise ChangeError(
        f"{shown}: {where}: no entry named {key!r}; give a position from 0"
        + (f" or one of {', '.join(names)}" if names else "")
    )


# -------------------------------------------------------------------------------- key=value changes


def _whole_number(text: str) -> int:
    """``text`` as a whole number: digits (``1000000``) or e-notation of a whole value (``1e6``);
    ``ValueError`` for anything else (``1.5``, ``1e-3``)."""
    try:
        return int(text)
    except ValueError:
        value = float(text)  # ValueError for no number at all
        if not (math.isfinite(value) and value.is_integer() and abs(value) < 2**53):
            raise ValueError(text) from None
        return int(value)


def assign(cls: type[T], items: Iterable[str], error: type[ValueError] = ConfigError, base: T | None = None) -> T:
    """``base`` (default ``cls()``) with ``key=value`` changes (``heading_tolerance=30``); ``error``
    (e.g. a subclass of :class:`odolab.core.errors.InputError`) naming the item, cut short, for an
    unknown key, a key given twice, a value that is not of the field's kind or out of its range;
    the config's own checks (two fields together) raise ``error(message, joiner=": ")`` when
    ``error`` takes a joiner, else ``error(message)``. A field with a range takes a number typed
    plainly (ASCII digits, no ``_``; a whole one also in e-notation, ``1e6``) or one of its choices (``loader_workers=auto``); any other field
    a TOML value (``true``, ``"text"``, ``[1, 2]``), or plain text."""
    hints = typing.get_type_hints(cls)
    names = [f.name for f in dataclasses.fields(cls) if f.init]
    short = reprlib.Repr()  # items are echoed cut short: a 5000-digit value is not printed whole
    short.maxstring = 60
    changes: dict[str, Any] = {}
    for item in items:
        key, sep, text = item.partition("=")
        key, shown = key.strip(), short.repr(item)
        if not sep or key not in names:
            unknown = f"unknown key {key!r}; " if sep and key else ""
            raise error(f"{shown}: {unknown}expected key=value with key one of {', '.join(names)}")
        if key in changes:
            raise error(f"{shown}: {key} is given twice")
        f = _field(cls, key)
        options = choices(cls, key)
        if _RANGE in f.metadata and options and _is_choice(word := _toml_value(text.strip()), options):
            value = word  # loader_workers=auto
        elif _RANGE in f.metadata:
            either = f"{_choices_text(options)} or " if options else ""
            kind = f"{either}{_noun(f)} in {range_text(cls, key)}"
            if len(text.strip()) > MAX_NUMBER_CHARS:
                raise error(f"{shown}: {key} takes {kind}; this value is too long to read")
            try:
                if not text.isascii() or "_" in text:  # Python reads "١" and "1_0" as numbers too
                    raise ValueError(text)
                value = _whole_number(text) if _whole(f) else float(text)
            except ValueError:
                raise error(f"{shown}: {key} takes {kind}") from None
            if not math.isfinite(float(value)) or not in_range(cls, key, value):
                raise error(
                    f"{shown}: {key} must be {either}in {range_text(cls, key)}, got {short.repr(text.strip())[1:-1]}"
                )
        else:
            try:
                value = _check(_toml_value(text.strip()), hints[key], key)
            except ConfigError as exc:
                raise error(f"{shown}: {exc}") from None
        changes[key] = value
    try:
        return dataclasses.replace(base, **changes) if base is not None else cls(**changes)
    except ValueError as exc:
        if issubclass(error, InputError):
            raise error(str(exc), joiner=": ") from None
        raise error(str(exc)) from None


def toml_value(text: str) -> Any:
    """``text`` as a TOML value when it is one (``3``, ``0.5``, ``true``, ``"x"``, ``[1, 2]``), else as
    plain text (``runs/tiny.pt``): how a ``key=value`` of a command line or a recipe change is read.
    :class:`ConfigError` for a value nested too deeply or a number too long for Python to read."""
    try:
        return tomllib.loads(f"v = {text}")["v"]
    except tomllib.TOMLDecodeError:
        return text
    except RecursionError:  # [[[[...]]]] thousands deep
        raise ConfigError("value nested too deeply") from None
    except ValueError:  # Python refuses to read integers of over 4300 digits
        raise ConfigError("a number too long to read (over 4300 digits)") from None


def _toml_value(text: str) -> Any:
    """:func:`toml_value`, or ``text`` itself where that cannot read it (its check then names why)."""
    try:
        return toml_value(text)
    except ConfigError:
        return text
