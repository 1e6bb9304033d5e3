"""The one interface every odometer implements, and the name registry (value types: :mod:`odolab.core.types`).

An odometer sees a sequence of :class:`Frame` pairs and answers, for each pair, an
:class:`Estimate` of ``T_prev_cur`` (conventions in :mod:`odolab.core.geometry`)::

    odo = load_odometer("icp")
    odo.reset(intrinsics)
    for prev, cur, action in pairs:
        est = odo.step(prev, cur, action)   # est.transform: 4x4, est.valid: bool

Odometers are found by name: built-ins and third-party packages declare an entry point in the
group ``odolab.odometers``; a class can also be registered in code with :func:`register_odometer`,
or named directly as ``"package.module:Class"`` (an importable module) or ``"path/to/file.py:Class"``
(a Python file anywhere, imported from its path). A composite ``head(a,b)`` nests at most
:data:`MAX_NESTING` levels deep.
Heavy imports happen when an odometer is loaded, not when :mod:`odolab` is imported.
"""

from __future__ import annotations

import dataclasses
import functools
import hashlib
import importlib
import importlib.util
import inspect
import os
import re
import sys
from collections.abc import Callable, Iterator
from importlib.metadata import entry_points
from typing import Any

import numpy as np

from odolab.core.errors import InputError
from odolab.core.types import MOTION_ACTIONS, Action, Estimate, Frame, Intrinsics, Sequence, as_action  # noqa: F401
from odolab.odometry.configured import configured_signature

__all__ = [
    "ENTRY_POINT_GROUP",
    "MAX_NESTING",
    "REGISTRY",
    "IncompleteOdometerError",
    "Odometer",
    "OdometerListError",
    "OdometerRegistry",
    "OracleInputError",
    "UnknownOdometerError",
    "available_odometers",
    "load_odometer",
    "own_copy",
    "register_odometer",
]

ENTRY_POINT_GROUP = "odolab.odometers"
#: Deepest nesting of composites in one name: ``manhattan(fused(icp,open3d-rgbd))`` is 2.
MAX_NESTING = 8


class Odometer:
    """Base class of all odometers. Subclass it and override :meth:`step` (and :meth:`reset`); a
    class that overrides neither :meth:`step` nor :meth:`step_batch` is refused when loaded by name.

    Class attributes: ``name`` (registry key), ``oracle`` (True if it reads ground truth, e.g.
    ``Frame.gt_pose``; reports mark such rows; a composite with an oracle input must be one too),
    ``batch_size`` (how many consecutive pairs the
    runner hands to :meth:`step_batch` at once; 1 = one :meth:`step` per pair), ``threads``
    (torch threads while this odometer runs, or None to leave torch alone; see :mod:`odolab.running.threads`),
    ``needs_action`` (True if it cannot answer without the action taken, e.g. a learned model with one
    network per action: it is refused on real data, which has no actions), ``composite`` (True for an
    odometer built on others, named with its inputs as ``head(a,b)``: it is never part of "every
    odometer"; a class whose constructor takes ``inputs`` counts as one when it does not say), ``identity_digest`` (a digest of
    what its answers depend on besides code: a learned odometer's model file, a baseline's
    configuration, a fused one's inputs' digests and its calibration; or None: studies that keep
    results per odometer redo them when it changes), ``Config`` (the frozen config dataclass the
    odometer takes as ``config`` and keeps as ``self.config``, or None: its signature then lists
    every field as a keyword option, and the registry checks and describes options from the fields;
    :mod:`odolab.odometry.configured`).
    """

    name: str = "odometer"
    oracle: bool = False
    needs_action: bool = False
    batch_size: int = 1
    threads: int | None = None
    composite: bool = False
    identity_digest: str | None = None
    Config: type | None = None
    _intrinsics: Intrinsics | None = None

    def __init_subclass__(cls, **kwargs) -> None:
        """A subclass's own ``step`` and ``step_batch`` see actions as :class:`Action` or None: an
        integer 0-3 is turned into its Action, anything else refused (:func:`~odolab.core.types.as_action`),
        so that a caller's ``1`` is not silently read as "not MOVE_FORWARD". A subclass that
        declares ``Config`` gets the signature of its options (every field, keyword-only)."""
        super().__init_subclass__(**kwargs)
        if cls.__dict__.get("Config") is not None and "__signature__" not in cls.__dict__:
            cls.__signature__ = configured_signature(cls.__init__, cls.Config)
        if "step" in cls.__dict__:
            cls.step = _actions_checked_step(cls.__dict__["step"])
        if "step_batch" in cls.__dict__:
            cls.step_batch = _actions_checked_batch(cls.__dict__["step_batch"])

    @property
    def intrinsics(self) -> Intrinsics:
        """The camera of the current sequence (set by :meth:`reset`)."""
        if self._intrinsics is None:
            raise RuntimeError(f"{type(self).__name__}: call reset(intrinsics) before step()")
        return self._intrinsics

    @intrinsics.setter
    def intrinsics(self, value: Intrinsics) -> None:
        self._intrinsics = value

    def reset(self, intrinsics: Intrinsics) -> None:
        """Start a new sequence seen through a camera with these intrinsics."""
        self.intrinsics = intrinsics

    def step(self, prev: Frame, cur: Frame, action: Action | None) -> Estimate:
        """Estimate ``T_prev_cur`` for one consecutive frame pair; ``action`` is None on real data."""
        raise NotImplementedError(f"{type(self).__name__} must implement step()")

    def step_batch(self, pairs: list[tuple[Frame, Frame, Action | None]]) -> list[Estimate]:
        """Estimates for consecutive ``(prev, cur, action)`` pairs, in order (default: :meth:`step`
        on each). Override it to batch the work (e.g. one network forward pass) and set
        ``batch_size``; it must return exactly one :class:`Estimate` per pair. Each step's answer is
        copied as it returns (:func:`own_copy`), so a ``step`` that reuses one output array does not
        change the answers before it."""
        return [own_copy(self.step(prev, cur, action)) for prev, cur, action in pairs]


