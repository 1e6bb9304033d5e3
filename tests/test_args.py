"""odolab.cli.args against hostile disks and names (issue 56): a name over 255 bytes, a full disk
while a command writes, a read-only cache: one line and exit 2, never a traceback. Also: RAY_ADDRESS
and --ray-address checked before any folder is made, a folder named by the command that wrote it,
numbers in plain ASCII digits, long names cut, and run_cli's exits on Ctrl-C, SIGTERM and a closed pipe."""

from __future__ import annotations

import errno
import json
import os
import re
from pathlib import Path

import pytest

from odolab.cli import run_cli
from odolab.cli.args import NAME_MAX, UsageError, check_cache_dir, disk_error
from odolab.cli.study import command
from odolab.io import atomic
from tests.helpers import command_argv, refused, stderr_line

TUM = Path(__file__).parent / "data" / "tum_fr1_xyz_10"


def _one_line(err: str) -> str:
    lines = err.strip().splitlines()
    assert len(lines) == 1, err
    return lines[0]


@pytest.mark.parametrize("option", ["--out", "--cache"])
def test_a_folder_name_over_255_bytes_is_one_line(tmp_path, capsys, option):
    from odolab.cli.compare import main

    long = tmp_path / ("é" * 130)  # 260 bytes in UTF-8, 130 characters
    assert run_cli(main, "python -m odolab.compare", [option, str(long / "x"), "--quiet"]) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith(f"python -m odolab.compare: error: {option}: expected folder and file names of at most")
    assert f"{NAME_MAX} bytes, got one of 260 bytes" in line and len(line) < 300
    assert os.listdir(tmp_path) == []


def test_a_path_over_the_systems_limit_is_one_line(capsys):
    from odolab.cli.compare import main

    deep = "/".join(["d" * 200] * 21)  # every name fits, the whole does not
    assert run_cli(main, "python -m odolab.compare", ["--out", deep]) == 2
    assert "expected a path of at most 4095 bytes" in _one_line(capsys.readouterr().err)


def test_run_cli_says_an_input_error_found_during_the_work_in_one_line(capsys):
    """An input error raised once the work began (a scene with no episode, found as it renders) is one
    line and exit 2; another ValueError is a bug to see whole."""
    from odolab.core.errors import InputError

    def late(argv):
        raise InputError("no start and goal 1-30 m apart", joiner=": ", subject="room.obj")

    assert run_cli(late, "prog", []) == 2
    assert _one_line(capsys.readouterr().err) == "prog: error: room.obj: no start and goal 1-30 m apart"

    def bug(argv):
        raise ValueError("a bug")

    with pytest.raises(ValueError, match="a bug"):
        run_cli(bug, "prog", [])


def test_a_disk_error_is_one_line_naming_the_file_and_others_still_raise(capsys):
    def full(argv):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), "runs/x/table.csv")

    assert run_cli(full, "prog", []) == 2
    line = _one_line(capsys.readouterr().err)
    assert line.startswith("prog: error: runs/x/table.csv: no space left on device; nothing half-written")

    def broken(argv):
        raise OSError(errno.EIO, "input/output error")

    with pytest.raises(OSError):  # not a disk's refusal of a write: a bug to see whole
        run_cli(broken, "prog", [])
    assert disk_error(OSError(errno.EDQUOT, "Disk quota exceeded")).startswith("disk quota exceeded; ")


def test_a_full_disk_while_compare_writes_out_is_one_line_and_leaves_nothing_half_written(
    tmp_path, monkeypatch, capsys
):
    from odolab.cli.compare import main

    real, calls = os.fsync, []

    def full(fd: int) -> None:  # the disk fills once the manifest is written
        calls.append(fd)
        if len(calls) > 1:
            raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
        real(fd)

    out = tmp_path / "out"
    monkeypatch.setattr(atomic.os, "fsync", full)
    argv = ["--tum", str(TUM), "--odometers", "ground-truth", "--out", str(out), "--quiet"]
    assert run_cli(main, "python -m odolab.compare", argv) == 2
    line = _one_line(capsys.readouterr().err)
    assert f"{out / 'table.csv'}: no space left on device; nothing half-written was left" in line
    assert not [p for p in out.rglob("*") if p.name.endswith(".tmp")] and not (out / "table.csv").exists()


