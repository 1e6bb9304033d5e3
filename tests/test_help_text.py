"""odolab.cli.help_text: help in plain text, under the name the command was typed with."""

from __future__ import annotations

import argparse
import sys
import types

import pytest

from odolab.cli.help_text import PlainHelp, command_face, plain


@pytest.mark.parametrize(
    ("rest", "text"),
    [
        ("``python -m odolab.compare``: run odometers", "python -m odolab.compare: run odometers"),
        ("see :func:`odolab.api.run` and :class:`~odolab.config.Setting`", "see odolab.api.run and Setting"),
        (":doc:`the page <docs/x.md>`, `evo <https://github.com/MichaelGrupp/evo>`_", "the page, evo"),
        ("*as used* and **own**", "as used and own"),
        ("Layout of ``DIR``::", "Layout of DIR:"),
        ("x1e-2 * 3, train | val | test, fused(a,b), 50 %", "x1e-2 * 3, train | val | test, fused(a,b), 50 %"),
    ],
)
def test_plain_takes_the_markup_out(rest, text):
    assert plain(rest) == text


def _parser(**kwargs) -> PlainHelp:
    ap = PlainHelp(prog="python -m odolab.thing", description="``python -m odolab.thing``: does *it*", **kwargs)
    ap.add_argument("--out", help="the folder (:func:`odolab.io.owned.owned_path` checks it; default %(default)s)")
    return ap


@pytest.mark.parametrize("formatter", [argparse.HelpFormatter, argparse.RawDescriptionHelpFormatter])
def test_help_is_plain_text(formatter):
    text = _parser(formatter_class=formatter).format_help()
    assert "usage: python -m odolab.thing" in text and "python -m odolab.thing: does it" in text
    assert "owned_path checks it; default None" in " ".join(text.split())
    assert "``" not in text and ":func:" not in text and "*it*" not in text


def test_a_face_names_the_command_as_typed():
    with command_face("odolab thing"):
        text = _parser().format_help()
    assert text.startswith("usage: odolab thing [-h]") and "odolab thing: does it" in text
    assert "python -m" not in text
    assert _parser().format_usage().startswith("usage: python -m odolab.thing")  # the face ends with its block


def test_the_odolab_command_runs_a_subcommand_under_its_face(monkeypatch, capsys):
    from odolab.cli import commands

    def main(argv):
        print(_parser().format_usage(), end="")
        return 0

    monkeypatch.setitem(sys.modules, "odolab_fake_command", types.SimpleNamespace(main=main))
    monkeypatch.setitem(commands.COMMANDS, "thing", ("odolab.thing", "odolab_fake_command", "a test command"))
    assert commands.main(["thing"]) == 0
    assert capsys.readouterr().out.startswith("usage: odolab thing [-h]")


@pytest.mark.parametrize("name", ["compare", "navigate", "simcard"])
def test_odolab_subcommand_help_is_plain_and_names_the_odolab_face(name, capsys):
    from odolab.cli.commands import main

    with pytest.raises(SystemExit) as exit_:
        main([name, "--help"])
    assert exit_.value.code == 0
    text = capsys.readouterr().out
    assert text.startswith(f"usage: odolab {name} ") and "python -m odolab." not in text.split("\n\n")[1]
    assert "``" not in text and not any(f":{role}:`" in text for role in ("func", "class", "mod", "data"))
