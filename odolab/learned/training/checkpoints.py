"""Checkpoints as plain data: ``{"format": ..., "kind": ..., ...}`` of tensors, numbers, strings,
lists and dicts, written atomically and read with ``torch.load(weights_only=True)`` (no pickled code
is ever executed).

Every checkpoint carries a SHA-256 of its contents (:data:`CHECKSUM_KEY`: every tensor's dtype,
shape and bytes and every other value, in a fixed key order; :func:`content_digest`), checked
when it is read: a flipped bit in a weight is refused in one line naming the file
(:class:`CheckpointError`), never run. A file written before checksums were kept is read with a
one-line note on stderr; the shipped models, written before, are checked against the SHA-256 of
their bytes instead (:class:`Shipped`)."""

from __future__ import annotations

import hashlib
import io
import os
import pickle
import sys
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from odolab.io.atomic import write_bytes_atomic


class CheckpointError(ValueError):
    """A file that is not a checkpoint of the expected kind and format (the message names it)."""


#: The entry of a checkpoint that holds the SHA-256 (hex) of the rest of its contents.
CHECKSUM_KEY = "content_sha256"


@dataclass(frozen=True)
class Shipped:
    """A model file shipped with odolab before checksums were kept inside files: where it lies and
    the SHA-256 (hex) of its bytes, which it must match when read from there."""

    path: Path
    sha256: str


def _order(key: Any) -> tuple[str, str]:
    """A sort key for a dict's keys of any plain type (optimiser states have integer keys)."""
    return type(key).__name__, str(key)


def _feed(h: Any, value: Any) -> None:
    """Add ``value`` (tensors, dicts, lists, tuples, numbers, strings, None) to hash ``h``, each
    part tagged with its type and length so that no two different documents feed the same bytes."""
    if isinstance(value, torch.Tensor):
        t = value.detach().cpu().contiguous()
        h.update(f"T{t.dtype}{tuple(t.shape)}:".encode())
        if t.numel():
            h.update(t.reshape(-1).view(torch.uint8).numpy())
    elif isinstance(value, dict):
        h.update(f"D{len(value)}:".encode())
        for key in sorted(value, key=_order):
            _feed(h, key)
            _feed(h, value[key])
    elif isinstance(value, (list, tuple)):
        h.update(f"{'L' if isinstance(value, list) else 'U'}{len(value)}:".encode())
        for item in value:
            _feed(h, item)
    elif isinstance(value, str):
        data = value.encode("utf-8", "surrogatepass")
        h.update(f"S{len(data)}:".encode() + data)
    elif isinstance(value, float):
        h.update(f"F{value.hex()};".encode())
    elif value is None or isinstance(value, (bool, int)):
        h.update(f"{type(value).__name__}{value!r};".encode())
    else:  # a torch.dtype, a device...: what weights_only loading accepts besides the above
        text = repr(value).encode("utf-8", "surrogatepass")
        h.update(f"O{type(value).__qualname__}{len(text)}:".encode() + text)


def content_digest(doc: dict[str, Any]) -> str:
    """The SHA-256 (hex) of a checkpoint's contents, its :data:`CHECKSUM_KEY` entry left out: the
    same for the document saved and the one read back, whatever the order of its keys."""
    h = hashlib.sha256()
    _feed(h, {k: v for k, v in doc.items() if k != CHECKSUM_KEY})
    return h.hexdigest()


def save_checkpoint(path: str | os.PathLike, kind: str, format: int, doc: dict[str, Any]) -> None:
    """Write ``doc`` (plain data and tensors) tagged with ``kind``, ``format`` and the checksum of it
    all (:func:`content_digest`; one already in ``doc`` is replaced), atomically."""
    full = {"kind": kind, "format": format, **{k: v for k, v in doc.items() if k != CHECKSUM_KEY}}
    full[CHECKSUM_KEY] = content_digest(full)
    buffer = io.BytesIO()
    torch.save(full, buffer)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    write_bytes_atomic(path, buffer.getvalue())