def test_a_read_only_cache_is_accepted_and_a_file_is_not(tmp_path, monkeypatch):
    cache = tmp_path / "cache"
    cache.mkdir()
    real = os.access
    monkeypatch.setattr(os, "access", lambda p, mode: False if mode & os.W_OK else real(p, mode))
    check_cache_dir(cache, "--cache")  # read, not refused (root writes anywhere: the check is faked)
    (tmp_path / "file").write_text("x")
    with pytest.raises(UsageError, match="is a file, not a folder"):
        check_cache_dir(tmp_path / "file", "--cache")
    monkeypatch.setattr(os, "access", real)
    check_cache_dir(tmp_path / "new", "--cache")  # made
    assert (tmp_path / "new").is_dir()


def test_a_pasted_20000_character_name_is_not_echoed_whole(tmp_path):
    import contextlib
    import io

    from odolab.cli import MAX_ERROR_CHARS
    from odolab.compare import main

    name = "k" * 20000
    for args in (["--odometers", name], ["--odometers", "icp", "--odometer-option", f"icp.{name}=1"]):
        err = io.StringIO()
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = run_cli(
                main,
                "odolab.compare",
                [*args, "--episodes", "1", "--max-steps", "3", "--no-cache", "--out", str(tmp_path / "o")],
            )
        line = err.getvalue().strip()
        assert code == 2 and "\n" not in line and line.endswith("more characters)")
        assert len(line) < MAX_ERROR_CHARS + 100


def test_an_option_is_named_once_in_its_error():
    from odolab.cli import ArgumentParser, pinhole

    ap = ArgumentParser(prog="x")
    ap.add_argument("--intrinsics", type=pinhole("--intrinsics"))
    with pytest.raises(UsageError) as err:
        ap.parse_args(["--intrinsics", "0,1,2,3"])
    assert str(err.value).count("--intrinsics") == 1


def test_a_dangling_output_folder_is_named_as_a_link(tmp_path):
    from odolab.cli import check_output_dir

    (tmp_path / "out").symlink_to(tmp_path / "nowhere")
    with pytest.raises(UsageError, match="link to nothing"):
        check_output_dir(tmp_path / "out", "--out")


def test_a_reader_that_goes_away_is_no_traceback(capsys):
    """``odolab help | head -1`` ended in a BrokenPipeError traceback."""

    def main(argv):
        raise BrokenPipeError(32, "Broken pipe")

    assert run_cli(main, "python -m odolab.evaluate", []) == 141
    assert capsys.readouterr().err == ""


@pytest.mark.parametrize("text", ["1_0", "\uff15", "1\u0660"])
def test_numbers_are_plain_ascii_digits(text):
    """'--rgb-noise 1_0' ran at ten times the noise, '--episodes ５' (a full-width 5) as 5."""
    import argparse

    from odolab.cli import number

    with pytest.raises(argparse.ArgumentTypeError, match="must be a number"):
        number("--rgb-noise", float, 0, 10)(text)
    assert number("--rgb-noise", float, 0, 10)(" 2.5e0 ") == 2.5 and number("--episodes", int, 1)("+3") == 3


@pytest.mark.slow
def test_sigterm_ends_a_command_after_its_clean_up(tmp_path):
    """SIGTERM (what `kill` and job schedulers send) ends a command like Ctrl-C, exit 143 after its
    `with` blocks ran: the training bench's temporary data folder is removed, not left in the
    system's temporary folder."""
    import os
    import signal
    import subprocess
    import sys
    import time

    recipe = tmp_path / "tiny.toml"
    recipe.write_text(
        'base = "' + str(Path("studies/robust_vo/shipped.toml").resolve()) + '"\n'
        "[model]\nwidth = 48\nheight = 32\n[train_data]\nwidth = 48\nheight = 32\n"
        "[val_data]\nwidth = 48\nheight = 32\nmax_steps = 400\n"
    )
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    env = {**os.environ, "TMPDIR": str(tmp)}
    proc = subprocess.Popen(
        [sys.executable, "-m", "odolab.bench", "--only", "training", "--recipe", str(recipe)],
        env=env,
        stdout=subprocess.DEVNULL,
        stderr=subprocess.PIPE,
        text=True,
    )
    deadline = time.monotonic() + 120
    while not list(tmp.glob("odolab-bench-*")) and proc.poll() is None and time.monotonic() < deadline:
        time.sleep(0.05)
    assert list(tmp.glob("odolab-bench-*")), "the bench never made its temporary folder"
    proc.send_signal(signal.SIGTERM)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 143, err
    assert "python -m odolab.bench: terminated" in err
    assert not list(tmp.glob("odolab-bench-*"))


