"""Where a model runs: a GPU when one is present, else the CPU."""

from __future__ import annotations

import os
import re

import torch

#: The device names :func:`pick_device` takes.
DEVICE_NAME = re.compile(r"cpu|mps|cuda(?::(\d+))?")


def pick_device(name: str | None = None) -> torch.device:
    """``torch.device(name)`` for ``name`` cpu, cuda, cuda:N or mps (``ValueError`` for another name
    or one this machine lacks); for None, ``cuda`` when a CUDA GPU is present, ``mps`` on Apple
    silicon, otherwise ``cpu``."""
    if name is not None:
        form = DEVICE_NAME.fullmatch(name)
        if form is None:
            raise ValueError(f"device {name!r}: expected cpu, cuda, cuda:N or mps")
        device = torch.device(name)
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"device {name!r} asked for but no CUDA GPU is available")
        if form.group(1) is not None and int(form.group(1)) >= torch.cuda.device_count():
            n = torch.cuda.device_count()
            names = "cuda:0" if n == 1 else f"cuda:0 to cuda:{n - 1}"
            raise ValueError(f"device {name!r}: this machine has {n} CUDA GPU{'s' if n != 1 else ''} ({names})")
        if device.type == "mps" and not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
            raise ValueError(f"device {name!r} asked for but Apple's MPS is not available")
        return device
    if torch.cuda.is_available():
        return torch.device("cuda")
    if getattr(torch.backends, "mps", None) is not None and torch.backends.mps.is_available():
        return torch.device("mps")
    return torch.device("cpu")


def set_threads(threads: int) -> None:
    """Have torch use ``threads`` CPU threads in this process."""
    torch.set_num_threads(threads)


def local_ray_resources() -> tuple[float, float]:
    """The CPUs and GPUs a local Ray instance started here would have (Ray's own count of the
    CPUs, which heeds a container's limit; torch's count of the CUDA GPUs)."""
    try:
        from ray._private.utils import get_num_cpus

        cpus = float(get_num_cpus())
    except Exception:  # noqa: BLE001 - a Ray without this helper: the machine's count
        cpus = float(os.cpu_count() or 1)
    return cpus, float(torch.cuda.device_count() if torch.cuda.is_available() else 0)