def check_checksum(
    path: str | os.PathLike, doc: dict[str, Any], shipped: Shipped | None = None, file_sha256: str | None = None
) -> None:
    """Refuse (:class:`CheckpointError`, one line naming the file) a checkpoint whose contents do not
    match the checksum stored in it. One without a checksum (written before they were kept) is
    read with a one-line note on stderr, unless it is the ``shipped`` file (or a copy of it: the
    SHA-256 of its bytes, ``file_sha256``, is the shipped one's): then its bytes must match."""
    stored = doc.get(CHECKSUM_KEY)
    if stored is not None:
        if not isinstance(stored, str) or stored != content_digest(doc):
            raise CheckpointError(
                f"{path}: damaged: its contents do not match the checksum stored in it (a changed bit, or "
                "a file edited by hand); use an intact copy, or train or export it again"
            )
        return
    if shipped is not None and file_sha256 == shipped.sha256:
        return  # the shipped file, byte for byte (here or copied elsewhere)
    if shipped is not None and _same_file(path, shipped.path):
        raise CheckpointError(
            f"{path}: damaged: the shipped model's bytes do not match its SHA-256 ({shipped.sha256[:16]}...); "
            "restore it (git checkout, or reinstall odolab)"
        )
    print(
        f"note: {path}: written before odolab kept checksums in its files, so damage to it cannot be "
        "detected; save it again (train or export) to add one",
        file=sys.stderr,
    )


def _same_file(a: str | os.PathLike, b: str | os.PathLike) -> bool:
    """Whether ``a`` and ``b`` are one file (links and hard links followed; False when one is missing)."""
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