def own_copy(answer: Any) -> Any:
    """An :class:`Estimate` with ``valid`` as a plain bool and its own float64 copy of
    ``transform`` (read once, here: a plug-in's odd array or truth value cannot answer one thing to
    the checks and another to the integration), and its own copies of ``covariance`` and
    ``unverified`` (same dtype; kept as given where they cannot be copied, for the runner's checks);
    anything else (not an Estimate) is returned as it is. Raises where ``valid`` is no bool (or 0 / 1)
    or ``transform`` cannot be read as real numbers (a tensor on a GPU, complex numbers): that step
    fails, with the reason."""
    if not isinstance(answer, Estimate):
        return answer
    if not isinstance(answer.valid, (bool, np.bool_)) and not (
        isinstance(answer.valid, (int, np.integer)) and answer.valid in (0, 1)
    ):
        raise TypeError(f"Estimate.valid must be True or False, got {type(answer.valid).__name__}")
    if np.iscomplexobj(answer.transform):
        raise TypeError("Estimate.transform must be real, got complex numbers")
    valid = bool(answer.valid)
    transform = np.array(answer.transform, dtype=np.float64, copy=True)

    def copied(a: Any) -> Any:
        try:
            return None if a is None else np.array(a, copy=True)
        except Exception:  # noqa: BLE001 - the runner's checks say what is wrong with it
            return a

    return dataclasses.replace(
        answer,
        valid=valid,
        transform=transform,
        covariance=copied(answer.covariance),
        unverified=copied(answer.unverified),
    )


def _actions_checked_step(step: Callable) -> Callable:
    """``step`` (a plain method ``step(self, prev, cur, action, ...)``) with its action argument, given
    by position or by its own name, passed through :func:`as_action`; anything else (a staticmethod, a
    ``step`` without an action argument) is left as it is."""
    if not inspect.isfunction(step) or getattr(step, "_actions_checked", False):
        return step
    params = list(inspect.signature(step).parameters.values())
    if len(params) < 4 or params[3].kind not in (
        inspect.Parameter.POSITIONAL_OR_KEYWORD,
        inspect.Parameter.POSITIONAL_ONLY,
    ):
        return step
    name = params[3].name

    @functools.wraps(step)
    def checked(self, *args, **kwargs):
        if len(args) > 2:
            args = (*args[:2], as_action(args[2]), *args[3:])
        elif name in kwargs:
            kwargs[name] = as_action(kwargs[name])
        return step(self, *args, **kwargs)

    checked._actions_checked = True  # type: ignore[attr-defined]
    return checked


