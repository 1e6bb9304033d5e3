"""odolab.config: fields that carry their range and description, one check, one builder, key=value."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np
import pytest

from odolab.config import ConfigError, assign, build, check, choices, describe, from_toml, range_text, setting
from odolab.core.errors import InputError


@dataclass(frozen=True)
class Example:
    cell: float = setting(0.05, range=(0.02, 1.0), doc="map cell edge, m")
    stride: int = setting(4, range=(1, 64), doc="every n-th pixel")
    speed: float = setting(0.5, range=(0.0, 1.0), open_low=True, doc="relative speed")
    reach: float | None = setting(None, range=(0.0, 10.0), doc="None: unbounded")
    name: str = setting("x", doc="a label")

    def __post_init__(self) -> None:
        check(self)


class ExampleError(InputError):
    subject = "example"


def test_ranges_and_kinds_are_checked_with_one_line():
    for bad, said in (
        ({"cell": "0.1"}, "cell must be a number in [0.02, 1], got '0.1'"),
        ({"cell": True}, "cell must be a number in [0.02, 1], got True"),
        ({"cell": float("nan")}, "cell must be a number in [0.02, 1], got nan"),
        ({"cell": float("inf")}, "cell must be in [0.02, 1], got inf"),
        ({"cell": 5}, "cell must be in [0.02, 1], got 5"),
        ({"stride": 4.0}, "stride must be a whole number in [1, 64], got 4.0"),
        ({"stride": 10**400}, "stride must be in [1, 64], got an integer of about 401 digits"),
        ({"speed": 0}, "speed must be in (0, 1], got 0"),
    ):
        with pytest.raises(ValueError) as info:
            Example(**bad)
        assert str(info.value).startswith(said), (bad, str(info.value))
    cfg = Example(cell=np.float32(0.25), stride=np.int64(8), speed=1, reach=None)
    assert type(cfg.cell) is float and type(cfg.stride) is int and type(cfg.speed) is float
    assert str(Example(speed=-0.0 + 1.0, cell=0.02).cell) == "0.02"
    assert range_text(Example, "speed") == "(0, 1]" and range_text(Example, "stride") == "[1, 64]"


def test_metadata_leaves_the_contents_as_they_were():
    assert dataclasses.asdict(Example()) == {"cell": 0.05, "stride": 4, "speed": 0.5, "reach": None, "name": "x"}
    rows = describe(Example)
    assert [(r.name, r.value, r.range, r.doc) for r in rows][:2] == [
        ("cell", 0.05, "[0.02, 1]", "map cell edge, m"),
        ("stride", 4, "[1, 64]", "every n-th pixel"),
    ]
    assert describe(Example(stride=2))[1].value == 2 and rows[-1].range == ""


def test_built_from_toml_and_key_value_changes(tmp_path):
    base = tmp_path / "base.toml"
    base.write_text("cell = 0.1\nstride = 2\n")
    child = tmp_path / "child.toml"
    child.write_text('base = "base.toml"\nstride = 8\n')
    assert from_toml(Example, child) == Example(cell=0.1, stride=8)
    child.write_text('base = "base.toml"\nchanges = ["stride=16", "cell=0.5"]\nstride = 8\n')
    assert from_toml(Example, child) == Example(cell=0.5, stride=16)  # after the merge, in order
    for changes, said in (
        ('"stride"', "changes: expected a list"),
        ('["stride"]', "changes: 'stride': expected path=value"),
    ):
        child.write_text(f'base = "base.toml"\nchanges = {changes}\n')
        with pytest.raises(ConfigError, match=f"child.toml: {said}"):
            from_toml(Example, child)
    with pytest.raises(ConfigError, match=r"f: unknown field\(s\) bogus"):
        build(Example, {"bogus": 1}, "f")
    with pytest.raises(ConfigError, match=r"f: stride must be in \[1, 64\], got 0"):
        build(Example, {"stride": 0}, "f")
    assert assign(Example, ["stride=8", "name=y", "cell=1"]) == Example(cell=1.0, stride=8, name="y")
    for items, said in (
        (["stride=1.5"], "example 'stride=1.5': stride takes a whole number in [1, 64]"),
        (["stride=1_0"], "example 'stride=1_0': stride takes a whole number in [1, 64]"),
        (["cell=nan"], "example 'cell=nan': cell must be in [0.02, 1], got nan"),
        (["stride=2", "stride=3"], "example 'stride=3': stride is given twice"),
        (
            ["nope=1"],
            "example 'nope=1': unknown key 'nope'; expected key=value with key one of cell, stride, speed, reach, name",
        ),
        (["stride"], "example 'stride': expected key=value with key one of cell, stride, speed, reach, name"),
        (["name=[1]"], "example 'name=[1]': name: expected str, got [1]"),
    ):
        with pytest.raises(ExampleError) as info:
            assign(Example, items, error=ExampleError)
        assert str(info.value) == said
    with pytest.raises(ConfigError, match="stride takes"):
        assign(Example, ["stride=x"])


@dataclass(frozen=True)
class Choosing:
    precision: Literal["auto", "fp32", "bf16"] = setting("auto", doc="numeric precision")
    workers: int | Literal["auto"] = setting("auto", range=(0, 64), doc="batch-making processes")
    mode: Literal[1, 2] | None = setting(None, doc="None: off")

    def __post_init__(self) -> None:
        check(self, "c: ")


def test_literal_choices_are_checked_described_built_and_assigned(tmp_path):
    assert Choosing(precision="bf16", workers=np.int64(3), mode=2).workers == 3
    assert Choosing(workers="auto") == Choosing() and dataclasses.asdict(Choosing())["workers"] == "auto"
    for bad, said in (
        ({"precision": "fp16"}, "c: precision must be one of 'auto', 'fp32', 'bf16', got 'fp16'"),
        ({"workers": -1}, "c: workers must be 'auto' or in [0, 64], got -1"),
        ({"workers": "many"}, "c: workers must be 'auto' or a whole number in [0, 64], got 'many'"),
        ({"workers": True}, "c: workers must be 'auto' or a whole number in [0, 64], got True"),
        ({"mode": True}, "c: mode must be one of 1, 2, got True"),  # True == 1, but no choice
        ({"mode": 1.0}, "c: mode must be one of 1, 2, got 1.0"),
    ):
        with pytest.raises(ValueError) as info:
            Choosing(**bad)
        assert str(info.value) == said
    assert [(r.name, r.range) for r in describe(Choosing)] == [
        ("precision", "one of 'auto', 'fp32', 'bf16'"),
        ("workers", "'auto' or [0, 64]"),
        ("mode", "one of 1, 2"),
    ]
    assert choices(Choosing, "workers") == ("auto",) and choices(Example(), "cell") == ()
    assert build(Choosing, {"workers": 2, "precision": "fp32"}, "f") == Choosing(precision="fp32", workers=2)
    with pytest.raises(ConfigError, match=r"f: precision: expected one of 'auto', 'fp32', 'bf16', got 'fp16'"):
        build(Choosing, {"precision": "fp16"}, "f")
    assert assign(Choosing, ["workers=auto", "precision=fp32"]) == Choosing(precision="fp32")
    assert assign(Choosing, ['workers="auto"']).workers == "auto" and assign(Choosing, ["workers=8"]).workers == 8
    for items, said in (
        (["workers=x"], "'workers=x': workers takes 'auto' or a whole number in [0, 64]"),
        (["workers=65"], "'workers=65': workers must be 'auto' or in [0, 64], got 65"),
    ):
        with pytest.raises(ConfigError) as info:
            assign(Choosing, items)
        assert str(info.value) == said


def test_change_document_sets_dotted_paths_and_leaves_the_original_alone():
    from odolab.config import ChangeError, change_document

    doc = {"seed": 0, "model": {"width": 170}, "stages": [{"name": "forward", "lr": 1e-3}, {"name": "turns"}]}
    out = change_document(
        doc, ["seed=3", "model.width=341", "stages.turns.lr=2e-4", "stages.0.epochs=2", "new.key=true", "tag=x y"]
    )
    assert out == {
        "seed": 3,
        "model": {"width": 341},
        "stages": [{"name": "forward", "lr": 1e-3, "epochs": 2}, {"name": "turns", "lr": 2e-4}],
        "new": {"key": True},
        "tag": "x y",
    }
    assert doc["model"]["width"] == 170 and "lr" not in doc["stages"][1]
    for bad in ("=1", "a..b=1", "seed.x=1", "stages=[1]", "stages.2.lr=1", "stages.x.lr=1", "stages.0=1"):
        if bad == "stages=[1]":
            assert change_document(doc, [bad])["stages"] == [1]  # a whole value is replaced; build judges it
            continue
        with pytest.raises(ChangeError) as info:
            change_document(doc, [bad])
        assert str(info.value).startswith(repr(bad))


def test_a_refused_change_among_several_is_the_one_named(tmp_path):
    """The message's ``stages[0].lr`` is the change ``stages.forward.lr``: that change alone is named."""
    from odolab.config import ChangeError
    from odolab.learned.robust_vo.config import TrainConfig

    recipe = Path(__file__).resolve().parents[1] / "studies" / "robust_vo" / "shipped.toml"
    for changes, named in (
        (["seed=1", "stages.forward.lr=abc"], "'stages.forward.lr=abc': stages[0].lr: expected a number"),
        (["stages.1.lr=abc", "seed=2"], "'stages.1.lr=abc': stages[1].lr: expected a number"),
        (["stages.forward.lr=5", "stages.forward.epochs=3"], "'stages.forward.lr=5': stages[0]: stage 'forward': lr"),
        (["model.dropout=5", "model.hidden=256"], "'model.dropout=5': model: dropout must be in"),
        (["seed=1", "model.width=100"], "'model.width=100': train data is 170 x 96 px"),
    ):
        with pytest.raises(ChangeError) as info:
            from_toml(TrainConfig, recipe, changes)
        assert str(info.value).startswith(named), str(info.value)


