"""An odometer's ``Config``: the frozen dataclass (fields declared with :func:`odolab.config.setting`)
it takes and keeps as ``odometer.config``. Keyword options override single fields wherever they sit,
nested configs included (``load_odometer("icp", max_depth=3.0, voxel=0.05)`` sets
``config.depth.max_depth`` and ``config.voxel``: :func:`configure`); the odometer's signature lists
every field (:func:`configured_signature`, which :class:`~odolab.odometry.odometer.Odometer` sets for a
class that declares ``Config``), so the registry's option checks and help come from the fields; and
:func:`config_digest` is what its answers depend on besides code."""

from __future__ import annotations

import hashlib
import inspect
import json
from collections.abc import Callable, Iterable
from dataclasses import Field, asdict, fields, is_dataclass, replace
from typing import Any, TypeVar


class OptionTypeError(TypeError, ValueError):
    """An option of a type its field does not take (``anchor_steps=2.5``, ``kernel_width="abc"``): a
    ``TypeError`` and a ``ValueError`` both, as callers of either kind expect."""


__all__ = [
    "OptionTypeError",
    "check_choice",
    "config_digest",
    "configure",
    "configured_signature",
    "option_names",
    "options_signature",
]

_C = TypeVar("_C")


class _Changes(dict):
    """Field name -> new value, or -> the changes of a nested config (another ``_Changes``)."""


def configure(cls: type[_C], config: _C | None = None, **overrides: Any) -> _C:
    """``config`` (default ``cls()``) with each keyword override applied to the field of that name.

    The field is looked up in the config and in the configs nested in it (a field holding a
    dataclass); the shallowest match wins. ``TypeError`` for a name no field has, one that two
    nested configs share at the same depth, or a value its simple annotation (``float``, ``int |
    None``, ...) does not allow; the configs' own checks raise ``ValueError``.
    """
    config = cls() if config is None else config
    if not isinstance(config, cls):
        raise TypeError(f"expected a {cls.__name__}, got {type(config).__name__}")
    changes = _Changes()
    for name, value in overrides.items():
        paths = _paths(config, name)
        if not paths:
            raise TypeError(f"{cls.__name__} has no option {name!r}; options: {', '.join(option_names(config))}")
        shallowest = [p for p in paths if len(p) == len(paths[0])]
        if len(shallowest) > 1:
            raise TypeError(
                f"{cls.__name__}: option {name!r} is ambiguous: {', '.join('.'.join(p) for p in shallowest)}"
            )
        current = config
        for part in paths[0]:
            current = getattr(current, part)
        if _is_config(current) and value is not None and not isinstance(value, type(current)):
            raise TypeError(
                f"{cls.__name__}: {name!r} is a group of options ({', '.join(option_names(current))}); "
                "set those instead"
            )
        _check_type(cls.__name__, _field(config, paths[0]), value)
        node = changes
        for part in paths[0][:-1]:
            node = node.setdefault(part, _Changes())
            if not isinstance(node, _Changes):
                raise TypeError(f"{cls.__name__}: {part!r} and {name!r} both given; give one")
        node[name] = value
    return _apply(config, changes)


def options_signature(config_cls: type) -> inspect.Signature:
    """What an odometer configured by ``config_cls`` accepts, for ``inspect.signature`` (and option
    checkers that read it): ``config``, then every field name, nested or not, keyword-only, with its
    annotation and default. Set it as the odometer class's ``__signature__``."""
    default = config_cls()
    params = [
        inspect.Parameter(
            "config", inspect.Parameter.POSITIONAL_OR_KEYWORD, default=None, annotation=f"{config_cls.__name__} | None"
        )
    ]
    for name in dict.fromkeys(path[-1] for path in _all_paths(default)):  # declaration order
        path = _paths(default, name)[0]
        value = default
        for part in path:
            value = getattr(value, part)
        params.append(
            inspect.Parameter(
                name, inspect.Parameter.KEYWORD_ONLY, default=value, annotation=_field(default, path).type
            )
        )
    return inspect.Signature(params)


