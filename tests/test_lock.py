"""odolab.io.lock: one run at a time into a folder; a second is refused at once, a killed one never blocks
for compare's, navigate's and simcard's --out, the trainers' --work and a study's --out."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from odolab.io.lock import PROC_LOCKS, FolderInUseError, FolderLock, holder_pid, lock_folder
from tests.helpers import command_argv, refused

#: A second process that holds the folder given as its argument until it is killed (no odolab
#: import: it starts in a few milliseconds, and holds the lock as lock_folder takes it).
HOLDER = (
    "import fcntl, os, sys, time\n"
    "fd = os.open(sys.argv[1], os.O_RDONLY)\n"
    "fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)\n"
    "print('held', flush=True)\n"
    "time.sleep(60)\n"
)


@pytest.fixture
def held(tmp_path):
    """``hold(folder)`` starts another process holding ``folder``; all are killed after the test."""
    started: list[subprocess.Popen] = []

    def hold(folder: Path) -> subprocess.Popen:
        folder.mkdir(parents=True, exist_ok=True)
        proc = subprocess.Popen([sys.executable, "-c", HOLDER, str(folder)], stdout=subprocess.PIPE, text=True)
        started.append(proc)
        assert proc.stdout.readline().strip() == "held"
        return proc

    yield hold
    for proc in started:
        proc.kill()
        proc.wait()


def test_a_folder_another_process_holds_is_refused_at_once_naming_its_pid(tmp_path, held):
    proc = held(tmp_path / "out")
    with pytest.raises(FolderInUseError) as exc:
        lock_folder(tmp_path / "out")
    said = exc.value.named("--out")
    assert said.startswith(f"--out {tmp_path / 'out'} is in use by another odolab run")
    assert "\n" not in said and "choose another folder" in said
    if os.path.exists(PROC_LOCKS):  # Linux tells who holds it
        assert exc.value.pid == proc.pid and f"(pid {proc.pid})" in said


def test_a_lock_left_by_a_killed_process_does_not_block(tmp_path, held):
    proc = held(tmp_path / "out")
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    with lock_folder(tmp_path / "out") as lock:
        assert lock.held
    assert os.listdir(tmp_path / "out") == []  # the lock is the folder's own: no file in it, none left


def test_released_or_dropped_the_folder_is_free_again(tmp_path):
    lock = lock_folder(tmp_path)
    with pytest.raises(FolderInUseError):  # a second hold, even from this process
        lock_folder(tmp_path)
    lock.release()
    lock_folder(tmp_path)  # taken and dropped at once
    with FolderLock(tmp_path) as again:
        assert again.held
    assert not again.held and lock_folder(tmp_path).held


def test_the_holder_is_read_from_the_systems_lock_list(tmp_path):
    st = os.stat(tmp_path)
    dev = f"{os.major(st.st_dev):02x}:{os.minor(st.st_dev):02x}:{st.st_ino}"
    listing = tmp_path / "locks"
    listing.write_text(
        f"1: POSIX  ADVISORY  WRITE 11 {dev} 0 EOF\n"  # another kind of lock on it: not ours
        f"2: FLOCK  ADVISORY  WRITE 4242 {dev} 0 EOF\n"
        f"2: -> FLOCK  ADVISORY  WRITE 77 {dev} 0 EOF\n"  # a waiter
    )
    assert holder_pid(tmp_path, str(listing)) == 4242
    listing.write_text("garbage\n1: FLOCK ADVISORY WRITE x y 0 EOF\n")
    assert holder_pid(tmp_path, str(listing)) is None
    assert holder_pid(tmp_path, str(tmp_path / "missing")) is None


def _one_error_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


def test_a_second_compare_into_the_same_out_is_refused_before_any_work(tmp_path, held, capsys):
    from odolab.cli import run_cli
    from odolab.cli.compare import main

    out = tmp_path / "out"
    proc = held(out)
    argv = ["--odometers", "ground-truth", "--episodes", "1", "--max-steps", "2", "--serial", "--quiet"]
    assert run_cli(main, "python -m odolab.compare", [*argv, "--no-cache", "--out", str(out)]) == 2
    line = _one_error_line(capsys.readouterr().err)
    assert f"--out {out} is in use by another odolab run" in line
    assert os.listdir(out) == []  # nothing computed, nothing written
    proc.kill()
    proc.wait()


@pytest.mark.parametrize("command", ["navigate", "simcard"])
def test_a_second_navigate_or_simcard_into_the_same_out_is_refused(tmp_path, held, capsys, command):
    out = tmp_path / command
    held(out)
    line = refused(capsys, command, [*command_argv(command, out), "--serial"])
    assert f"--out {out} is in use by another odolab run" in line and os.listdir(out) == []


def test_a_second_training_into_the_same_work_or_reports_is_refused(tmp_path, held):
    from odolab.cli import UsageError
    from odolab.cli.train import hold_training_folders

    work, reports = tmp_path / "work", tmp_path / "reports"
    reports.mkdir()
    job = SimpleNamespace(work=work, reports=reports)
    proc = held(work)
    with pytest.raises(UsageError, match=r"^--work .* is in use by another odolab run"), hold_training_folders(job):
        pytest.fail("trained although --work is in use")
    proc.kill()
    proc.wait()
    held(reports)
    with pytest.raises(UsageError, match=r"^--reports .* is in use"), hold_training_folders(job):
        pytest.fail("trained although --reports is in use")
    with hold_training_folders(SimpleNamespace(work=work, reports=work)), pytest.raises(FolderInUseError):
        lock_folder(work)  # one folder for both: held once
    lock_folder(work)  # released after the block


def test_a_second_run_of_a_study_into_the_same_out_is_refused(tmp_path, held):
    from odolab.cli import UsageError
    from studies import framework

    out = tmp_path / "study"
    out.mkdir()
    with framework.hold_out(out), pytest.raises(FolderInUseError):
        lock_folder(out)
    held(out)
    with pytest.raises(UsageError, match=r"^--out .* is in use by another odolab run"):
        framework.hold_out(out)


def test_a_finished_runs_hold_kept_only_by_a_reference_cycle_lets_the_same_process_take_the_folder(tmp_path):
    """A study's main that returned may leave its frame in a garbage cycle (a traceback's) until the
    collector runs: its hold then gives way to the next run in the same process; a live hold does not."""
    import gc

    gc.disable()
    try:
        garbage = [lock_folder(tmp_path)]
        garbage.append(garbage)  # a cycle: only the collector frees it
        del garbage
        taken = lock_folder(tmp_path)
        assert taken.held
        with pytest.raises(FolderInUseError):
            lock_folder(tmp_path)  # the live hold of this very process still refuses a second run
    finally:
        gc.enable()
