"""What a figure was measured on: the machine description every benchmark and study records."""

from __future__ import annotations

import os
import platform

__all__ = ["machine"]

#: CPU flags (Linux ``/proc/cpuinfo``) that say the CPU computes bf16 natively.
BF16_FLAGS = ("avx512_bf16", "amx_bf16", "bf16")


def machine() -> dict:
    """What the figures were measured on: CPU count, processor, CPU model (name, and on Linux its
    family and model numbers), whether it has native bf16 (None where unknown) and Python version."""
    info = _cpuinfo()
    flags = set((info.get("flags") or info.get("Features") or "").split())
    return {
        "cpus": os.cpu_count(),
        "processor": platform.processor() or platform.machine(),
        "cpu_model": info.get("model name", "unknown"),
        "cpu_family_model": f"{info['cpu family']}/{info['model']}" if "cpu family" in info and "model" in info else "",
        "native_bf16": bool(flags & set(BF16_FLAGS)) if flags else None,
        "python": platform.python_version(),
    }


def _cpuinfo() -> dict[str, str]:
    """The first processor's fields in Linux ``/proc/cpuinfo`` (empty elsewhere): ratios differ
    between CPUs."""
    fields: dict[str, str] = {}
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if not line.strip():
                    if fields:
                        break
                    continue
                key, _, value = line.partition(":")
                fields.setdefault(key.strip(), value.strip())
    except OSError:
        pass
    return fields
