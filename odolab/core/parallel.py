"""Fan-out of independent work items as Ray tasks: a local Ray instance by default, the user's
cluster when given its address. The same call runs serially in-process when asked to (tests,
single items), so results never depend on where they were computed.
"""

from __future__ import annotations

import contextlib
import logging
import os
import re
import signal
import socket
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from typing import Any, TypeVar

from tqdm.auto import tqdm

from odolab.core.errors import InputError
from odolab.core.memory import children_keep_freed_memory

T = TypeVar("T")


@dataclass(frozen=True)
class Execution:
    """Where and how fan-out work runs: on the Ray cluster at ``ray_address`` (None: a local
    instance, started when needed), or serially in this process when ``parallel`` is False (tests,
    debugging); ``progress``: show progress bars. Results never depend on it."""

    ray_address: str | None = None
    parallel: bool = True
    progress: bool = True


#: In this process, without progress bars (tests, work inside a task).
SERIAL = Execution(parallel=False, progress=False)

#: Seconds to wait for a cluster's address to accept a connection before giving up.
CONNECT_TIMEOUT = 3.0
_ADDRESS = re.compile(r"^(?:ray://)?(?P<host>\[[0-9A-Fa-f:.]+\]|[A-Za-z0-9._-]+):(?P<port>[0-9]{1,5})$")


class RayAddressError(InputError):
    """A Ray cluster address that is malformed, or where no cluster answers (``problem`` names the
    address). Its ``str()`` begins with its ``subject``: ``--ray-address``, or :data:`ENVIRONMENT`
    for the address in the ``RAY_ADDRESS`` variable (:func:`check_environment_ray_address`); the
    command lines word it with ``named()``."""

    subject = "--ray-address"


#: The environment variable ray.init() connects to when given no address, as it would to --ray-address.
RAY_ADDRESS = "RAY_ADDRESS"
#: The subject of a :class:`RayAddressError` about that variable's address.
ENVIRONMENT = f"{RAY_ADDRESS} (environment)"


def check_ray_address(address: str, timeout: float = CONNECT_TIMEOUT) -> None:
    """Check a Ray cluster address (``host:port``, ``ray://host:port`` or ``auto``) before use:
    malformed, or nothing accepting connections there within ``timeout`` seconds, raises
    :class:`RayAddressError` with one line naming the address (instead of Ray's minutes-long retries)."""
    if address == "auto":
        address = _local_cluster_address()
    match = _ADDRESS.match(address)
    if match is None or not 0 < int(match["port"]) < 65536:
        raise RayAddressError(f"{address!r} is not an address; expected host:port, ray://host:port or auto")
    if address.startswith("ray://") and not has_ray_client():
        raise RayAddressError(
            f"{address}: a ray:// address needs Ray Client, which this installation lacks "
            "(pip install 'ray[client]'); or give the cluster's host:port"
        )
    host = match["host"].strip("[]")
    try:
        with socket.create_connection((host, int(match["port"])), timeout=timeout) as conn:
            grpc = _speaks_grpc(conn)
    except OSError as exc:
        reason = (
            f"no answer within {timeout:g} s" if isinstance(exc, TimeoutError) else (exc.strerror or str(exc)).lower()
        )
        raise RayAddressError(f"{address}: no Ray cluster there ({reason})") from None
    if not grpc:
        raise RayAddressError(
            f"{address}: something answers there, but not as a Ray cluster does (gRPC); give the head "
            "node's GCS address (ray start --head prints it)"
        )


#: An HTTP/2 client's opening: the connection preface and an empty SETTINGS frame.
_HTTP2_OPENING = b"PRI * HTTP/2.0\r\n\r\nSM\r\n\r\n" + bytes([0, 0, 0, 4, 0, 0, 0, 0, 0])


def _speaks_grpc(conn: socket.socket) -> bool:
    """Whether the server on ``conn`` answers an HTTP/2 opening with a SETTINGS frame, as every
    gRPC server (a Ray cluster's GCS, Ray Client's server) does; a web server or a database does
    not. Uses the connection's timeout."""
    conn.sendall(_HTTP2_OPENING)
    head = b""
    with contextlib.suppress(OSError):
        while len(head) < 9:
            chunk = conn.recv(9 - len(head))
            if not chunk:
                break
            head += chunk
    return len(head) == 9 and head[3] == 4  # a frame header: length (3 bytes), type 4 = SETTINGS


