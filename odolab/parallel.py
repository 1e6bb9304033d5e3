"""Fan-out of independent work items as Ray tasks: a local Ray instance by default, the user's
cluster when given its address. The same call runs serially in-process when asked to (tests,
single items), so results never depend on where they were computed.
"""
from __future__ import annotations

from typing import Any, Callable, Sequence

from tqdm.auto import tqdm


def fan_out(fn: Callable[[Any], Any], items: Sequence[Any], *,
            on_result: Callable[[int, Any], None] | None = None, parallel: bool = True,
            ray_address: str | None = None, progress: bool = True, desc: str = "tasks") -> list[Any]:
    """``[fn(item) for item in items]``, as Ray tasks when ``parallel`` and there are 2+ items.

    ``on_result(k, result)`` is called in the driver as each item finishes (in completion order),
    e.g. to write it to disk at once so finished work survives an interruption; results are then
    handed to it and not kept (the returned list holds None), so large results can stream.
    ``ray_address``: None starts (or reuses) a local instance; otherwise e.g. "ray://host:10001".
    """
    results: list[Any] = [None] * len(items)
    bar = tqdm(total=len(items), desc=desc, disable=not progress or not items, leave=False)

    def done(k: int, value: Any) -> None:
        if on_result:
            on_result(k, value)
        else:
            results[k] = value
        bar.update(1)

    try:
        if not parallel or len(items) < 2:
            for k, item in enumerate(items):
                done(k, fn(item))
            return results
        import ray

        started = not ray.is_initialized()
        if started:
            ray.init(address=ray_address, include_dashboard=False, log_to_driver=False,
                     configure_logging=False)
        try:
            task = ray.remote(fn)
            pending = {task.remote(item): k for k, item in enumerate(items)}
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    done(pending.pop(ref), ray.get(ref))
        finally:
            if started:  # a local instance's daemons would otherwise slow the timed work that follows
                ray.shutdown()
        return results
    finally:
        bar.close()
