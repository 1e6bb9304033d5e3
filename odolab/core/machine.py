"""What a figure was measured on: the machine description every benchmark and study records."""

from __future__ import annotations

import os
import platform

__all__ = ["machine"]


def machine() -> dict:
    """What the figures were measured on: CPU count, processor, CPU model and Python version."""
    return {
        "cpus": os.cpu_count(),
        "processor": platform.processor() or platform.machine(),
        "cpu_model": _cpu_model(),
        "python": platform.python_version(),
    }


def _cpu_model() -> str:
    """The CPU's model name (Linux ``/proc/cpuinfo``), or ``"unknown"``: ratios differ between CPUs."""
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as f:
            for line in f:
                if line.startswith("model name"):
                    return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return "unknown"
