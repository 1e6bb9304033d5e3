"""Batches made ahead of the training step: a worker process prepares the next batches (shard
reads, input transforms) while the network computes, so loading is not the bottleneck."""

from __future__ import annotations

from collections.abc import Callable, Iterable, Iterator
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


def prefetched(parts: list[Any], make: Callable[[Any], Any], workers: int = 1, ahead: int = 2) -> Iterable[Any]:
    """``make(p)`` for each ``p`` of ``parts``, in order. With ``workers`` > 0 they are made in that
    many worker processes (torch's DataLoader, one torch thread each), up to ``ahead`` batches per
    worker in advance; 0 makes them here, on demand, after ``make.advise(part)`` (where ``make`` has
    it) told the data which part comes ``ahead`` batches later, so its reads overlap the computing.
    ``make`` and its closure must pickle where the platform spawns processes (Linux forks)."""
    if workers <= 0 or len(parts) <= 1:
        return _here(parts, make, ahead)
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
