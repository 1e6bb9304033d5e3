"""What a figure was measured on: the machine description every benchmark and study records, and the
CPU's feature flags (Linux ``/proc/cpuinfo``) that other choices read."""

from __future__ import annotations

import os
import platform

__all__ = ["BF16_FLAGS", "cpu_flags", "machine"]

#: CPU flags that say the CPU computes bf16 natively (x86 ``avx512_bf16``, ``amx_bf16``; Arm ``bf16``).
BF16_FLAGS = frozenset({"avx512_bf16", "amx_bf16", "bf16"})


def machine() -> dict:
    """What the figures were measured on: CPU count, processor, CPU model (name, and on Linux its
    family and model numbers), whether it has native bf16 (None where unknown) and Python version."""
    text = _read_cpuinfo()
    fields, flags = _first_processor(text), cpu_flags(text)
    known = "cpu family" in fields and "model" in fields
    return {
        "cpus": os.cpu_count(),
        "processor": platform.processor() or platform.machine(),
        "cpu_model": fields.get("model name", "unknown"),
        "cpu_family_model": f"{fields['cpu family']}/{fields['model']}" if known else "",
        "native_bf16": bool(flags & BF16_FLAGS) if flags else None,
        "python": platform.python_version(),
    }


def cpu_flags(cpuinfo: str | None = None) -> set[str]:
    """The CPU feature flags Linux reports (``flags`` on x86, ``Features`` on Arm); empty where
    ``/proc/cpuinfo`` is not readable. ``cpuinfo``: its text, for tests."""
    flags: set[str] = set()
    for line in (_read_cpuinfo() if cpuinfo is None else cpuinfo).splitlines():
        key, _, value = line.partition(":")
        if key.strip() in ("flags", "Features"):
            flags.update(value.split())
    return flags


def _read_cpuinfo() -> str:
    """The text of Linux ``/proc/cpuinfo`` (empty elsewhere): ratios differ between CPUs."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            return f.read()
    except OSError:
        return ""


def _first_processor(cpuinfo: str) -> dict[str, str]:
    """The first processor's ``key: value`` fields of a ``/proc/cpuinfo`` text."""
    fields: dict[str, str] = {}
    for line in cpuinfo.splitlines():
        if not line.strip():
            if fields:
                break
            continue
        key, _, value = line.partition(":")
        fields.setdefault(key.strip(), value.strip())
    return fields
