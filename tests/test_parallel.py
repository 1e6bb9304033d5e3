"""odolab/core/parallel.py: Ray addresses checked before Ray starts (dead, not Ray, from RAY_ADDRESS), the
command's signal handlers kept while Ray starts, the driver's own work beside Ray's start, GPUs per task, and
no token notice for a local Ray."""

from __future__ import annotations

import logging
import os
import subprocess
import sys
import time

import pytest

from odolab.core.parallel import Execution
from tests.helpers import ROOT, run_python


def test_fan_out_checks_the_address_before_starting_ray():
    from odolab.core.parallel import fan_out

    start = time.monotonic()
    with pytest.raises(ValueError, match="no Ray cluster there"):
        fan_out(abs, [1, 2], execution=Execution(ray_address="127.0.0.1:1", progress=False))
    assert time.monotonic() - start < 10


@pytest.mark.slow
def test_tasks_that_ask_for_gpus_get_one_each_or_a_clear_refusal():
    """The ablation study's paper scale asks Ray for a GPU per training unit: Ray then shows each task
    only its GPU; a cluster with fewer GPUs than a task asks for refuses in one line at once instead of
    waiting for ever."""
    import os

    import ray

    from odolab.core.parallel import RayAddressError, fan_out

    quiet = Execution(progress=False)
    visible = ["CUDA_VISIBLE_DEVICES"] * 2  # each task's os.getenv of it
    ray.init(num_cpus=2, num_gpus=1, include_dashboard=False, log_to_driver=False)  # a GPU declared, none there
    try:
        assert fan_out(os.getenv, visible, execution=quiet, gpus=1) == ["0", "0"]  # one after the other
        with pytest.raises(RayAddressError) as info:
            fan_out(os.getenv, visible, execution=quiet, gpus=2)
        assert str(info.value) == (
            "the local Ray instance has 1 GPUs; each task asks for 2 (run where there are GPUs, or ask for none)"
        )
    finally:
        ray.shutdown()


@pytest.mark.slow
def test_starting_ray_keeps_the_commands_signal_handlers(monkeypatch):
    """ray.init() puts in a SIGTERM handler of its own that exits at once; start_ray puts the
    command's back, so SIGTERM still ends a command that fans out on Ray after its clean-up (143)."""
    import signal

    import ray

    from odolab.core.parallel import start_ray

    monkeypatch.delenv("RAY_ADDRESS", raising=False)

    def mine(signum, frame):  # pragma: no cover - never called
        raise AssertionError

    previous = signal.signal(signal.SIGTERM, mine)
    try:
        started = start_ray(None, quiet=True)
        try:
            assert started, "Ray was already running in the test process"
            assert signal.getsignal(signal.SIGTERM) is mine
        finally:
            if started:
                ray.shutdown()
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_a_sigterm_while_ray_starts_reaches_the_commands_handler(monkeypatch):
    """ray.init() puts its own SIGTERM handler (exit 15) in place first thing; a SIGTERM that lands
    before it returns is handed to the command's handler, and what Ray started is shut down."""
    import os
    import signal
    import sys
    import time

    import ray

    from odolab.core.parallel import start_ray

    class Mine(Exception):
        pass

    def mine(signum, frame):
        raise Mine()

    def init(**kwargs):  # what ray.init does with SIGTERM, then a SIGTERM half-way
        signal.signal(signal.SIGTERM, lambda signum, frame: sys.exit(signum))
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(10)

    shut = []
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(ray, "init", init)
    monkeypatch.setattr(ray, "shutdown", lambda: shut.append(True))
    previous = signal.signal(signal.SIGTERM, mine)
    try:
        with pytest.raises(Mine):
            start_ray(None, quiet=True)
        assert signal.getsignal(signal.SIGTERM) is mine
        assert shut == [True]
    finally:
        signal.signal(signal.SIGTERM, previous)


def test_an_address_where_no_ray_cluster_answers_is_one_line_at_once():
    """A web server at --ray-address takes the connection but is no Ray cluster: refused within
    seconds (Ray itself retries for minutes), naming the address."""
    import http.server
    import threading

    from odolab.core.parallel import RayAddressError, check_ray_address

    server = http.server.HTTPServer(("127.0.0.1", 0), http.server.BaseHTTPRequestHandler)
    thread = threading.Thread(target=server.serve_forever, daemon=True)
    thread.start()
    try:
        address = f"127.0.0.1:{server.server_address[1]}"
        with pytest.raises(RayAddressError, match=f"--ray-address {address}: something answers there, but not as a"):
            check_ray_address(address)
    finally:
        server.shutdown()
        server.server_close()


