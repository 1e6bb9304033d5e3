"""odolab/odometry/action_prior.py and ``python -m odolab.action_prior``: bounded options, refused out paths, and
prior files that are pipes, repeat a key or hold bad fields named in one line."""

from __future__ import annotations

import os

import pytest

from odolab.cli import run_cli
from tests.helpers import one_line_error, refused_option


@pytest.mark.parametrize(
    "args,words",
    [
        (["--seed", "-5"], "--seed must be in"),
        (["--episodes", "1e9"], "--episodes must be an integer"),
        (["--episodes", "100000000"], "--episodes must be in"),
        (["--max-steps", "0"], "--max-steps must be in"),
    ],
)
def test_action_prior_numeric_options_have_ranges(args, words):
    one_line_error("odolab.action_prior", *args, words=words)


def test_action_prior_refuses_a_prior_of_nothing_and_odd_out_paths(tmp_path):
    one_line_error("odolab.action_prior", "--episodes", "1", "--max-steps", "1", words="a mean of nothing is no prior")
    one_line_error("odolab.action_prior", "--out", tmp_path / "missing" / "x.json", words="does not exist")
    assert not (tmp_path / "missing").exists()
    afile = tmp_path / "afile"
    afile.write_text("")
    one_line_error("odolab.action_prior", "--out", afile / "x.json", words="is a file, not a folder")


def test_an_action_prior_file_that_is_a_pipe_or_repeats_a_key_is_one_line(tmp_path):
    """A pipe would block the reader for ever, and JSON keeps the last of two equal keys silently."""
    fifo = tmp_path / "prior.fifo"
    os.mkfifo(fifo)
    twice = tmp_path / "twice.json"
    twice.write_text('{"means": {"move_forward": [0, 0, 0]}, "means": {}, "samples": {}}')
    for path, words in [(fifo, "is a pipe, device or socket"), (twice, "key 'means' appears twice")]:
        refused_option(tmp_path, "action-prior", f"action-prior.prior={path}", words=words)


@pytest.mark.parametrize(
    "change,words",
    [
        ({"means": [[0, 0.25, 0]]}, "'means' must be an object mapping each of move_forward"),
        ({"samples": "x"}, "'samples' must be an object"),
        ({"means": {"move_forward": "123"}}, "means.move_forward: expected [dx m, dz m, dyaw rad]"),
        ({"means": {"move_forward": [0, 1000, 0]}}, "means.move_forward: expected"),
        ({"means": {"turn_left": None}}, "means.turn_left: expected"),
        ({"means": {"move_forward": [0, 0.25, 0]}, "drop": "turn_left"}, "means: no value for 'turn_left'"),
        ({"means": {"stop": [0, 0, 0]}}, "means: unknown action 'stop'"),
        ({"samples": {"turn_left": -5}}, "samples.turn_left: expected a whole number >= 0"),
        ({"samples": {"turn_left": True}}, "samples.turn_left: expected a whole number >= 0"),
    ],
)
def test_an_action_prior_file_with_bad_fields_names_the_field(tmp_path, change, words):
    import json

    from odolab.odometry.action_prior import ActionPrior

    doc = ActionPrior.shipped().to_json()
    for field in ("means", "samples"):
        if field in change:
            doc[field] = {**doc[field], **change[field]} if isinstance(change[field], dict) else change[field]
    if "drop" in change:
        del doc["means"][change["drop"]]
    path = tmp_path / "prior.json"
    path.write_text(json.dumps(doc))
    refused_option(tmp_path, "action-prior", f"action-prior.prior={path}", words=words)


def test_an_output_file_that_is_a_link_to_nothing_is_refused_before_work(tmp_path, capsys):
    """``action_prior --out dead`` (dead -> /somewhere/new) wrote a file wherever the link pointed."""
    from odolab.cli.action_prior import main

    dead = tmp_path / "dead.json"
    dead.symlink_to(tmp_path / "elsewhere" / "created.json")
    argv = ["--episodes", "1", "--max-steps", "5", "--out", str(dead)]
    assert run_cli(main, "python -m odolab.action_prior", argv) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "is a link to nothing" in err and "--out" in err
    assert not (tmp_path / "elsewhere").exists()


def test_out_replaces_only_an_action_prior(tmp_path):
    """--out writes JSON: a recipe or another JSON file given by mistake is refused, untouched."""
    recipe, other = tmp_path / "recipe.toml", tmp_path / "other.json"
    recipe.write_text("x = 1\n")
    other.write_text('{"a": 1}')
    one_line_error("odolab.action_prior", "--out", recipe, words="unknown file type '.toml'")
    one_line_error("odolab.action_prior", "--out", other, words="found a file of another kind")
    assert recipe.read_text() == "x = 1\n" and other.read_text() == '{"a": 1}'