def _actions_checked_batch(step_batch: Callable) -> Callable:
    """``step_batch`` (a plain method) with each pair's action passed through :func:`as_action`, and a
    pair that is not ``(prev, cur, action)`` refused by name."""
    if not inspect.isfunction(step_batch) or getattr(step_batch, "_actions_checked", False):
        return step_batch

    @functools.wraps(step_batch)
    def checked(self, pairs, *args, **kwargs):
        pairs = list(pairs)
        for k, pair in enumerate(pairs):
            if not isinstance(pair, (tuple, list)) or len(pair) != 3:
                raise ValueError(
                    f"step_batch: pair {k} must be (prev, cur, action), got "
                    f"{f'{len(pair)} items' if isinstance(pair, (tuple, list)) else type(pair).__name__}"
                )
        return step_batch(self, [(p, c, as_action(a)) for p, c, a in pairs], *args, **kwargs)

    checked._actions_checked = True  # type: ignore[attr-defined]
    return checked


Odometer.step_batch = _actions_checked_batch(Odometer.step_batch)  # the default one checks its pairs too


class UnknownOdometerError(KeyError):
    """Raised by :func:`load_odometer` for a name nobody registered."""

    def __str__(self) -> str:  # KeyError quotes its message; we want it plain
        return str(self.args[0])


class IncompleteOdometerError(TypeError):
    """Raised by :func:`load_odometer` for a class that overrides neither ``step`` nor
    ``step_batch``: every step it was asked would fail."""


class OracleInputError(ValueError):
    """Raised by :func:`load_odometer` for a composite that takes an oracle input (one reading
    ``Frame.gt_pose``) but is not itself marked ``oracle``: the runner would hide the ground truth
    from it, and its input would never answer."""


def _short_name(name: str) -> str:
    """``name`` cut to 80 characters for a message."""
    return name if len(name) <= 80 else name[:77] + "..."


def nesting_depth(text: str) -> int:
    """The deepest parenthesis level in ``text`` (``fused(icp,manhattan(icp))`` -> 2)."""
    depth = deepest = 0
    for ch in text:
        if ch == "(":
            depth += 1
            deepest = max(deepest, depth)
        elif ch == ")":
            depth -= 1
    return deepest


def check_nesting(text: str) -> None:
    """``ValueError`` when odometer name(s) ``text`` nest composites more than :data:`MAX_NESTING` deep."""
    deepest = nesting_depth(text)
    if deepest > MAX_NESTING:
        raise ValueError(
            f"odometer name {_short_name(text)!r} nests composites {deepest} deep; "
            f"at most {MAX_NESTING} (manhattan(fused(icp,open3d-rgbd)) is 2)"
        )


def _registry() -> dict[str, Callable[..., Odometer] | str]:
    """Name -> class or "module:attr" string, from entry points (installed built-ins included)."""
    reg: dict[str, Callable[..., Odometer] | str] = {
        "ground-truth": "odolab.odometry.reference_odometers:GroundTruthOdometer",
        "action-prior": "odolab.odometry.reference_odometers:ActionPriorOdometer",
        "fused": "odolab.fusion.odometer:FusedOdometer",
    }
    for ep in entry_points(group=ENTRY_POINT_GROUP):
        reg.setdefault(ep.name, ep.value)
    return reg