def _local_cluster_address() -> str:
    """What ``auto`` means to Ray: the cluster this machine's last ``ray start`` made, or a running
    one found among its processes; :class:`RayAddressError` when there is none (Ray would raise a
    ConnectionError deep in its start-up)."""
    from ray._private.services import get_ray_address_from_environment

    try:
        found = get_ray_address_from_environment("auto", None)
    except ConnectionError:
        found = None
    if not found or found == "auto":
        raise RayAddressError(
            "auto: no running Ray cluster found on this machine; start one (ray start --head) or give host:port"
        )
    return found


def has_ray_client() -> bool:
    """Whether Ray Client, which ``ray://`` addresses need, is installed (Ray's own test: gRPC)."""
    import importlib.util

    return importlib.util.find_spec("grpc") is not None


def check_environment_ray_address(timeout: float = CONNECT_TIMEOUT) -> None:
    """Check the address in the ``RAY_ADDRESS`` variable, if any, as :func:`check_ray_address` checks
    ``--ray-address``: Ray connects there when it is given no address. :class:`RayAddressError`'s
    subject is then :data:`ENVIRONMENT`."""
    address = os.environ.get(RAY_ADDRESS)
    if not address:
        return
    try:
        check_ray_address(address, timeout)
    except RayAddressError as exc:
        raise RayAddressError(exc.problem, exc.joiner, subject=ENVIRONMENT) from None


#: The logger of Ray's token-authentication notices (warnings printed as ``ray.init`` starts).
_TOKEN_NOTICES = "ray._private.authentication.authentication_token_setup"


def _errors_only(record: logging.LogRecord) -> bool:
    """A logging filter that keeps only errors."""
    return record.levelno >= logging.ERROR


@contextlib.contextmanager
def _signal_handlers_kept() -> Iterator[None]:
    """Put back this process's SIGINT and SIGTERM handlers after the block: ``ray.init`` replaces
    SIGTERM's with one that exits at once, so a command's own handling (clean-up, exit 143,
    :func:`odolab.cli.run_cli`) would be lost for the rest of the run."""
    if threading.current_thread() is not threading.main_thread():  # only the main thread has handlers
        yield
        return
    kept = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    put_back = False
    try:
        yield
    except SystemExit as exc:  # Ray's handler, in place during ray.init, turns SIGTERM into exit(15)
        if exc.code != signal.SIGTERM:
            raise
        put_back = True
    finally:
        for sig, handler in kept.items():
            if handler is not None:  # None: set outside Python, cannot be put back
                signal.signal(sig, handler)
    if put_back:  # the SIGTERM Ray's handler took goes to the handler that was there before
        signal.raise_signal(signal.SIGTERM)
        raise SystemExit(128 + signal.SIGTERM)  # that handler ignored it: the run cannot go on half-started


@contextlib.contextmanager
def _token_notices_hidden(local: bool, quiet: bool) -> Iterator[None]:
    """Hide Ray's token-authentication notices while a Ray instance starts, when it is a local
    instance odolab starts for itself (the user started no cluster, so the notice is noise) or the
    user asked for quiet; a user's own cluster keeps them. Errors always pass."""
    if not (local or quiet):
        yield
        return
    notices = logging.getLogger(_TOKEN_NOTICES)
    notices.addFilter(_errors_only)
    try:
        yield
    finally:
        notices.removeFilter(_errors_only)


def shutdown_ray() -> None:
    """``ray.shutdown()``, then this process's SIGTERM and SIGINT handlers installed again: Ray's
    shutdown resets SIGTERM to the default action beneath Python (which still reports its own
    handler), so a SIGTERM after it would end a command at once, without its clean-up or its line."""
    import ray

    try:
        ray.shutdown()
    finally:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                handler = signal.getsignal(sig)
                if handler is not None:  # None: set outside Python, cannot be put back
                    signal.signal(sig, handler)


