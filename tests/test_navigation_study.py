"""navigate reuses a saved episode only when everything it depends on is the task's (its key) and
its fields agree with each other; any other is run again and named on the console (issue 42)."""

from __future__ import annotations

import json
import shutil

import pytest

from odolab.cli import run_cli

ARGS = ["--odometers", "ground-truth", "--episodes", "1", "--serial", "--quiet"]
EPISODE = "episodes/ground-truth/0000.json"


def _navigate(argv) -> int:
    from odolab.navigate import main

    return run_cli(main, "python -m odolab.navigate", [str(a) for a in argv])


def _notes(capsys) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if line.startswith("note:")]


@pytest.mark.slow
def test_an_episode_of_another_max_steps_or_contradicting_itself_is_run_again_and_named(tmp_path, capsys):
    short, out = tmp_path / "short", tmp_path / "out"
    assert _navigate(ARGS + ["--max-steps", "4", "--out", short]) == 0
    assert _navigate(ARGS + ["--max-steps", "5", "--out", out]) == 0
    right = (out / EPISODE).read_text()
    table = (out / "nav.csv").read_text()
    assert json.loads(right)["max_steps"] == 5 and len(json.loads(right)["key"]) == 64
    capsys.readouterr()
    shutil.copy(short / EPISODE, out / EPISODE)  # a 4-step episode where a 5-step one belongs
    assert _navigate(ARGS + ["--max-steps", "5", "--out", out]) == 0
    (note,) = _notes(capsys)
    assert "0000.json: made with --max-steps 4, not 5" in note and "running them again" in note
    assert (out / EPISODE).read_text() == right and (out / "nav.csv").read_text() == table
    row = json.loads(right)
    (out / EPISODE).write_text(json.dumps({**row, "success": 1, "stopped": False, "d_end": 9.0}))
    assert _navigate(ARGS + ["--max-steps", "5", "--out", out]) == 0
    (note,) = _notes(capsys)
    assert "0000.json: success 1 with stopped false and 9.00 m left" in note
    assert (out / EPISODE).read_text() == right and (out / "nav.csv").read_text() == table


def test_rows_without_a_key_must_fit_the_step_limit_and_agree_with_themselves(tmp_path):
    """Rows of an older version have no key: their odometer, episode, split, seed and weights are
    checked, and their step count against the limit (an episode ends at STOP before it, or at it)."""
    from odolab.navigation.agent import PolicyConfig
    from odolab.navigation.study import NavTask, read_row
    from odolab.sim.episodes import EpisodeSpec

    out = tmp_path / "out"
    assert _navigate(ARGS + ["--max-steps", "5", "--out", out]) == 0
    saved = json.loads((out / EPISODE).read_text())
    assert not saved["stopped"] and saved["steps"] == 5  # ran out: no STOP within 5 steps
    old = {k: v for k, v in saved.items() if k not in ("key", "max_steps")}
    path = tmp_path / "0000.json"
    path.write_text(json.dumps(old))

    def task(max_steps: int) -> NavTask:
        return NavTask(
            "ground-truth", {}, EpisodeSpec(split="test", index=0, max_steps=max_steps), PolicyConfig(), None
        )

    assert read_row(path, task(5)) == old
    for limit, why in ((4, "5 steps, above --max-steps 4"), (6, "not stopped after 5 steps, below --max-steps 6")):
        reasons = {}
        assert read_row(path, task(limit), [], reasons) is None and reasons[path] == why
    for change, why in (
        ({"stopped": True}, "stopped after 5 steps, where --max-steps 5 ends"),
        ({"spl": 0.5}, "spl 0.5 where success and the distances give 0.0"),
        ({"path": saved["path"] + 1.0}, "m where its positions give"),
        ({"failed_steps": 6}, "more failed steps or collisions than its 5 steps"),
    ):
        path.write_text(json.dumps({**old, **change}))
        reasons = {}
        assert read_row(path, task(5), [], reasons) is None and why in reasons[path], change
    path.write_text(json.dumps({**saved, "key": "0" * 64}))  # a key of other settings (options, noise, policy)
    reasons = {}
    assert read_row(path, task(5), [], reasons) is None and "its key differs" in reasons[path]