def test_a_bad_value_in_a_base_file_names_that_file(tmp_path):
    from odolab.learned.robust_vo.config import TrainConfig

    shipped = Path(__file__).resolve().parents[1] / "studies" / "robust_vo" / "shipped.toml"
    (tmp_path / "bad.toml").write_text(f'base = "{shipped}"\n[model]\ndropout = "x"\n')
    (tmp_path / "child.toml").write_text('base = "bad.toml"\nseed = 3\n')
    with pytest.raises(
        ConfigError, match=r"bad.toml: model.dropout: expected a number, got 'x' \(a base of .*child.toml\)"
    ):
        from_toml(TrainConfig, tmp_path / "child.toml")
    (tmp_path / "child.toml").write_text('base = "bad.toml"\n[model]\ndropout = "y"\n')  # the child's own value
    with pytest.raises(ConfigError, match=r"child.toml: model.dropout: expected a number, got 'y'$"):
        from_toml(TrainConfig, tmp_path / "child.toml")


def test_a_linked_recipe_takes_its_base_beside_the_file_it_links_to(tmp_path):
    from odolab.learned.robust_vo.config import TrainConfig

    recipe = Path(__file__).resolve().parents[1] / "studies" / "robust_vo" / "ablations" / "no-dropout.toml"
    (tmp_path / "links").mkdir()
    (tmp_path / "links" / "r.toml").symlink_to(recipe)
    (tmp_path / "shipped.toml").write_text("seed = 99\n")  # where '../shipped.toml' would be beside the link
    assert from_toml(TrainConfig, tmp_path / "links" / "r.toml") == from_toml(TrainConfig, recipe)


