"""glibc's malloc told to keep freed memory for reuse, in odolab's processes and the Ray workers they start.

With glibc's defaults a block above the mmap threshold (128 KiB, raised as large blocks are freed,
never above 32 MiB) is mapped from the system on each allocation and unmapped on free, and free
memory at the heap's top is handed back above the trim threshold; every such allocation then
faults its pages in again, zeroed by the kernel. A step of the robust VO allocates a few dozen
blocks of 0.1-10 MiB (activations, psi, the warp) of changing sizes, so a process that has not yet
freed larger ones (a Ray worker reading cached episodes) spends a good part of each step on page
faults (docs/results.md#speed). Where memory is allocated changes no computed value.

A user's own settings win: nothing is changed where ``MALLOC_MMAP_THRESHOLD_``,
``MALLOC_TRIM_THRESHOLD_`` or ``GLIBC_TUNABLES`` is set in the environment.
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import platform
from collections.abc import Iterator

__all__ = ["ENVIRONMENT", "MMAP_THRESHOLD", "TRIM_THRESHOLD", "children_keep_freed_memory", "keep_freed_memory"]

#: Blocks up to this size come from the heap and are reused after free (glibc's largest allowed), bytes.
MMAP_THRESHOLD = 32 << 20
#: Free memory at the heap's top kept for reuse up to this much, bytes.
TRIM_THRESHOLD = 256 << 20
#: The same settings as environment variables, read by glibc as a process starts.
ENVIRONMENT = {"MALLOC_MMAP_THRESHOLD_": str(MMAP_THRESHOLD), "MALLOC_TRIM_THRESHOLD_": str(TRIM_THRESHOLD)}

_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3  # mallopt's parameter numbers (malloc.h)


def _user_settings() -> bool:
    """Whether the environment holds malloc settings of the user's own."""
    return any(name in os.environ for name in (*ENVIRONMENT, "GLIBC_TUNABLES"))


def keep_freed_memory() -> bool:
    """Set this process's malloc thresholds (:data:`MMAP_THRESHOLD`, :data:`TRIM_THRESHOLD`) with
    glibc's ``mallopt``; whether they were set (False: not glibc, the user's own settings in the
    environment, or refused)."""
    if platform.system() != "Linux" or platform.libc_ver()[0] != "glibc" or _user_settings():
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    mallopt.argtypes, mallopt.restype = (ctypes.c_int, ctypes.c_int), ctypes.c_int
    return bool(mallopt(_M_MMAP_THRESHOLD, MMAP_THRESHOLD)) and bool(mallopt(_M_TRIM_THRESHOLD, TRIM_THRESHOLD))


@contextlib.contextmanager
def children_keep_freed_memory() -> Iterator[None]:
    """Processes started inside the block (a local Ray instance's daemons, whose workers inherit
    their environment) start with :data:`ENVIRONMENT`; this process's environment is as it was
    afterwards. Nothing changes where the user set malloc settings of their own."""
    if _user_settings():
        yield
        return
    os.environ.update(ENVIRONMENT)
    try:
        yield
    finally:
        for name in ENVIRONMENT:
            os.environ.pop(name, None)
