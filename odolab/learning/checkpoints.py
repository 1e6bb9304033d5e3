"""Checkpoints as plain data: ``{"format": ..., "kind": ..., ...}`` of tensors, numbers, strings,
lists and dicts, written atomically and read with ``torch.load(weights_only=True)`` (no pickled code
is ever executed)."""
from __future__ import annotations

import io
import os
import pickle
import zipfile
from typing import Any

import torch

from odolab.io.atomic import write_bytes_atomic


class CheckpointError(ValueError):
    """A file that is not a checkpoint of the expected kind and format (the message names it)."""


def save_checkpoint(path: str | os.PathLike, kind: str, format: int, doc: dict[str, Any]) -> None:
    """Write ``doc`` (plain data and tensors) tagged with ``kind`` and ``format``, atomically."""
    buffer = io.BytesIO()
    torch.save({"kind": kind, "format": format, **doc}, buffer)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    write_bytes_atomic(path, buffer.getvalue())


def load_checkpoint(path: str | os.PathLike, kind: str, format: int) -> dict[str, Any]:
    """Read a checkpoint written by :func:`save_checkpoint`; :class:`CheckpointError` names the file
    and what is wrong (missing, unreadable, unsafe content, another kind or format)."""
    if not os.path.isfile(path):
        raise CheckpointError(f"{path}: no such checkpoint file")
    try:
        doc = torch.load(path, map_location="cpu", weights_only=True)
    except (pickle.UnpicklingError, RuntimeError, EOFError, zipfile.BadZipFile, OSError, ValueError) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise CheckpointError(f"{path}: not a readable torch checkpoint ({first})") from None
    if not isinstance(doc, dict) or doc.get("kind") != kind:
        got = doc.get("kind") if isinstance(doc, dict) else type(doc).__name__
        raise CheckpointError(f"{path}: expected a {kind!r} checkpoint, got {got!r}")
    if doc.get("format") != format:
        raise CheckpointError(f"{path}: {kind} checkpoint of format {doc.get('format')!r}; this odolab reads format {format}")
    return doc
