"""A benchmark's timed child command: run to its end, its interruption passed on to it."""

from __future__ import annotations

import signal
import subprocess
import time

#: Seconds an interrupted child is given for its clean-up (Ray's shutdown, temporary folders) before it is killed.
CLEAN_UP_S = 60.0


class CommandFailed(RuntimeError):
    """A timed command that exited with another code than 0; its ``str()`` is one line."""


def timed_command(command: list[str], capture_stderr: bool = False) -> float:
    """Wall seconds of ``command`` from its start to its exit (its stdout discarded; its stderr
    passed through, or with ``capture_stderr`` kept for the error's line). The child runs in a
    session of its own, so a terminal's Ctrl-C reaches this process only: when that, or a SIGTERM,
    interrupts the wait, the child is sent the same signal once and given :data:`CLEAN_UP_S` to clean
    up before it is killed, then the interruption goes on. :class:`CommandFailed` when it exits
    with another code than 0."""
    stderr = subprocess.PIPE if capture_stderr else None
    started = time.perf_counter()
    child = subprocess.Popen(command, stdout=subprocess.DEVNULL, stderr=stderr, text=True, start_new_session=True)
    try:
        _, said = child.communicate()
    except BaseException as exc:
        child.send_signal(signal.SIGINT if isinstance(exc, KeyboardInterrupt) else signal.SIGTERM)
        try:
            child.wait(timeout=CLEAN_UP_S)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait()
        raise
    elapsed = time.perf_counter() - started
    if child.returncode != 0:
        last = (said or "").strip().splitlines()[-1:] or ["its message is above"]
        name = f"python -m {command[2]}" if command[1:2] == ["-m"] else command[0]
        raise CommandFailed(f"{name} exited with {child.returncode}: {last[0]}")
    return elapsed