def configured_signature(init: Callable[..., Any], config_cls: type) -> inspect.Signature:
    """The signature of an odometer whose ``__init__(self, ..., config=None, **overrides)`` takes
    ``config_cls``: ``__init__``'s own parameters (``self`` and ``**overrides`` left out), then every
    field of ``config_cls`` as a keyword-only option (:func:`options_signature`)."""
    own = [
        p
        for name, p in inspect.signature(init).parameters.items()
        if name != "self" and p.kind is not inspect.Parameter.VAR_KEYWORD
    ]
    config_param, *fields_ = options_signature(config_cls).parameters.values()
    if not any(p.name == "config" for p in own):
        own.append(config_param)
    taken = {p.name for p in own}
    return inspect.Signature([*own, *(p for p in fields_ if p.name not in taken)])


def config_digest(config: object) -> str:
    """SHA-256 of every field of ``config`` (nested ones too) as sorted JSON: what a baseline's
    answers depend on besides its code. Baselines keep it as ``Odometer.identity_digest``, so that studies
    which keep results per odometer redo them when a default or an option changes."""
    return hashlib.sha256(json.dumps(_as_floats(asdict(config)), sort_keys=True, default=repr).encode()).hexdigest()


def _as_floats(value: Any) -> Any:
    """Every number (not bool) as a float, in nested dicts, lists and tuples: ``6`` and ``6.0`` set
    the same option and give the same digest."""
    if isinstance(value, dict):
        return {k: _as_floats(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_as_floats(v) for v in value]
    return float(value) if isinstance(value, (int, float)) and not isinstance(value, bool) else value


def check_choice(name: str, value: object, choices: Iterable[object]) -> None:
    """``ValueError`` unless ``value`` (of option ``name``) is one of ``choices``."""
    choices = tuple(choices)
    if value not in choices:
        raise ValueError(f"{name} must be one of {', '.join(map(str, choices))}; got {value!r}")


def option_names(config: object) -> list[str]:
    """Every field name of ``config`` and of the configs nested in it, sorted."""
    return sorted({path[-1] for path in _all_paths(config)})


def _all_paths(config: object) -> list[tuple[str, ...]]:
    """Paths (field names, outermost first) to every field, nested ones too, in declaration order."""
    found = []
    for f in fields(config):
        found.append((f.name,))
        value = getattr(config, f.name)
        if _is_config(value):
            found += [(f.name, *p) for p in _all_paths(value)]
    return found


def _paths(config: object, name: str) -> list[tuple[str, ...]]:
    """Paths to the fields called ``name``, shallowest first."""
    return sorted((p for p in _all_paths(config) if p[-1] == name), key=len)


def _apply(config: _C, changes: _Changes) -> _C:
    """One ``dataclasses.replace`` per config level (so checks see all changes of a level at once)."""
    return replace(
        config, **{k: _apply(getattr(config, k), v) if isinstance(v, _Changes) else v for k, v in changes.items()}
    )


#: Simple annotations -> the Python types a value may have (an int is a number; a bool is not).
_SIMPLE = {"float": (int, float), "int": (int,), "str": (str,), "bool": (bool,)}


def _field(config: object, path: tuple[str, ...]) -> Field:
    for part in path[:-1]:
        config = getattr(config, part)
    return next(f for f in fields(config) if f.name == path[-1])


def _check_type(owner: str, f: Field, value: Any) -> None:
    """``TypeError`` for a value a simple annotation (``float``, ``int | None``, ...) does not allow;
    other annotations are left to the config's own checks."""
    parts = [p.strip() for p in str(f.type).split("|")]
    if value is None and "None" in parts:
        return
    simple = [p for p in parts if p != "None"]
    if not simple or not all(p in _SIMPLE for p in simple):
        return
    if not any(isinstance(value, _SIMPLE[p]) and (p == "bool" or not isinstance(value, bool)) for p in simple):
        raise OptionTypeError(f"{owner}: option {f.name} must be {' or '.join(simple)}, got {value!r}")


def _is_config(value: object) -> bool:
    return is_dataclass(value) and not isinstance(value, type)