def _with_inputs(factory: Callable[..., Odometer], name: str, inputs: str) -> Callable[..., Odometer]:
    """``factory`` with its ``inputs`` option fixed to ``inputs`` (and no longer an option: the
    name says it)."""
    signature = inspect.signature(factory)
    if "inputs" not in signature.parameters:
        raise UnknownOdometerError(f"odometer {name.split('(')[0]!r} takes no inputs, so {name!r} means nothing")

    def build(**options) -> Odometer:
        if "inputs" in options:
            raise ValueError(f"{name}: its inputs are in its name; the option 'inputs' cannot change them")
        return factory(inputs=inputs, **options)

    build.__signature__ = signature.replace(parameters=[p for k, p in signature.parameters.items() if k != "inputs"])
    return build


def _names_a_file(module: str) -> bool:
    """Whether the module part of ``module:Class`` is a Python file's path rather than a module name."""
    return module.endswith(".py") or "/" in module or os.sep in module


def _import_file(path: str):
    """The module of Python file ``path`` (relative to the current folder), imported once per
    file: it is kept in ``sys.modules`` under a name made from its absolute path, as an import
    keeps a module, so a second load returns the same classes. ``ImportError`` naming the file
    when it is missing or raises while it is imported."""
    full = os.path.abspath(path)
    if not os.path.isfile(full):
        raise ImportError(
            f"no such file {path}" + (" (a file's path must end in .py)" if not full.endswith(".py") else "")
        )
    stem = re.sub(r"\W", "_", os.path.splitext(os.path.basename(full))[0])
    module_name = f"odolab_file_{stem}_{hashlib.sha256(full.encode()).hexdigest()[:12]}"
    if module_name in sys.modules:
        return sys.modules[module_name]
    spec = importlib.util.spec_from_file_location(module_name, full)
    if spec is None or spec.loader is None:
        raise ImportError(f"{path} is not a Python file")
    module = importlib.util.module_from_spec(spec)
    sys.modules[module_name] = module  # dataclasses and pickling look their module up there
    try:
        spec.loader.exec_module(module)
    except (Exception, SystemExit) as exc:  # noqa: BLE001 - a syntax error or any error of the file's own code
        del sys.modules[module_name]
        raise ImportError(f"{path} raised {type(exc).__name__} while imported: {exc}") from None
    except BaseException:
        del sys.modules[module_name]
        raise
    return module


#: ``head(inputs)``: an odometer built on others, e.g. ``fused(icp,open3d-rgbd)``.
COMPOSITE = re.compile(r"(?P<head>[A-Za-z0-9_.:-]+)\((?P<inputs>.*)\)")


def split_odometer_names(text: str, keep_empty: bool = False) -> list[str]:
    """Comma-separated odometer names, commas inside parentheses kept: ``"icp,fused(icp,open3d-rgbd)"``
    -> ``["icp", "fused(icp,open3d-rgbd)"]``; empty names dropped unless ``keep_empty``. Raises
    ``ValueError`` on unbalanced parentheses."""
    check_nesting(text)
    names, depth, part = [], 0, ""
    for ch in text:
        depth += {"(": 1, ")": -1}.get(ch, 0)
        if depth < 0:
            raise ValueError(f"unbalanced ')' in odometer names {text!r}")
        if ch == "," and depth == 0:
            names.append(part.strip())
            part = ""
        else:
            part += ch
    if depth:
        raise ValueError(f"unbalanced '(' in odometer names {text!r}")
    names.append(part.strip())
    return names if keep_empty else [n for n in names if n]


class OdometerListError(InputError):
    """A list of odometer names that cannot be run (empty, a name twice, a composite with an empty
    or repeated input); ``named("--odometers")`` words it after a command line's option."""

    subject = "odometer list"


def parse_odometer_list(text: str) -> list[str]:
    """A list of odometer names such as a command line's ``--odometers``: :func:`split_odometer_names`,
    refusing an empty list, a name given twice and a composite with an empty or repeated input
    (:class:`OdometerListError`; ``ValueError`` for unbalanced parentheses)."""
    parts = split_odometer_names(text, keep_empty=True)
    names = [n for n in parts if n]
    if not names:
        raise OdometerListError("is empty")
    if len(names) < len(parts):
        raise OdometerListError(f"{text!r} has an empty name (a comma too many?)", joiner=": ")
    twice = sorted({n for n in names if names.count(n) > 1})
    if twice:
        raise OdometerListError(f"names {twice[0]!r} twice")
    for name in names:
        match = COMPOSITE.fullmatch(name)
        if match:
            parts = split_odometer_names(match["inputs"], keep_empty=True)  # fused(fused(a,b),c): 2 inputs
            if any(not part for part in parts):
                raise OdometerListError(
                    f"{name!r} has an empty input; name its inputs inside the parentheses, "
                    "e.g. fused(icp,open3d-rgbd) or manhattan(icp)",
                    joiner=": ",
                )
            if len(set(parts)) < len(parts):
                raise OdometerListError(f"{name!r}: an input is named twice", joiner=": ")
    return names