def load_checkpoint(path: str | os.PathLike, kind: str, format: int, *, verify: bool = True) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint`; :class:`CheckpointError` names the file
    and what is wrong (missing, unreadable, unsafe content, another kind or format, or, with
    ``verify``, contents that do not match its checksum: :func:`check_checksum`)."""
    if os.path.isdir(path):
        raise CheckpointError(f"{path}: is a folder, not a checkpoint file")
    if os.path.islink(path) and not os.path.exists(path):
        raise CheckpointError(f"{path}: a link to nothing, not a checkpoint file")
    if os.path.exists(path) and not os.path.isfile(path):
        raise CheckpointError(f"{path}: a pipe, device or socket, not a checkpoint file")
    if not os.path.isfile(path):
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        with warnings.catch_warnings():  # torch warns of an old pickle protocol before refusing: one line only
            warnings.simplefilter("ignore")
            doc = torch.load(path, map_location="cpu", weights_only=True)
    except pickle.UnpicklingError:  # torch's message would suggest weights_only=False: never for a file like this
        raise CheckpointError(
            f"{path}: not a readable torch checkpoint (corrupt, or it holds objects other than "
            "tensors and plain data, which odolab never unpickles)"
        ) from None
    except Exception as exc:  # noqa: BLE001 - truncated, not a zip, not torch's format: whatever torch raised
        raise CheckpointError(
            f"{path}: not a readable torch checkpoint (corrupt or not a torch file: {type(exc).__name__})"
        ) from None
    if not isinstance(doc, dict) or doc.get("kind") != kind:
        got = doc.get("kind") if isinstance(doc, dict) else type(doc).__name__
        raise CheckpointError(f"{path}: expected a checkpoint of kind {kind!r}, got {got!r}")
    if doc.get("format") != format:
        raise CheckpointError(
            f"{path}: {kind} checkpoint of format {doc.get('format')!r}; this odolab reads format {format}"
        )
    if verify:
        check_checksum(path, doc)
    return doc


MODEL_FORMAT = 1


def what_file(path: str | os.PathLike, kind: str | None = None) -> str | None:
    """None when ``path`` is a model file odolab exported (of ``kind``, when given); else what it
    is, in words: "a training state", "a checkpoint of kind 'x'", "a model of kind 'x' (another
    trainer's)", "a folder", or "a file that is not an odolab model (a recipe, data or another
    program's file)"."""
    if os.path.isdir(path):
        return "a folder"
    if os.path.islink(path) and not os.path.exists(path):
        return "a link to nothing (or a loop of links)"
    try:
        doc = torch.load(path, map_location="cpu", weights_only=True)
    except Exception:  # noqa: BLE001 - not a torch file, or unsafe content: not a model either way
        return "a file that is not an odolab model (a recipe, data or another program's file)"
    if (
        isinstance(doc, dict)
        and doc.get("format") == MODEL_FORMAT
        and isinstance(doc.get("networks"), dict)
        and isinstance(doc.get("kind"), str)
        and "model" in doc
    ):
        return None if kind is None or doc["kind"] == kind else f"a model of kind {doc['kind']!r} (another trainer's)"
    kind = doc.get("kind") if isinstance(doc, dict) else None
    if kind == "odolab-training-state":
        return "a training state"
    return f"a checkpoint of kind {kind!r}" if isinstance(kind, str) else "a torch file that is not an odolab model"


def check_export(export: Path, recipe: Path, states: dict[str, Path], kind: str | None = None) -> None:
    """Refuse, with one ``ValueError`` line naming ``--export``, what it would find there and what
    it expects, an export path that would replace what no export wrote: the recipe, a training
    state the run keeps (``states``: what keeps it -> its path, e.g. ``"stage 'model'"``), or an
    existing file that is not a model odolab exported (a state, data, a recipe) or is another
    trainer's model (``kind``: this trainer's). Checked before any training."""
    export = Path(export)
    expected = "a new file or a model odolab exported"

    def same(a: Path, b: Path) -> bool:
        try:
            return os.path.samefile(a, b)
        except OSError:
            return os.path.realpath(a) == os.path.realpath(b)

    if same(export, recipe):
        raise ValueError(
            f"--export {export}: expected {expected}, found the recipe (--config {recipe}), which the "
            "model would replace; give --export another path"
        )
    for what, state in states.items():
        if same(export, state):
            raise ValueError(
                f"--export {export}: expected {expected}, found the file where {what} keeps its "
                "training state, which the model would replace; give --export another path"
            )
    if os.path.lexists(export):
        found = what_file(export, kind)
        if found is not None:
            raise ValueError(
                f"--export {export}: expected {expected}, found {found}; odolab replaces only the "
                "models it exported: give --export another path"
            )


#: Model files whose float32 weights would be larger than this store them in float16 (the project's
#: limit on a shipped model is 20 MB; the rest of the file is a few kilobytes).
MAX_MODEL_BYTES = 19_000_000


def save_model(
    path: str | os.PathLike, kind: str, recipe: Any, networks: dict[str, torch.nn.Module], training: dict[str, Any]
) -> None:
    """A trained model file: the recipe (a dataclass with a ``model`` field; its ``model`` part is what
    loading needs), each network's weights (on the CPU) and the training status, all plain data.
    Floating-point weights are stored in float32, or in float16 where float32 would pass
    :data:`MAX_MODEL_BYTES` (loading casts them back to the network's float32; the file's
    ``weights_dtype`` says which). An existing file at ``path`` that is not a model odolab exported is
    never replaced (:class:`CheckpointError`, see :func:`what_file`)."""
    import dataclasses
    import json

    if os.path.lexists(path) and (found := what_file(path, kind)) is not None:
        raise CheckpointError(
            f"{path}: expected a new file or a model odolab exported, found {found}; "
            "not replaced (export the model elsewhere)"
        )
    doc = json.loads(json.dumps(dataclasses.asdict(recipe)))
    weights = {name: {k: v.detach().cpu() for k, v in net.state_dict().items()} for name, net in networks.items()}
    dtype = torch.float32
    if sum(v.numel() * 4 for w in weights.values() for v in w.values() if v.is_floating_point()) > MAX_MODEL_BYTES:
        dtype = torch.float16
    weights = {
        name: {k: v.to(dtype) if v.is_floating_point() else v for k, v in w.items()} for name, w in weights.items()
    }
    save_checkpoint(
        path,
        kind,
        MODEL_FORMAT,
        {
            "model": doc["model"],
            "recipe": doc,
            "training": json.loads(json.dumps(training)),
            "weights_dtype": str(dtype).removeprefix("torch."),
            "networks": weights,
        },
    )


def load_model(
    path: str | os.PathLike,
    kind: str,
    model_cls: type,
    build: Callable[[Any], dict[str, torch.nn.Module]],
    shipped: Shipped | None = None,
) -> tuple[Any, dict[str, torch.nn.Module], dict]:
    """Read a model file of ``kind``: (``model_cls`` config, networks built by ``build(config)`` with
    their weights, in eval mode, ``{"recipe": ..., "training": ..., "sha256": file digest}``). :class:`CheckpointError`
    names the file when it is not such a file, its weights do not fit its config or its contents
    do not match its checksum (:func:`check_checksum`; ``shipped``: the model shipped with odolab)."""
    from odolab.config import build as build_config

    doc = load_checkpoint(path, kind, MODEL_FORMAT, verify=False)  # checked below, once it reads as a model
    try:
        cfg = build_config(model_cls, doc["model"], f"{path}: model")
        nets = build(cfg)
        missing = sorted(set(nets) - set(doc["networks"]))
        if missing:
            raise CheckpointError(f"{path}: no weights for network(s) {', '.join(missing)}")
        for name, net in nets.items():
            net.load_state_dict(doc["networks"][name])
            net.eval()
            for key, value in net.state_dict().items():
                if value.is_floating_point() and not bool(torch.isfinite(value).all()):
                    raise CheckpointError(f"{path}: network {name}: {key} holds NaN or infinite values")
    except CheckpointError:
        raise
    except (KeyError, TypeError, RuntimeError, ValueError) as exc:
        lines = [line.strip() for line in str(exc).strip().splitlines() if line.strip()] or [type(exc).__name__]
        said = " ".join(lines[:2]) if lines[0].endswith(":") and len(lines) > 1 else lines[0]
        raise CheckpointError(f"{path}: the weights do not fit the {kind} config ({said})") from None
    digest = hashlib.sha256(Path(path).read_bytes()).hexdigest()  # which weights, for results kept per model
    check_checksum(path, doc, shipped, digest)
    return cfg, nets, {"recipe": doc.get("recipe", {}), "training": doc.get("training", {}), "sha256": digest}


def differences_from_init(started: Any, recipe: Any, names: Sequence[str]) -> str:
    """``width (48 there, 170 here), ...``: each field of ``names`` with its value in the model a
    recipe starts from (``started``) and in the recipe's model."""
    return ", ".join(f"{n} ({getattr(started, n)!r} there, {getattr(recipe, n)!r} here)" for n in names)


def load_init(
    init: str, export: str | os.PathLike, load: Callable[[Path], tuple[Any, Any, dict]]
) -> tuple[Any, Any, str]:
    """The exported model a run starts from (a recipe's ``init``): ``load(path)``'s config and networks
    and the file's SHA-256 (part of the run's identity: another start is another run). Refused with
    a message naming ``init``: a missing file, a folder, the run's own ``export`` (which would
    overwrite it) and whatever ``load`` refuses."""
    path = Path(init)
    if path.is_dir():
        raise ValueError(f"init = {init!r} is a folder; give the exported model file (e.g. <work>/model.pt)")
    if path.is_symlink() and not path.exists():
        raise ValueError(f"init = {init!r} is a link to nothing ({os.readlink(path)}); give the exported model file")
    if not path.is_file():
        where = "" if path.is_absolute() else f" (relative to {Path.cwd()})"
        raise ValueError(
            f"init = {init!r}: no such model file{where}; the recipe's comments name the command that makes it"
        )
    if path.resolve() == Path(export).resolve():
        raise ValueError(f"init = {init!r} is this run's --export, which would overwrite it; export elsewhere")
    try:
        model, nets, info = load(path)
    except ValueError as exc:
        said = str(exc).removeprefix(f"{path}: ")  # the message names the file once
        raise ValueError(f"init = {init!r}: {said}") from None
    return model, nets, info["sha256"]