def test_sigterm_is_reported_as_such_when_a_library_re_raises_it_as_ctrl_c(capsys):
    """Ray turns any exception raised by a signal handler during ray.get/ray.wait into a bare
    KeyboardInterrupt; run_cli still knows SIGTERM came and answers 143, "terminated"."""
    import os
    import signal
    import time

    from odolab.cli import run_cli

    def main(argv):
        try:
            os.kill(os.getpid(), signal.SIGTERM)
            time.sleep(10)  # the handler raises in here
        except KeyboardInterrupt:
            raise KeyboardInterrupt() from None  # what Ray's check_signals does with it

    assert run_cli(main, "prog", []) == 143
    assert "prog: terminated" in capsys.readouterr().err
    assert run_cli(lambda argv: (_ for _ in ()).throw(KeyboardInterrupt()), "prog", []) == 130


@pytest.mark.parametrize(("signum", "code", "word"), [("SIGINT", 130, "interrupted"), ("SIGTERM", 143, "terminated")])
@pytest.mark.parametrize("then", ["returns", "fails"])
def test_a_signal_that_a_library_swallowed_still_ends_the_command(capsys, signum, code, word, then):
    """Open3D's import swallows a Ctrl-C that lands while it loads; the command then runs on, but
    its exit code and last line still say it was stopped (a hostile review found exit 0)."""
    import os
    import signal
    import time

    swallowed = []

    def main(argv):
        try:
            os.kill(os.getpid(), getattr(signal, signum))
            time.sleep(1)
        except KeyboardInterrupt as exc:  # swallowed, as a library's import does
            swallowed.append(exc)
        if then == "fails":
            raise RuntimeError("what the swallowed signal left broken")
        return 0

    before = signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)
    assert run_cli(main, "prog", []) == code
    assert len(swallowed) == 1  # the signal reached the library, which went on
    assert capsys.readouterr().err == f"prog: {word}\n"
    assert (signal.getsignal(signal.SIGINT), signal.getsignal(signal.SIGTERM)) == before


COMMANDS = ["compare", "navigate", "simcard", "training_data", "calibrate", "e_table"]


@pytest.mark.parametrize("name", COMMANDS)
@pytest.mark.parametrize(
    "environment, extra, words",
    [
        ("garbage", [], "RAY_ADDRESS (environment) 'garbage' is not an address"),
        ("127.0.0.1:1", [], "RAY_ADDRESS (environment) 127.0.0.1:1: no Ray cluster there"),
        (None, ["--ray-address", "garbage"], "--ray-address 'garbage' is not an address"),
        (None, ["--ray-address", "127.0.0.1:1", "--serial"], "--ray-address and --serial exclude each other"),
    ],
)
def test_every_command_that_can_start_ray_checks_its_address_before_making_anything(
    tmp_path, monkeypatch, capsys, name, environment, extra, words
):
    """RAY_ADDRESS was a traceback (garbage), a hang (a dead address) or Ray's own text, after
    --out was made; simcard and training_data ignored --ray-address with --serial."""
    if environment is None:
        monkeypatch.delenv("RAY_ADDRESS", raising=False)
    else:
        monkeypatch.setenv("RAY_ADDRESS", environment)
    monkeypatch.chdir(tmp_path)  # a default folder a command would make lands here
    out = tmp_path / "new" / "out"
    err = refused(capsys, name, command_argv(name, out) + extra)
    assert words in err, err
    assert ("unset it for a local instance" in err) == (environment is not None)
    assert list(tmp_path.iterdir()) == [], "a refusal makes no folder"


def test_ray_address_in_the_environment_is_left_alone_when_no_ray_starts(monkeypatch):
    from odolab.cli.args import check_ray_option

    monkeypatch.setenv("RAY_ADDRESS", "garbage")
    check_ray_option(None, serial=True)  # --serial: Ray is never started
    check_ray_option(None, starts_ray=False)  # a study's --redraw computes nothing
    with pytest.raises(UsageError, match=r"^RAY_ADDRESS \(environment\) 'garbage' is not an address"):
        check_ray_option(None)
    monkeypatch.setenv("RAY_ADDRESS", "")  # set but empty: Ray ignores it too
    check_ray_option(None)