def test_a_list_setting_checks_each_item_its_length_and_repeats():
    """A list field's range holds for each item; min_items and distinct for the list (build names the place)."""
    from dataclasses import dataclass

    from odolab.config import ConfigError, build, check, setting

    @dataclass(frozen=True)
    class Seeds:
        seeds: tuple[int, ...] = setting(range=(0, 9), min_items=1, distinct=True)
        levels: tuple[float, ...] = setting((1.0,), range=(0.0, 10.0))

        def __post_init__(self):
            check(self)

    assert build(Seeds, {"seeds": [0, 9]}, "f.toml: s").seeds == (0, 9)
    for doc, said in [
        ({"seeds": []}, "f.toml: s: seeds must hold at least 1 item, got []"),
        ({"seeds": [3, 3]}, "f.toml: s: seeds must hold no value twice, got [3, 3]"),
        ({"seeds": [0, 10]}, "f.toml: s: seeds[1] must be a whole number in [0, 9], got 10"),
        ({"seeds": [0], "levels": [float("nan")]}, "f.toml: s: levels[0] must be a number in [0, 10], got nan"),
    ]:
        with pytest.raises(ConfigError) as exc:
            build(Seeds, doc, "f.toml: s")
        assert str(exc.value) == said


def test_a_base_chain_too_long_is_one_line(tmp_path):
    from odolab.learned.training.configs import MAX_BASE_CHAIN, ConfigError, read_toml

    for i in range(1000):
        (tmp_path / f"r{i}.toml").write_text(f'base = "r{i + 1}.toml"\n' if i < 999 else "x = 1\n")
    with pytest.raises(ConfigError, match=f"chain of {MAX_BASE_CHAIN} base files"):
        read_toml(tmp_path / "r0.toml")
    (tmp_path / "r10.toml").write_text("x = 2\n")  # a chain of 10: fine
    assert read_toml(tmp_path / "r0.toml") == {"x": 2}


def test_tables_nested_too_deep_to_merge_are_one_line(tmp_path):
    from odolab.learned.training.configs import ConfigError, read_toml

    deep = ".".join(["t"] * 2000)
    (tmp_path / "base.toml").write_text(f"{deep} = 1\n")
    (tmp_path / "top.toml").write_text(f'base = "base.toml"\n{deep} = 2\n')
    with pytest.raises(ConfigError, match="top.toml: t.t.*tables nested more than 32 deep"):
        read_toml(tmp_path / "top.toml")
