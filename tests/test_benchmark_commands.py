"""odolab.benchmarks.commands: a benchmark's timed child command."""

from __future__ import annotations

import signal
import subprocess
import sys
import time

import pytest

from odolab.benchmarks.commands import CommandFailed, timed_command


def test_timed_command_times_a_command_and_names_a_failure_in_one_line():
    assert timed_command([sys.executable, "-c", "import time; time.sleep(0.2)"]) >= 0.2
    failing = [sys.executable, "-c", "import sys; print('first', file=sys.stderr); sys.exit('bad input: x')"]
    with pytest.raises(CommandFailed) as caught:
        timed_command(failing, capture_stderr=True)
    assert str(caught.value) == f"{sys.executable} exited with 1: bad input: x"
    with pytest.raises(CommandFailed, match=r"^python -m odolab.nosuch exited with 1: "):
        timed_command([sys.executable, "-m", "odolab.nosuch"], capture_stderr=True)


def test_timed_command_passes_an_interruption_on_and_waits_for_the_childs_clean_up(tmp_path):
    """Ctrl-C of the timing process reaches the child once, which cleans up before the timing
    process stops (it is not killed at once)."""
    ready, cleaned = tmp_path / "ready", tmp_path / "cleaned"
    child = (
        "import pathlib, signal, sys, time\n"
        "def stop(*_):\n"
        "    time.sleep(0.5)\n"
        f"    pathlib.Path({str(cleaned)!r}).write_text('done')\n"
        "    sys.exit(130)\n"
        "signal.signal(signal.SIGINT, stop)\n"
        f"pathlib.Path({str(ready)!r}).touch()\n"
        "time.sleep(60)\n"
    )
    parent = (
        "import sys\n"
        "from odolab.benchmarks.commands import timed_command\n"
        f"timed_command([sys.executable, '-c', {child!r}])\n"
    )
    proc = subprocess.Popen([sys.executable, "-c", parent], stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 60
    while not ready.exists() and time.monotonic() < deadline:
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    _, said = proc.communicate(timeout=60)
    assert proc.returncode != 0 and "KeyboardInterrupt" in said
    assert cleaned.read_text() == "done"
