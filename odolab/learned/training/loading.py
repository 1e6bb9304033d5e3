"""Batches made ahead of the training step: worker processes, or one thread of the training
process, prepare the next batches (shard reads, input transforms) while the network computes, so
loading is not the bottleneck."""

from __future__ import annotations

from collections import deque
from collections.abc import Callable, Iterable, Iterator
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

from torch.utils.data import DataLoader, Dataset


class BatchList(Dataset):
    """Item ``k`` is ``make(parts[k])``: one whole batch per item (a map-style dataset)."""

    def __init__(self, parts: list[Any], make: Callable[[Any], Any]) -> None:
        self.parts, self.make = parts, make

    def __len__(self) -> int:
        return len(self.parts)

    def __getitem__(self, k: int) -> Any:
        return self.make(self.parts[k])


def prefetched(
    parts: list[Any], make: Callable[[Any], Any], workers: int = 1, ahead: int = 2, thread: bool = False
) -> Iterable[Any]:
    """``make(p)`` for each ``p`` of ``parts``, in order. With ``workers`` > 0 they are made in that
    many worker processes (torch's DataLoader, one torch thread each), up to ``ahead`` batches per
    worker in advance; 0 makes them in this process: with ``thread``, in one thread beside the
    caller, up to ``ahead`` in advance (numpy and torch release the GIL while they compute); without,
    here, on demand, after ``make.advise(part)`` (where ``make`` has it) told the data which part
    comes ``ahead`` batches later, so its reads overlap the computing. ``make`` and its closure must
    pickle where the platform spawns processes (Linux forks)."""
    if workers <= 0 or len(parts) <= 1:
        return _threaded(parts, make, ahead) if thread and len(parts) > 1 else _here(parts, make, ahead)
    return _Loader(
        DataLoader(
            BatchList(parts, make),
            batch_size=None,
            shuffle=False,
            num_workers=workers,
            prefetch_factor=ahead,
            persistent_workers=False,
            collate_fn=_keep,
        )
    )


def _threaded(parts: list[Any], make: Callable[[Any], Any], ahead: int) -> Iterator[Any]:
    """``make(p)`` made in order by one thread, at most ``ahead`` results waiting; before making a
    part the thread advises the reads of the part ``ahead`` after it (as :func:`_here`), so only that
    thread touches the data. Abandoning the iteration cancels what was not started and waits for
    the one being made."""
    advise = getattr(make, "advise", None)

    def advised(k: int) -> Any:
        if advise is not None and k + ahead < len(parts):
            advise(parts[k + ahead])
        return make(parts[k])

    pool = ThreadPoolExecutor(max_workers=1, thread_name_prefix="odolab-batches")
    waiting: deque[Future] = deque()
    try:
        if advise is not None:
            pool.submit(lambda: [advise(p) for p in parts[:ahead]])
        for k in range(len(parts)):
            waiting.append(pool.submit(advised, k))
            if len(waiting) > ahead:
                yield waiting.popleft().result()
        while waiting:
            yield waiting.popleft().result()
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _here(parts: list[Any], make: Callable[[Any], Any], ahead: int) -> Iterator[Any]:
    advise = getattr(make, "advise", None)
    if advise is not None:
        for p in parts[:ahead]:
            advise(p)
    for k, p in enumerate(parts):
        if advise is not None and k + ahead < len(parts):
            advise(parts[k + ahead])
        yield make(p)


def _keep(item: Any) -> Any:
    return item


class _Loader:
    """A DataLoader iterated once, its workers shut down when iteration ends or is abandoned."""

    def __init__(self, loader: DataLoader) -> None:
        self.loader = loader

    def __iter__(self) -> Iterator[Any]:
        it = iter(self.loader)
        try:
            yield from it
        finally:
            shutdown = getattr(it, "_shutdown_workers", None)
            if shutdown is not None:
                shutdown()
