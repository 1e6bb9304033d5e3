"""How a training step runs on its device: the numeric precision (fp32, or bf16 autocast) and the
memory format of the network's inputs, chosen per machine.

``auto`` picks bf16 autocast only where the hardware computes bf16 natively (x86 CPUs with
``avx512_bf16`` or ``amx_bf16``, Arm CPUs with ``bf16``, CUDA GPUs that support it) and fp32
elsewhere; emulated bf16 is slower than fp32. ``auto`` keeps the default contiguous memory layout
(``channels_last`` is there to be asked for and timed: docs/training.md).
"""

from __future__ import annotations

import contextlib
import dataclasses
import platform
from collections.abc import Callable, Iterable
from dataclasses import dataclass
from typing import Any, Literal, get_args

import torch

from odolab.config import check, setting
from odolab.core.machine import BF16_FLAGS, cpu_flags
from odolab.learned.training.loading import prefetched

Precision = Literal["auto", "fp32", "bf16"]
MemoryFormat = Literal["auto", "contiguous", "channels_last"]
LoaderThread = Literal["auto", "on", "off"]
PRECISIONS: tuple[str, ...] = get_args(Precision)
MEMORY_FORMATS: tuple[str, ...] = get_args(MemoryFormat)
#: Most batch-making processes a recipe may ask for.
MAX_LOADER_WORKERS = 64


def native_bf16(device: torch.device, flags: set[str] | None = None) -> bool:
    """Whether ``device`` computes bf16 natively (see the module docstring)."""
    if device.type == "cuda":
        return bool(torch.cuda.is_available() and torch.cuda.is_bf16_supported())
    if device.type != "cpu":
        return False
    flags = cpu_flags() if flags is None else flags
    return bool(BF16_FLAGS & flags)


@dataclass(frozen=True)
class Compute:
    """The resolved choice: ``device``, ``precision`` (``fp32`` or ``bf16``) and ``memory_format``
    (``contiguous`` or ``channels_last``)."""

    device: torch.device
    precision: str
    memory_format: str
    loader_workers: int = 0
    loader_thread: bool = False

    def autocast(self) -> contextlib.AbstractContextManager:
        """The autocast context of a forward pass (a no-op in fp32)."""
        if self.precision == "bf16":
            return torch.autocast(self.device.type, dtype=torch.bfloat16)
        return contextlib.nullcontext()

    def inputs(self, x: torch.Tensor) -> torch.Tensor:
        """``x`` (B, C, H, W) on the device in the chosen memory format."""
        x = x.to(self.device, non_blocking=True)
        return x.contiguous(memory_format=torch.channels_last) if self.memory_format == "channels_last" else x

    def prepare(self, module: torch.nn.Module) -> torch.nn.Module:
        """``module`` moved to the device in the chosen memory format (in place; returned)."""
        module.to(self.device)
        if self.memory_format == "channels_last":
            module.to(memory_format=torch.channels_last)
        return module

    def batches(self, parts: list[Any], make: Callable[[Any], Any]) -> Iterable[Any]:
        """``make(p)`` for each ``p`` of ``parts``, in order, made ahead of the step as this compute
        says (:func:`odolab.learned.training.loading.prefetched`)."""
        return prefetched(parts, make, self.loader_workers, thread=self.loader_thread)

    def describe(self) -> dict[str, str]:
        """Plain data for reports."""
        return {
            "device": str(self.device),
            "precision": self.precision,
            "memory_format": self.memory_format,
            "loader_workers": self.loader_workers,
            "loader_thread": self.loader_thread,
            "machine": " ".join(dict.fromkeys(n for n in (platform.machine(), platform.processor()) if n)),
        }


@dataclass(frozen=True)
class ComputeConfig:
    """A recipe's ``[compute]`` table: ``precision`` and ``memory_format`` (``auto``: the module
    docstring's rule), ``loader_workers``, processes that make batches ahead of the step (0: in
    the training process; ``auto``: 0 on a GPU, where the GPU makes the network inputs from the
    frames read in the training process, and on a machine of at most 2 cores, where a worker only
    competes with the network for them and costs a copy of every batch, else 1) and
    ``loader_thread``, whether the training process makes them in a thread beside the step rather
    than between steps (``on`` means no worker; ``auto``: off: on 2 cores the thread and the
    network's step compete for them, and on an H200 it overlapped no better; ``python -m
    odolab.bench --only training``). None of it is part of a run's identity: a run resumes on
    another machine with that machine's choice."""

    precision: Precision = setting("auto", doc="numeric precision of a step (auto: bf16 where native, else fp32)")
    memory_format: MemoryFormat = setting("auto", doc="memory layout of the inputs (auto: contiguous)")
    loader_workers: int | Literal["auto"] = setting(
        "auto",
        range=(0, MAX_LOADER_WORKERS),
        doc="processes making batches ahead of the step (auto: 0 on a GPU or on <= 2 cores, else 1)",
    )
    loader_thread: LoaderThread = setting(
        "auto", doc="with no loader worker, make batches in a thread beside the step (auto: off)"
    )

    def __post_init__(self) -> None:
        check(self)
        if self.loader_thread == "on" and self.loader_workers not in ("auto", 0):
            raise ValueError(
                f"loader_thread 'on' makes the batches in the training process: expected loader_workers 0 "
                f"or 'auto' with it, got {self.loader_workers}"
            )

    def resolve(self, device: torch.device, cores: int | None = None) -> Compute:
        """The :class:`Compute` of this config on ``device`` (``cores``: the machine's, by default
        ``os.cpu_count()``)."""
        import os

        workers = self.loader_workers
        if workers == "auto":
            few = (cores or os.cpu_count() or 1) <= 2
            workers = 0 if self.loader_thread == "on" or device.type != "cpu" or few else 1
        return dataclasses.replace(
            choose_compute(device, self.precision, self.memory_format),
            loader_workers=workers,
            loader_thread=self.loader_thread == "on",
        )


def choose_compute(
    device: torch.device, precision: str = "auto", memory_format: str = "auto", flags: set[str] | None = None
) -> Compute:
    """Resolve ``auto`` choices for ``device`` (module docstring); an explicit ``bf16`` is honoured
    even where it is emulated. ``ValueError`` for an unknown name."""
    if precision not in PRECISIONS:
        raise ValueError(f"precision must be one of {', '.join(PRECISIONS)}, got {precision!r}")
    if memory_format not in MEMORY_FORMATS:
        raise ValueError(f"memory_format must be one of {', '.join(MEMORY_FORMATS)}, got {memory_format!r}")
    if precision == "auto":
        precision = "bf16" if native_bf16(device, flags) else "fp32"
    if memory_format == "auto":
        memory_format = "contiguous"
    return Compute(device, precision, memory_format)