def test_the_library_checks_ray_address_before_ray_init_and_names_it(monkeypatch):
    """Library callers (odolab.api) get the typed error, named after the variable, not a hang."""
    pytest.importorskip("ray")
    from odolab.core.parallel import RayAddressError, start_ray

    monkeypatch.setenv("RAY_ADDRESS", "127.0.0.1:1")
    with pytest.raises(RayAddressError, match=r"^RAY_ADDRESS \(environment\) 127.0.0.1:1: no Ray cluster"):
        start_ray(None)


@pytest.mark.slow
def test_a_local_ray_start_prints_no_token_notice():
    code = (
        "from odolab.core.parallel import Execution, fan_out\n"
        "def neg(x):\n    return -x\n"
        "assert fan_out(neg, [1, 2], execution=Execution(progress=True)) == [-1, -2]\n"
    )
    env = {k: v for k, v in os.environ.items() if k not in ("RAY_AUTH_MODE", "RAY_ADDRESS")}
    proc = subprocess.run(
        [sys.executable, "-c", code], capture_output=True, text=True, cwd=ROOT, env=env, timeout=120, check=False
    )
    assert proc.returncode == 0, proc.stderr[-2000:]
    assert "Token authentication" not in proc.stdout + proc.stderr


def test_token_notices_are_kept_for_a_users_cluster_and_hidden_for_a_local_one(caplog):
    from odolab.core.parallel import _TOKEN_NOTICES, _token_notices_hidden

    notices = logging.getLogger(_TOKEN_NOTICES)
    for local, quiet, shown in ((True, False, False), (False, True, False), (False, False, True)):
        caplog.clear()
        with caplog.at_level(logging.WARNING), _token_notices_hidden(local=local, quiet=quiet):
            notices.warning("Token authentication is enabled for this Ray cluster.")
            notices.error("an error always passes")
        messages = [r.getMessage() for r in caplog.records]
        assert ("Token authentication is enabled for this Ray cluster." in messages) is shown
        assert "an error always passes" in messages
    assert not notices.filters


def test_fan_out_on_a_terminal_that_cannot_draw_a_bar_says_each_stage_in_a_line(monkeypatch, capsys):
    import odolab.core.progress
    from odolab.core.parallel import Execution, fan_out

    monkeypatch.setattr(odolab.core.progress, "plain_terminal", lambda file=None: True)
    assert fan_out(abs, [-1, -2], execution=Execution(parallel=False), desc="episodes") == [1, 2]
    lines = capsys.readouterr().err.splitlines()
    assert lines[0] == "episodes: 2 to run" and lines[1].startswith("episodes: 2 done in ") and len(lines) == 2


def test_fan_out_inputs_reach_each_task_once_the_tasks_they_name_are_done():
    """``inputs`` gives each item a second argument; a Ray reference there is the value of an earlier
    task, which the item's task waits for (in Ray, and read in the serial run alike)."""
    import ray

    from odolab.core.parallel import fan_out

    def _sum(item, extra):  # local functions: Ray pickles them by value
        return item + extra

    def _later(value, seconds):
        time.sleep(seconds)
        return value

    assert fan_out(_sum, [1, 2], inputs=[10, 20], execution=Execution(parallel=False)) == [11, 22]
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        slow = ray.remote(_later).remote(100, 1.0)
        finished = []
        got = fan_out(
            _sum,
            [1, 2, 3],
            inputs=[slow, 5, slow],
            execution=Execution(progress=False),
            on_result=lambda k, v: finished.append((k, v)),
        )
        assert got == [None, None, None] and sorted(finished) == [(0, 101), (1, 7), (2, 103)]
        assert finished[0] == (1, 7)  # the item without a wait is done first
        assert fan_out(_sum, [4], inputs=[ray.remote(_later).remote(1, 0.0)], execution=Execution(progress=False)) == [
            5
        ]
    finally:
        ray.shutdown()


