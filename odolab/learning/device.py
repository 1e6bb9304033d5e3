"""Where a model runs: a GPU when one is present, else the CPU."""

from __future__ import annotations

import torch


def pick_device(name: str | None = None) -> torch.device:
    """``torch.device(name)`` if given (``ValueError`` when it is not available), else ``cuda`` when
    a CUDA GPU is present, ``mps`` on Apple silicon, otherwise ``cpu``."""
    if name:
        try:
            device = torch.device(name)
        except RuntimeError as exc:
            raise ValueError(f"device {name!r} is not a torch device ({exc})") from None
        if device.type not in ("cpu", "cuda", "mps"):
            raise ValueError(f"device {name!r}: expected cpu, cuda, cuda:N or mps")
        if device.type == "cuda" and not torch.cuda.is_available():
            raise ValueError(f"device {name!r} asked for but no CUDA GPU is available")
        if device.type == "mps" and not (getattr(torch.backends, "mps", None) and torch.backends.mps.is_available()):
            raise ValueError(f"device {name!r} asked for but Apple's MPS is not available")
        return device
    if torch.cuda.is_available():
        return torch.device("cuda")
    if getattr(torch.backends, "mps", None) is not None and torch.backends.mps.is_available():
        return torch.device("mps")
    return torch.device("cpu")