def start_ray(ray_address: str | None, quiet: bool = False, log_to_driver: bool = False) -> bool:
    """Connect to the cluster at ``ray_address`` (None: the one ``RAY_ADDRESS`` names, if any; either
    checked first, :func:`check_ray_address`) or start a local instance, unless Ray is already running
    in this process; returns whether it started it (the caller then shuts it down). This process's
    signal handlers stay as they were."""
    import ray

    if ray.is_initialized():
        return False
    if ray_address is not None:
        check_ray_address(ray_address)
    else:  # ray.init() would connect to RAY_ADDRESS: a dead one hangs it, a malformed one is a traceback
        check_environment_ray_address()
    local = ray_address is None and not os.environ.get(RAY_ADDRESS)
    try:
        with (
            _signal_handlers_kept(),
            _token_notices_hidden(local=local, quiet=quiet),
            children_keep_freed_memory() if local else contextlib.nullcontext(),  # the workers' malloc
        ):
            # "local": a new instance of this process's own, never a `ray start` cluster found on the machine
            # (ray.init() without an address joins one, and its owner may stop it mid-run)
            address = ray_address or ("local" if local else None)
            ray.init(address=address, include_dashboard=False, log_to_driver=log_to_driver, configure_logging=False)
    except BaseException as exc:  # interrupted or refused half-way: stop what it started
        with contextlib.suppress(Exception):
            shutdown_ray()
        address = ray_address or os.environ.get(RAY_ADDRESS)
        if isinstance(exc, ConnectionError) and address:  # a gRPC server that is no Ray cluster's
            said = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
            subject = RayAddressError.subject if ray_address else ENVIRONMENT
            raise RayAddressError(f"{address}: Ray could not connect there ({said})", subject=subject) from None
        raise
    return True


def start_ray_beside(
    work: Callable[[threading.Event], T], ray_address: str | None = None, quiet: bool = False
) -> tuple[T, bool]:
    """:func:`start_ray` in this thread while ``work(up)`` runs on another: the driver's own work
    done during Ray's few seconds of start (mostly waiting for its processes). ``up`` is set once
    the start has ended (Ray up, or the start failed), so ``work`` may stop early then. Returns
    ``work``'s result and whether Ray was started here (the caller then shuts it down); raises, once
    ``work`` has ended, what the start raised, else what ``work`` raised (Ray, where started here,
    shut down again). Where Ray runs already, ``work`` runs here with ``up`` set."""
    from concurrent.futures import ThreadPoolExecutor

    import ray

    up = threading.Event()
    if ray.is_initialized():
        up.set()
        return work(up), False
    with ThreadPoolExecutor(max_workers=1, thread_name_prefix="odolab-beside-ray") as pool:
        done = pool.submit(work, up)
        try:
            started = start_ray(ray_address, quiet=quiet)
        finally:
            up.set()
        try:
            return done.result(), started
        except BaseException:
            if started:
                shutdown_ray()
            raise


def _resolved(value: Any) -> Any:
    """``value``, or what it refers to where it is a Ray object reference."""
    if type(value).__name__ == "ObjectRef":
        import ray

        return _value(ray, value)
    return value


def _value(ray, ref) -> Any:
    """``ray.get(ref)``; a task's ``ValueError`` or ``OSError`` (bad input met in the task, such as
    a mesh file changed meanwhile) raised as itself, as in this process, not wrapped in Ray's
    traceback."""
    try:
        return ray.get(ref)
    except ray.exceptions.RayTaskError as exc:
        if isinstance(exc.cause, (ValueError, OSError)):
            raise exc.cause from None
        raise