def inner_names(name: str) -> set[str]:
    """Every odometer named inside a composite ``name`` at any depth (``manhattan(fused(a,b))`` ->
    ``{"fused(a,b)", "a", "b"}``); empty for a plain name or unbalanced parentheses. ``ValueError``
    for a name nested deeper than :data:`MAX_NESTING`."""
    check_nesting(name)
    match = COMPOSITE.fullmatch(name)
    if not match:
        return set()
    try:
        parts = split_odometer_names(match["inputs"])
    except ValueError:
        return set()
    return set(parts).union(*(inner_names(p) for p in parts))


class OdometerRegistry:
    """Names to odometer factories: entry points plus classes registered in code."""

    def __init__(self) -> None:
        self._extra: dict[str, Callable[..., Odometer]] = {}

    def register(self, name: str, factory: Callable[..., Odometer]) -> None:
        """Make ``factory`` (usually an :class:`Odometer` subclass) loadable as ``name``."""
        self._extra[name] = factory

    def names(self) -> list[str]:
        """All loadable names, sorted."""
        return sorted({**_registry(), **self._extra})

    def resolve(self, name: str) -> Callable[..., Odometer]:
        """The factory for ``name``; :class:`UnknownOdometerError` lists the valid choices.
        ``head(a,b,...)`` is odometer ``head`` with its option ``inputs="a,b,..."`` (e.g. ``fused(icp,robust-vo)``);
        ``module:Class`` is imported, ``path/to/file.py:Class`` is imported from that file; a module
        that cannot be imported (whatever it raises) is an :class:`UnknownOdometerError` naming it.
        ``ValueError`` for a name nested deeper than :data:`MAX_NESTING`."""
        check_nesting(name)
        composite = COMPOSITE.fullmatch(name)
        if composite:
            return _with_inputs(self.resolve(composite["head"]), name, composite["inputs"])
        target = self._extra.get(name) or _registry().get(name)
        if target is None and ":" in name:  # "package.module:Class" or "file.py:Class", imported on demand
            target = name
        if target is None:
            raise UnknownOdometerError(f"unknown odometer {name!r}; available: {', '.join(self.names())}")
        if isinstance(target, str):
            module, _, attr = target.rpartition(":")
            try:
                obj = _import_file(module) if _names_a_file(module) else importlib.import_module(module)
                for part in attr.split("."):
                    obj = getattr(obj, part)
            except (ImportError, AttributeError) as exc:
                raise UnknownOdometerError(f"odometer {name!r}: cannot import {target!r} ({exc})") from None
            except (Exception, SystemExit) as exc:  # noqa: BLE001 - a plug-in's module may raise anything at import
                raise UnknownOdometerError(
                    f"odometer {name!r}: cannot import {target!r} ({type(exc).__name__} while imported: {exc})"
                ) from None
            return obj
        return target

    def load(self, name: str, **options) -> Odometer:
        """Instantiate odometer ``name`` with keyword ``options`` (numpy scalars are passed on as the
        Python numbers they hold, so ``np.float32(4.0)`` sets an option as ``4.0`` does).
        :class:`IncompleteOdometerError` for an object that is not an :class:`Odometer`, or one
        overriding neither ``step`` nor ``step_batch``; :class:`OracleInputError` for a composite that does not pass on its
        input's ``oracle``."""
        options = {k: v.item() if isinstance(v, np.generic) else v for k, v in options.items()}
        odo = self.resolve(name)(**options)
        if not isinstance(odo, Odometer):
            raise IncompleteOdometerError(
                f"odometer {_short_name(name)!r}: made a {type(odo).__name__}, not an Odometer; subclass "
                "odolab.api.Odometer (it gives the name, oracle and intrinsics every odometer has)"
            )
        if type(odo).step is Odometer.step and type(odo).step_batch is Odometer.step_batch:
            raise IncompleteOdometerError(
                f"odometer {_short_name(name)!r}: class {type(odo).__name__} overrides neither step() nor "
                "step_batch(), so every step would fail; implement step(prev, cur, action)"
            )
        oracle_input = self._oracle_input(name)
        if oracle_input is not None and not getattr(odo, "oracle", False):
            head = name.split("(")[0]
            raise OracleInputError(
                f"odometer {_short_name(name)!r}: its input {oracle_input!r} reads ground truth (an oracle), but "
                f"{head} is not marked oracle, so the input would never see it; set {head}'s oracle attribute "
                "from its inputs, or leave the oracle out"
            )
        odo.name = name
        return odo

    def _oracle_input(self, name: str) -> str | None:
        """The first input of composite ``name`` (at any depth) whose class is marked ``oracle``,
        or None (also for a plain name)."""
        composite = COMPOSITE.fullmatch(name)
        if not composite:
            return None
        for part in split_odometer_names(composite["inputs"]):
            if COMPOSITE.fullmatch(part):
                found = self._oracle_input(part)
            else:
                try:
                    found = part if getattr(self.resolve(part), "oracle", False) is True else None
                except UnknownOdometerError:
                    found = None  # the composite has named it already, or will
            if found is not None:
                return found
        return None

    def __iter__(self) -> Iterator[str]:
        return iter(self.names())