def test_a_ray_client_address_without_ray_client_is_one_line(monkeypatch):
    """ray:// needs Ray Client (ray[client]); without it ray.init() raised after the folders were made."""
    from odolab.cli.args import check_ray_option

    monkeypatch.setattr("odolab.core.parallel.has_ray_client", lambda: False)
    with pytest.raises(UsageError, match=r"--ray-address ray://127.0.0.1:1: a ray:// address needs Ray Client"):
        check_ray_option("ray://127.0.0.1:1")
    monkeypatch.setenv("RAY_ADDRESS", "ray://127.0.0.1:1")
    with pytest.raises(UsageError, match=r"RAY_ADDRESS \(environment\) ray://127.0.0.1:1: a ray:// address needs"):
        check_ray_option(None)


def _navigation_folder(path: Path) -> Path:
    path.mkdir()
    (path / "config.json").write_text(json.dumps({"format": 1, "options": {}, "episodes": [{}], "policy": {}}))
    (path / "nav.csv").write_text("odometer\n")
    return path


def _study_folder(path: Path) -> Path:
    path.mkdir()
    (path / "manifest.txt").write_text("# odolab study e_table\ntable.md\n")
    (path / "table.md").write_text("| x |\n")
    return path


def _compare_folder(path: Path) -> Path:
    path.mkdir()
    (path / "manifest.txt").write_text("# odolab compare\ntable.csv\n")
    (path / "table.csv").write_text("odometer\n")
    return path


@pytest.mark.parametrize(
    "name, folder, owner",
    [
        ("compare", _navigation_folder, "a navigation results folder (python -m odolab.navigate)"),
        ("e_table", _navigation_folder, "a navigation results folder (python -m odolab.navigate)"),
        ("training_data", _study_folder, "the report folder of study e_table (python -m studies.e_table)"),
        ("navigate", _compare_folder, "a comparison report folder (python -m odolab.compare)"),
    ],
)
def test_a_folder_odolab_wrote_is_named_by_its_owner(tmp_path, monkeypatch, capsys, name, folder, owner):
    """Such folders were said to hold "files odolab did not write"."""
    monkeypatch.delenv("RAY_ADDRESS", raising=False)
    out = folder(tmp_path / "theirs")
    before = sorted(p.name for p in out.iterdir())
    err = refused(capsys, name, command_argv(name, out) + ["--serial"])
    assert f"--out {out}: is {owner}; choose another --out" in err, err
    assert sorted(p.name for p in out.iterdir()) == before


def test_setting_type_takes_what_the_config_field_takes():
    """An option made from a config field (setting_type) has the field's kind and range, so the
    command line and a TOML file take the same values."""
    import argparse

    from odolab.cli.args import setting_help, setting_type
    from odolab.sim.training_data import DataConfig

    width = setting_type("--width", DataConfig, "width")
    assert width("341") == 341 and type(width("1")) is int
    for bad, said in [
        ("342", "--width must be in [1, 341], got 342"),
        ("2.5", "--width must be an integer in [1, 341], got '2.5'"),
    ]:
        with pytest.raises(argparse.ArgumentTypeError, match=re.escape(said)):
            width(bad)
    assert (
        setting_help(DataConfig, "width")
        == "stored frame width, px (resized from the camera's), [1, 341] (default 170)"
    )


def test_dotdot_after_a_link_is_refused_before_anything_is_made(tmp_path):
    """``a/link/../z`` would be made beside the link's target, not in ``a``: refused in one line."""
    from odolab.cli import UsageError, check_output_dir, check_output_file

    (tmp_path / "far" / "target").mkdir(parents=True)
    (tmp_path / "a").mkdir()
    (tmp_path / "a" / "link").symlink_to(tmp_path / "far" / "target")
    odd = tmp_path / "a" / "link" / ".." / "z"
    with pytest.raises(UsageError, match=r"found '\.\.' after the link .*link, which leads to .*far.z"):
        check_output_dir(odd, "--out")
    with pytest.raises(UsageError, match=r"'\.\.' after the link"):
        check_output_file(odd / ".." / "f.json", "--json")
    assert not (tmp_path / "far" / "z").exists() and not (tmp_path / "a" / "z").exists()
    check_output_dir(tmp_path / "a" / ".." / "b", "--out")  # '..' after a real folder is fine
    assert (tmp_path / "b").is_dir()


