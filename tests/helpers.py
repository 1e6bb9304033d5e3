"""Helpers shared by several test files: a command's one-line refusal, the smallest run of each
command, a script in a fresh Python, small odometers and a five-frame sequence, the TUM test folder and its camera, figures kept
instead of written, and the robust VO trainer's command line on a tiny recipe."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

from odolab.api import Action, Estimate, Frame, Intrinsics, Odometer, planar_to_transform
from odolab.cli import run_cli
from odolab.odometry.odometer import load_odometer

ROOT = Path(__file__).resolve().parents[1]
TUM_DIR = ROOT / "tests" / "data" / "tum_fr1_xyz_10"
#: TUM RGB-D's fr1 camera (fx, fy, cx, cy), for a folder whose name names no TUM camera.
FR1 = (517.3, 516.5, 318.6, 255.3)
TUM_OK = "1.0 0 0 0 0 0 0 1\n2.0 1 0 0 0 0 0 1\n3.0 1 1 0 0 0 0 1\n4.0 0 1 1 0 0 0 1\n"


# -- one-line refusals -------------------------------------------------------------------------


def one_line_error(module: str, *args: str, words: str) -> None:
    """Run ``python -m module args`` in this process (as its ``__main__`` would, through
    ``run_cli``): exit 2, one line on stderr naming ``words``, no traceback."""
    import contextlib
    import importlib
    import io

    from odolab.cli.commands import COMMANDS

    command = {m: c for m, c, _ in COMMANDS.values()} | {"odolab.action_prior": "odolab.cli.action_prior"}
    main = importlib.import_module(command.get(module, module)).main
    err = io.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
        code = run_cli(main, module, [str(a) for a in args])
    assert code == 2, err.getvalue()
    lines = err.getvalue().strip().splitlines()
    assert len(lines) == 1, err.getvalue()
    assert words in lines[0] and lines[0].startswith(f"{module}: error: "), lines[0]


def command_main(name: str):
    """The ``main`` of a command, by its name in these tests."""
    import importlib

    module = {
        "compare": "odolab.cli.compare",
        "navigate": "odolab.cli.navigate",
        "simcard": "odolab.cli.simcard",
        "training_data": "odolab.cli.training_data",
        "calibrate": "odolab.cli.calibrate_fusion",
    }.get(name)
    if module is None:  # a study: its command line is odolab.cli.study's
        from odolab.cli.study import study

        return lambda argv: study(name.replace("_", "-"), argv)
    return importlib.import_module(module).main


def command_argv(name: str, out: Path) -> list[str]:
    """The smallest run of each command, into ``out`` (a folder, or calibrate's file in it)."""
    return (
        {
            "compare": ["--odometers", "action-prior", "--episodes", "2", "--max-steps", "5", "--no-cache"],
            "navigate": ["--odometers", "action-prior", "--episodes", "1", "--max-steps", "5"],
            "simcard": ["--episodes", "1", "--rendered", "1", "--frames", "2", "--max-steps", "5"],
            "training_data": ["--episodes", "1", "--max-steps", "5"],
            "calibrate": [
                "--odometers",
                "action-prior",
                "--episodes",
                "1",
                "--max-steps",
                "30",
                "--cache",
                str(out) + "-cache",
            ],
            "e_table": ["--scale", "ci"],
        }[name]
        + ["--quiet"] * (name not in ("training_data",))
        + [
            "--out",
            str(out / "cal.json" if name == "calibrate" else out),
        ]
    )


def refused(capsys, name: str, argv: list[str]) -> str:
    """Run command ``name``: exit 2 and one line on stderr, no traceback; returns the line."""
    assert run_cli(command_main(name), f"python -m {name}", argv) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    return err.strip()


# -- small odometers and a sequence ------------------------------------------------------------

INTRINSICS = Intrinsics.from_hfov(8, 6, 79.0)


class Steps:
    """A five-frame sequence moving 0.25 m forward per step, with ground truth and actions."""

    name = "steps"
    collisions = None
    intrinsics = INTRINSICS

    def __len__(self) -> int:
        return 5

    def gt_pose(self, i: int) -> np.ndarray:
        return planar_to_transform(0.0, 0.25 * i, 0.0)

    def __getitem__(self, i: int) -> Frame:
        return Frame(np.zeros((6, 8, 3), np.uint8), np.full((6, 8), 2.0, np.float32), float(i), self.gt_pose(i))

    def action(self, i: int) -> Action:
        return Action.MOVE_FORWARD


class Truth(Odometer):
    """An oracle that answers the true motion, and fails a step whose frames hide it."""

    oracle = True

    def step(self, prev, cur, action):
        if prev.gt_pose is None or cur.gt_pose is None:
            return Estimate.invalid()
        return Estimate(np.linalg.inv(prev.gt_pose) @ cur.gt_pose)


class BlindComposite(Odometer):
    """A third-party composite that does not pass its input's oracle nature on."""

    def __init__(self, inputs: str = "") -> None:
        self.inner = load_odometer(inputs)

    def step(self, prev, cur, action):
        return self.inner.step(prev, cur, action)


class Never(Odometer):
    """An odometer that fails every step."""

    def step(self, prev, cur, action):
        return Estimate.invalid()


# -- figures -----------------------------------------------------------------------------------


def captured_figures(monkeypatch, module) -> list:
    """Make ``module.save_figure_atomic`` keep the figure instead of writing it."""
    import matplotlib

    matplotlib.use("Agg")
    figures: list = []
    monkeypatch.setattr(module, "save_figure_atomic", lambda fig, path: figures.append(fig))
    return figures


# -- the trainers' command line ----------------------------------------------------------------

ROBUST_RECIPE = """
[model]
width = 48
height = 32

[train_data]
width = 48
height = 32

[val_data]
split = "val"
width = 48
height = 32

[[stages]]
name = "{stage}"
actions = ["move_forward"]
epochs = 1
"""


def robust_job(tmp_path: Path, *argv: str, stage: str = "forward"):
    """The robust VO trainer's command line parsed with ``argv`` on a tiny recipe in ``tmp_path``."""
    from odolab.cli.train import parse_training_command, training_parser
    from odolab.learned.robust_vo.config import load_train_config

    recipe = tmp_path / "recipe.toml"
    recipe.write_text(ROBUST_RECIPE.replace("{stage}", stage))  # parsed only: no data is made
    ap = training_parser("python -m odolab.learned.robust_vo.train", "train", "robust-vo")
    return parse_training_command(
        ap,
        ["--config", str(recipe), "--work", str(tmp_path / "work"), "--reports", str(tmp_path / "reports"), *argv],
        load_train_config,
    )


def compare_refused(tmp_path, *args, words: str) -> None:
    """``python -m odolab.compare args`` on one 5-step episode (no cache, ``--out tmp_path/o``):
    refused in one line naming ``words`` (:func:`one_line_error`)."""
    tail = ["--episodes", "1", "--max-steps", "5", "--no-cache", "--out", tmp_path / "o"]
    one_line_error("odolab.compare", *args, *tail, words=words)


def refused_option(tmp_path, odometer: str, option: str, *, words: str) -> None:
    """:func:`compare_refused` of ``--odometers odometer --odometer-option option``."""
    compare_refused(tmp_path, "--odometers", odometer, "--odometer-option", option, words=words)


def outside_folder(tmp_path: Path) -> Path:
    """A folder beside a command's output folder, holding a file no run may touch."""
    outside = tmp_path / "outside"
    outside.mkdir()
    (outside / "victim.tum").write_text("precious")
    return outside


def stderr_line(capsys, *words: str) -> str:
    """What the command wrote on stderr: one line, no traceback, holding ``words``."""
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "Traceback" not in err, err
    for w in words:
        assert w in err, (w, err)
    return err


def run_python(tmp_path: Path, code: str, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    """``code`` run by this Python in a fresh process from the repository's root, with this process's
    environment but RAY_ADDRESS, updated by ``env``."""
    script = tmp_path / "script.py"
    script.write_text(code)
    environ = {k: v for k, v in os.environ.items() if k != "RAY_ADDRESS"} | (env or {})
    return subprocess.run(
        [sys.executable, str(script)], check=False, cwd=ROOT, env=environ, capture_output=True, text=True, timeout=180
    )
