"""Configs from TOML files (read with :mod:`tomllib`, never evaluated) into frozen dataclasses, with
errors that name the file, the field, what was expected and what was found."""

from __future__ import annotations

import dataclasses
import os
import types
import typing
from typing import Any, TypeVar

from odolab.io.tomlfile import read_toml as read_toml_document

T = TypeVar("T")

#: Longest chain of ``base =`` files one recipe may start from.
MAX_BASE_CHAIN = 16
#: Deepest nesting of tables that two documents of a ``base =`` chain are merged through.
MAX_TABLE_DEPTH = 32


class ConfigError(ValueError):
    """A config that cannot be used; the message names the file and field."""


def read_toml(path: str | os.PathLike, _seen: tuple[str, ...] = ()) -> dict[str, Any]:
    """The TOML document at ``path``; :class:`ConfigError` when missing or malformed.

    A top-level ``base = "other.toml"`` (relative to this file) starts from that document: tables
    are merged key by key, anything else (numbers, strings, lists such as ``[[stages]]``) replaces
    the base's value. So a variant of a recipe states only what it changes. A chain of more than
    :data:`MAX_BASE_CHAIN` bases is refused.
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
    base_path = os.path.join(os.path.dirname(os.path.abspath(path)), base)
    if os.path.abspath(base_path) in _seen or os.path.abspath(path) == os.path.abspath(base_path):
        raise ConfigError(f"{path}: base {base!r} leads back to itself")
    if not os.path.isfile(base_path):
        raise ConfigError(f"{path}: its base {base!r} is not a file ({base_path})")
    merged = read_toml(base_path, (*_seen, os.path.abspath(path)))
    try:
        return _merge(merged, doc)
    except ConfigError as exc:
        raise ConfigError(f"{path}: {exc}") from None


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
        for option in typing.get_args(annotation):
            if option is type(None) and value is None:
                return None
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
        return dataclass_from_dict(annotation, value, where)
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


def dataclass_from_dict(cls: type[T], doc: dict[str, Any], where: str) -> T:
    """Build dataclass ``cls`` from ``doc``, checking names and types; ``where`` prefixes errors."""
    hints = typing.get_type_hints(cls)
    known = {f.name for f in dataclasses.fields(cls) if f.init}
    unknown = sorted(set(doc) - known)
    if unknown:
        raise ConfigError(
            f"{where}: unknown field(s) {', '.join(unknown)}; expected some of {', '.join(sorted(known))}"
        )
    values = {k: _check(v, hints[k], f"{where}.{k}" if where else k) for k, v in doc.items()}
    try:
        return cls(**values)
    except (TypeError, ValueError) as exc:
        raise ConfigError(f"{where}: {exc}") from None


def dataclass_from_toml(cls: type[T], path: str | os.PathLike) -> T:
    """Read ``path`` and build ``cls`` from it (see :func:`dataclass_from_dict`)."""
    return dataclass_from_dict(cls, read_toml(path), str(path))


def check_ranges(what: str, obj: Any, **bounds: tuple[float, float]) -> None:
    """``ValueError`` naming ``what``, the field, its range and the value, unless every field of
    ``obj`` named in ``bounds`` is a finite number in its closed ``(low, high)`` range."""
    import math

    for name, (low, high) in bounds.items():
        value = getattr(obj, name)
        if not (isinstance(value, (int, float)) and math.isfinite(value) and low <= value <= high):
            show = [f"{b:d}" if isinstance(b, int) else f"{b:g}" for b in (low, high)]
            prefix = f"{what}: " if what else ""
            raise ValueError(f"{prefix}{name} must be in [{show[0]}, {show[1]}], got {value!r}")
