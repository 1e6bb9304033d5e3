"""Every recursion and every integer option is bounded before work starts: a hostile depth or size is
one clear line, never a RecursionError or an OverflowError after the work was done."""

from __future__ import annotations

import pytest

from tests.helpers import one_line_error


def _nested(depth: int, inner: str = "icp") -> str:
    name = inner
    for _ in range(depth):
        name = f"manhattan({name})"
    return name


@pytest.mark.parametrize("depth", [9, 400, 1000, 5000])
def test_composites_nested_too_deep_are_one_line_in_every_entry_point(depth):
    from odolab.odometry.odometer import inner_names, load_odometer, parse_odometer_list, unknown_odometer
    from odolab.reporting.comparison import ComparisonError, load_odometers, odometer_names

    name = _nested(depth)
    for call in (parse_odometer_list, load_odometer, inner_names, unknown_odometer):
        with pytest.raises(ValueError, match=f"nests composites {depth} deep; at most 8"):
            call(name)
    for call in (odometer_names, load_odometers):
        with pytest.raises(ComparisonError, match="at most 8"):
            call([name])


def test_a_deep_name_on_the_command_line_is_one_short_line(tmp_path):
    one_line_error(
        "odolab.compare",
        "--odometers",
        _nested(1000),
        "--episodes",
        "1",
        "--max-steps",
        "2",
        "--no-cache",
        "--out",
        tmp_path / "o",
        words="nests composites 1000 deep",
    )


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


@pytest.mark.parametrize(
    "args,words",
    [
        (["--first", str(2**31)], "--first must be in [0, 2147483647]"),
        (["--first", str(2**63)], "--first must be in [0, 2147483647]"),
        (["--first", str(2**31 - 1), "--episodes", "2"], "the last episode's index would be 2147483648"),
        (["--episodes", str(10**12)], "--episodes must be in [1, 1000000]"),
        (["--max-steps", str(2**40)], "--max-steps must be in [1, 500]"),
        (["--episodes-per-shard", str(2**40)], "--episodes-per-shard must be in [1, 1000]"),
        (["--seed", str(2**32)], "--seed must be in [0, 4294967295]"),
    ],
)
def test_training_data_integers_are_checked_before_rendering(tmp_path, args, words):
    one_line_error("odolab.training_data", *args, "--serial", "--out", tmp_path / "d", words=words)
    assert not (tmp_path / "d").exists()  # refused before any work


def test_a_training_data_config_refuses_an_episode_index_its_shards_cannot_store():
    from odolab.sim.training_data import DataConfig

    with pytest.raises(ValueError, match=r"first must be in \[0, 2147483646\]"):
        DataConfig(first=2**31 - 1, episodes=2)
    with pytest.raises(ValueError, match=r"max_steps must be in \[1, 500\]"):
        DataConfig(max_steps=10**9)


@pytest.mark.parametrize(
    "args,words",
    [
        (["--episodes", str(10**9)], "--episodes must be in [1, 1000]"),
        (["--iterations", str(10**12)], "--iterations must be in [1, 1000000]"),
        (["--seed", "-1"], "--seed must be in [0, 4294967295]"),
    ],
)
def test_the_example_trainer_checks_its_integers_first(args, words, capsys):
    pytest.importorskip("torch")
    from examples import tiny_learned

    with pytest.raises(SystemExit) as info:
        tiny_learned.main(args)
    assert info.value.code == 2 and words in capsys.readouterr().err


def test_json_nested_too_deeply_in_a_manifest_or_a_cache_file_is_damage_not_a_traceback(tmp_path, small_spec):
    import numpy as np

    from odolab.sim.episodes import EpisodeCache
    from odolab.sim.training_data import MANIFEST, TrainingData

    deep = "[" * 100_000 + "]" * 100_000
    (tmp_path / MANIFEST).write_text(deep)
    with pytest.raises(ValueError, match="not a readable training-data manifest"):
        TrainingData(tmp_path)
    cache = EpisodeCache(tmp_path / "cache")
    for info in (deep, "[1]"):  # too deep to read, and not an object
        path = cache.path(small_spec)
        path.parent.mkdir(parents=True, exist_ok=True)
        with open(path, "wb") as f:
            np.savez(f, info=np.array(info))
        assert not cache.has(small_spec) and not path.exists()  # discarded, to be made again