def test_fan_out_then_queues_what_each_result_makes_possible_while_longer_items_run():
    """``then(k, result)`` adds items computed by the same function: after the items before them in
    the serial run; in Ray as soon as the result that made them is in, beside a longer item."""
    import ray

    from odolab.core.parallel import fan_out

    def _follow(k, value):
        return [value * 10] if value < 10 else []

    def _wait(item):  # local: Ray pickles it by value
        if item < 0:
            time.sleep(2.0)
        return abs(item)

    assert fan_out(abs, [-1, -2], then=_follow, execution=Execution(parallel=False)) == [1, 2, 10, 20]
    assert fan_out(abs, [], then=_follow, execution=Execution(progress=False)) == []  # nothing to start Ray for
    with pytest.raises(ValueError, match="then and inputs"):
        fan_out(abs, [1], inputs=[2], then=_follow, execution=Execution(parallel=False))
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        finished = []
        got = fan_out(
            _wait, [-3, 1], then=_follow, execution=Execution(progress=False), on_result=lambda k, v: finished.append(v)
        )
        assert got == [None, None, None, None] and finished[:2] == [1, 10]  # 1's follower done before -3 ends
        assert sorted(finished) == [1, 3, 10, 30]
        assert fan_out(_wait, [2], then=_follow, execution=Execution(progress=False)) == [2, 20]
    finally:
        ray.shutdown()


def _beside(monkeypatch, init, work, shut, initialized=False):
    """start_ray_beside(work) with ray.init replaced by ``init``; ``shut`` gains True per ray.shutdown()."""
    import ray

    from odolab.core.parallel import start_ray_beside

    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    monkeypatch.setattr(ray, "init", init)
    monkeypatch.setattr(ray, "is_initialized", lambda: initialized)
    monkeypatch.setattr(ray, "shutdown", lambda: shut.append(True))
    return start_ray_beside(work, quiet=True)


def test_start_ray_beside_runs_the_work_while_ray_starts_and_says_when_it_is_up(monkeypatch):
    import threading

    events, shut = [], []
    working = threading.Event()

    def init(**kwargs):
        assert working.wait(30), "the work had not begun while Ray was starting"
        events.append("ray up")

    def work(up):
        working.set()
        assert up.wait(30)
        events.append("work saw up")
        return 42

    assert _beside(monkeypatch, init, work, shut) == (42, True)
    assert events == ["ray up", "work saw up"] and shut == []


def test_start_ray_beside_shuts_ray_down_again_when_the_work_fails(monkeypatch):
    def work(up):
        raise ValueError("bad option")

    shut = []
    with pytest.raises(ValueError, match="bad option"):
        _beside(monkeypatch, lambda **kwargs: None, work, shut)
    assert shut == [True]


def test_start_ray_beside_raises_a_failed_start_after_the_work_has_ended(monkeypatch):
    ended = []

    def init(**kwargs):
        raise RuntimeError("no room for Ray")

    def work(up):
        assert up.wait(30)  # told the start has ended, so it may stop
        ended.append(True)

    with pytest.raises(RuntimeError, match="no room"):
        _beside(monkeypatch, init, work, [])
    assert ended == [True]


def test_start_ray_beside_leaves_a_running_ray_alone(monkeypatch):
    def init(**kwargs):  # pragma: no cover - Ray runs already
        raise AssertionError

    shut = []
    assert _beside(monkeypatch, init, lambda up: up.wait(30), shut, initialized=True) == (True, False)
    assert shut == []


@pytest.mark.slow
def test_shutdown_ray_puts_the_commands_sigterm_handler_back_beneathrun_python(tmp_path):
    """ray.shutdown() resets SIGTERM to the default action at the C level while Python still reports
    its handler; after shutdown_ray a SIGTERM reaches the command's handler (clean-up, its line)."""
    done = run_python(
        tmp_path,
        "import os, signal, sys, time\n"
        "signal.signal(signal.SIGTERM, lambda s, f: (print('handled', flush=True), sys.exit(7)))\n"
        "from odolab.core.parallel import shutdown_ray, start_ray\n"
        "assert start_ray(None, quiet=True)\n"
        "shutdown_ray()\n"
        "os.kill(os.getpid(), signal.SIGTERM)\n"
        "time.sleep(5)\n",
    )
    assert (done.returncode, done.stdout.strip()) == (7, "handled"), done.stderr[-2000:]


@pytest.mark.slow
def test_a_local_start_never_joins_a_cluster_running_on_the_machine(ray_cluster, tmp_path):
    """With no address, start_ray starts an instance of its own (Ray's ``address="local"``): a plain
    ray.init() would join the cluster another program started on this machine, and die with it."""
    done = run_python(
        tmp_path,
        "import ray\n"
        "from odolab.core.parallel import shutdown_ray, start_ray\n"
        "assert start_ray(None, quiet=True)\n"
        "print(ray.get_runtime_context().gcs_address)\n"
        "shutdown_ray()\n",
    )
    assert done.returncode == 0, done.stderr[-2000:]
    assert done.stdout.strip() and done.stdout.strip() != ray_cluster