#: The default registry behind :func:`load_odometer` and friends.
REGISTRY = OdometerRegistry()


def register_odometer(name: str, factory: Callable[..., Odometer]) -> None:
    """Register a class (or any callable returning an :class:`Odometer`) under ``name``."""
    REGISTRY.register(name, factory)


def available_odometers() -> list[str]:
    """Names :func:`load_odometer` accepts (composites such as ``fused`` take inputs: ``fused(a,b)``)."""
    return REGISTRY.names()


def is_composite(factory: Callable[..., Odometer]) -> bool:
    """Whether ``factory`` makes an odometer built on others: its class declares ``composite = True``,
    or (declaring nothing) its constructor takes ``inputs``, which only a composite's name gives."""
    declared = getattr(factory, "composite", None)
    if isinstance(declared, bool) and (declared or "composite" in vars(factory)):
        return declared
    try:
        return "inputs" in inspect.signature(factory).parameters
    except (TypeError, ValueError):  # a callable without a signature
        return False


def standalone_odometers() -> list[str]:
    """:func:`available_odometers` without the composites (:func:`is_composite`): what "every
    odometer" means. Each name's class is imported to ask it; one that cannot be is kept (loading
    it then says why)."""
    names = []
    for name in REGISTRY.names():
        try:
            composite = is_composite(REGISTRY.resolve(name))
        except UnknownOdometerError:
            composite = False
        if not composite:
            names.append(name)
    return names


def unknown_odometer(name: str) -> str | None:
    """The first part of ``name`` that names no odometer (``name`` itself, or an input of a
    composite ``head(a,b)``), or None when every part is known. ``module:Class`` and
    ``file.py:Class`` count as known. ``ValueError`` for a name nested deeper than :data:`MAX_NESTING`."""
    check_nesting(name)
    known = set(REGISTRY.names())
    composite = COMPOSITE.fullmatch(name)
    if composite:
        if composite["head"] not in known:
            return composite["head"]
        try:
            parts = split_odometer_names(composite["inputs"])
        except ValueError:
            return name
        return next((u for u in map(unknown_odometer, parts) if u), None)  # no parts: the odometer says so
    return None if name in known or ":" in name else name


def load_odometer(name: str, **options) -> Odometer:
    """Instantiate a registered odometer by name."""
    return REGISTRY.load(name, **options)