def test_an_output_file_of_another_kind_is_never_replaced(tmp_path, capsys):
    """bench --json replaces only a bench JSON; the forward-dz probe's --out only its own report;
    both refuse before any work."""
    pytest.importorskip("torch")
    from odolab.cli.bench import main as bench_main

    summary = tmp_path / "training.json"
    summary.write_text(json.dumps({"command": "x", "stages": {}}))
    assert run_cli(bench_main, "bench", ["--only", "evaluate", "--json", str(summary)]) == 2
    assert "expected a new file or a bench JSON file" in stderr_line(capsys)
    assert json.loads(summary.read_text()) == {"command": "x", "stages": {}}
    model = tmp_path / "model.pt"
    model.write_bytes(b"\x80weights")
    assert command("forward-dz-probe", ["--out", str(model)]) == 2
    assert "expected a new file or an earlier report of this probe" in stderr_line(capsys)
    assert model.read_bytes() == b"\x80weights"
    assert command("forward-dz-probe", ["--out", "/dev/null"]) == 2
    assert "is not a regular file" in stderr_line(capsys)


def test_exit_process_after_an_interruption_does_not_wait_for_threads_left_busy():
    """130 (Ctrl-C) leaves at once with that code and the flushed output, although a thread the
    interruption left busy would hold the interpreter's exit for a minute; another code exits as usual."""
    import subprocess
    import sys
    import time

    script = (
        "import threading, time, sys\n"
        "from odolab.cli.args import exit_process\n"
        "threading.Thread(target=time.sleep, args=(60,)).start()\n"
        "print('said', flush=False)\n"
        "exit_process(int(sys.argv[1]))\n"
    )
    started = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-c", script, "130"], check=False, capture_output=True, text=True, timeout=50
    )
    assert proc.returncode == 130 and proc.stdout == "said\n" and time.perf_counter() - started < 30
    plain = [sys.executable, "-c", script.replace("args=(60,)", "args=(0,)"), "3"]
    assert subprocess.run(plain, check=False, capture_output=True, timeout=50).returncode == 3


def test_exit_process_runs_the_exit_handlers_flushes_and_waits_for_a_thread_still_running(tmp_path):
    """A finished command leaves with its code after its exit handlers ran and its output was
    flushed (where it has an output); a (non-daemon) thread still running is waited for, as Python's
    own exit does."""
    import subprocess
    import sys

    done = tmp_path / "done"
    script = (
        "import atexit, threading, time, sys\n"
        "from odolab.cli.args import exit_process\n"
        "atexit.register(lambda: print('handler ran'))\n"
        "if len(sys.argv) > 2:\n"
        "    threading.Thread(target=lambda: (time.sleep(1), open(sys.argv[2], 'w').close())).start()\n"
        "print('said', flush=False)\n"
        "exit_process(int(sys.argv[1]))\n"
    )
    proc = subprocess.run([sys.executable, "-c", script, "3"], check=False, capture_output=True, text=True, timeout=60)
    assert (proc.returncode, proc.stdout) == (3, "said\nhandler ran\n")
    proc = subprocess.run(
        [sys.executable, "-c", script, "0", str(done)], check=False, capture_output=True, text=True, timeout=60
    )
    assert (proc.returncode, proc.stdout) == (0, "said\nhandler ran\n") and done.exists()
    closed = subprocess.run(["sh", "-c", f'"{sys.executable}" -c "$0" 4 >&- 2>&-', script], check=False, timeout=60)
    assert closed.returncode == 4  # started with stdout and stderr closed: nothing to flush, the same code


def test_python_m_odolab_is_the_odolab_command():
    import subprocess
    import sys

    proc = subprocess.run(
        [sys.executable, "-m", "odolab", "--help"], check=False, capture_output=True, text=True, timeout=60
    )
    assert proc.returncode == 0 and "commands:" in proc.stdout and "compare" in proc.stdout
