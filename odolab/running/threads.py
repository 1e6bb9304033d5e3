"""How many threads an odometer's torch work may use while it runs (two cores, shared with Open3D).

torch and Open3D each keep an OpenMP thread pool whose idle threads spin for a while after each
parallel region. On a 2-core machine a torch odometer left at torch's default pool (one thread
per core) would keep both cores busy between its own calls and slow whatever runs next. The
runner therefore enters :func:`odometer_threads` around each odometer's sequence: an odometer
that declares ``threads = k`` runs with ``torch.set_num_threads(k)``, and the previous setting is
restored before the next odometer runs, so one odometer's choice never leaks into another's
timing. Odometers that do not declare ``threads`` (all classical ones) leave torch alone; the
simulator avoids BLAS calls next to Open3D work for the same reason (see :mod:`odolab.sim.camera`).
torch is never imported here: only odometers that already imported it are affected.
"""

from __future__ import annotations

import contextlib
import sys
from collections.abc import Iterator

from odolab.odometry.odometer import Odometer
from odolab.odometry.options import whole_number

__all__ = ["MAX_THREADS", "check_threads", "odometer_threads", "torch_threads"]

#: The most torch threads an odometer may ask for (far above any core count here; torch itself
#: crashes the process on absurd values such as 100000).
MAX_THREADS = 256


def check_threads(value: object) -> int:
    """An odometer's ``threads`` option as an int in [1, MAX_THREADS]; ``ValueError`` naming it otherwise."""
    return whole_number("threads", value, 1, MAX_THREADS)


@contextlib.contextmanager
def torch_threads(threads: int | None) -> Iterator[None]:
    """Run the block with ``threads`` torch threads (an int >= 1, or None = leave as is), restoring
    the setting afterwards; nothing to do where torch was never imported."""
    torch = sys.modules.get("torch")
    if threads is None or torch is None:
        yield
        return
    before = torch.get_num_threads()
    torch.set_num_threads(min(max(1, int(threads)), MAX_THREADS))
    try:
        yield
    finally:
        torch.set_num_threads(before)


def odometer_threads(odometer: Odometer) -> contextlib.AbstractContextManager[None]:
    """Apply ``odometer.threads`` to torch's pool for the block (:func:`torch_threads`)."""
    return torch_threads(odometer.threads)