def fan_out(
    fn: Callable[[Any], Any],
    items: Sequence[Any],
    *,
    on_result: Callable[[int, Any], None] | None = None,
    execution: Execution = Execution(),
    desc: str = "tasks",
    gpus: float | Callable[[int], float] = 0.0,
    inputs: Sequence[Any] | None = None,
    then: Callable[[int, Any], Sequence[Any]] | None = None,
) -> list[Any]:
    """``[fn(item) for item in items]``, as Ray tasks when ``execution.parallel`` and there are 2+ items
    (or ``then`` is given).

    ``inputs``: per item a second argument, ``fn(item, inputs[k])``; a Ray object reference there (a
    task submitted earlier) is resolved first, so the item's task waits for it and no sooner.

    ``gpus``: GPUs each Ray task asks for (Ray then makes only its GPUs visible to it; 0: none asked,
    and a task sees whatever GPUs its node has), or a function of the item's index giving them;
    :class:`RayAddressError` naming the cluster's GPU count when it has fewer (the task would wait for
    ever). In this process (serial) it has no effect.

    ``then(k, result)``: the further items that item ``k``'s result makes possible (say, evaluations of
    a model just trained), called in the driver after ``on_result``; they are computed by ``fn`` too,
    queued behind every item submitted before them (so they fill cores that earlier, longer items leave
    idle), with the indices that follow on (the bar's total grows). Not with ``inputs``.

    ``on_result(k, result)`` is called in the driver as each item finishes (in completion order),
    e.g. to write it to disk at once so finished work survives an interruption; results are then
    handed to it and not kept (the returned list holds None), so large results can stream.
    ``execution.ray_address``: None starts (or reuses) a local instance; otherwise e.g.
    "ray://host:10001" (checked first by :func:`check_ray_address`: :class:`RayAddressError` within
    seconds if unreachable).
    """
    from odolab.core.progress import plain_terminal

    if then is not None and inputs is not None:
        raise ValueError("fan_out: then and inputs cannot be given together")
    parallel, ray_address, progress = execution.parallel, execution.ray_address, execution.progress
    queue = list(items)  # grows with what ``then`` adds
    results: list[Any] = [None] * len(queue)
    plain = bool(progress and queue) and plain_terminal()  # a terminal that cannot draw a bar: two lines
    bar = tqdm(total=len(queue), desc=desc, disable=not progress or not queue or plain, leave=False)
    if plain:
        print(f"{desc}: {len(queue)} to run", file=sys.stderr, flush=True)
        began = time.perf_counter()

    def done(k: int, value: Any) -> list[int]:
        """Hand item ``k``'s result on; the indices of the items it adds."""
        if on_result:
            on_result(k, value)
        else:
            results[k] = value
        bar.update(1)
        more = list(then(k, value)) if then is not None else []
        if more:
            queue.extend(more)
            results.extend([None] * len(more))
            bar.total = len(queue)
            bar.refresh()
        return list(range(len(queue) - len(more), len(queue)))

    def args(k: int) -> tuple[Any, ...]:
        return (queue[k],) if inputs is None else (queue[k], inputs[k])

    try:
        if not parallel or not queue or (len(queue) < 2 and then is None):
            k = 0
            while k < len(queue):
                done(k, fn(*(_resolved(a) for a in args(k))))
                k += 1
            return results
        import ray

        started = start_ray(ray_address, quiet=not progress)
        try:
            task = ray.remote(fn)
            have = None

            def submit(k: int) -> Any:
                nonlocal have
                asked = float(gpus(k) if callable(gpus) else gpus)
                if asked <= 0:
                    return task.remote(*args(k))
                if have is None:
                    have = ray.cluster_resources().get("GPU", 0.0)
                if have < asked:
                    raise RayAddressError(
                        f"has {have:g} GPUs; each task asks for {asked:g} (run where there are GPUs, or ask for none)",
                        subject=ray_address or "the local Ray instance",
                    )
                return task.options(num_gpus=asked).remote(*args(k))

            pending = {submit(k): k for k in range(len(queue))}
            while pending:
                ready, _ = ray.wait(list(pending), num_returns=1)
                for ref in ready:
                    k = pending.pop(ref)
                    for new in done(k, _value(ray, ref)):
                        pending[submit(new)] = new
        finally:
            if started:  # a local instance's daemons would otherwise slow the timed work that follows
                shutdown_ray()
        return results
    finally:
        bar.close()
        if plain and sys.exc_info()[0] is None:
            print(f"{desc}: {len(queue)} done in {time.perf_counter() - began:.0f} s", file=sys.stderr, flush=True)
