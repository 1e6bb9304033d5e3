"""odolab/odometry/options.py: per-odometer options from ``--odometer-option`` and ``--config`` files; unknown,
repeated, too long or too deeply nested values, files that are no option tables and absurd integer
options are one line, refused before any folder is made."""

from __future__ import annotations

import pytest

from odolab.cli import run_cli
from tests.helpers import compare_refused, one_line_error, refused_option


@pytest.mark.parametrize(
    ("module", "option", "words"),
    [
        ("odolab.compare", "icp.max_depth=-1", "max_depth must be in"),
        ("odolab.navigate", "icp.bogus=1", "has no option 'bogus'"),
        ("odolab.compare", "icp.max_dept=3", "has no option 'max_dept' (did you mean 'max_depth'"),
    ],
)
def test_a_bad_odometer_option_is_refused_before_the_out_folder_is_made(tmp_path, module, option, words):
    one_line_error(module, "--odometers", "icp", "--odometer-option", option, "--out", tmp_path / "o", words=words)
    assert not (tmp_path / "o").exists()


def test_config_files_that_are_not_option_tables_are_one_line(tmp_path):
    bad = tmp_path / "bad.toml"
    bad.write_text("odometers = 5\n")
    one_line_error("odolab.compare", "--config", bad, "--out", tmp_path / "o", words="odometers must be a table")
    bad.write_bytes(b"\x90\xff\x00garbage")
    one_line_error("odolab.compare", "--config", bad, "--out", tmp_path / "o", words="not valid TOML")


def test_absurd_thread_counts_are_refused_not_crashed_on():
    import numpy as np
    import pytest

    from odolab.api import load_odometer

    for name in ("robust-vo", "deepvo"):
        for bad in (100000, np.inf, np.nan, 2.5, True, "3"):
            with pytest.raises(ValueError, match=r"threads must be (an integer|a whole number|int\b|in \[1, 256\])"):
                load_odometer(name, threads=bad)
    for key in ("mc_samples", "batch_size", "seed"):  # named, with what it takes
        with pytest.raises(ValueError, match=f"{key} must be (an integer|a whole number|int\\b)"):
            load_odometer("robust-vo", **{key: np.nan})
    with pytest.raises(ValueError, match="mirror_tta must be (true or false|bool)"):
        load_odometer("robust-vo", mirror_tta="yes")


def test_numbers_too_long_to_read_are_one_line_errors(tmp_path):
    big = "9" * 5000
    refused_option(tmp_path, "action-prior", f"action-prior.x={big}", words="action-prior.x: a number too long to read")
    cfg = tmp_path / "big.toml"
    cfg.write_text(f'[odometers."action-prior"]\nx = {big}\n')
    one_line_error(
        "odolab.compare",
        "--config",
        cfg,
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--no-cache",
        "--out",
        tmp_path / "o2",
        words=f"{cfg}: holds a number too long to read",
    )
    from odolab.learned.robust_vo.config import load_train_config
    from odolab.learned.training import ConfigError

    with pytest.raises(ConfigError, match="holds a number too long to read"):
        load_train_config(str(cfg))


def test_an_option_given_twice_is_refused(tmp_path):
    compare_refused(
        tmp_path,
        "--odometers",
        "open3d-rgbd",
        "--odometer-option",
        "open3d-rgbd.term=hybrid",
        "--odometer-option",
        "open3d-rgbd.term=color",
        words="open3d-rgbd.term is given twice",
    )


def test_a_deeply_nested_options_file_and_a_huge_option_are_short_lines(tmp_path, capsys):
    deep = tmp_path / "deep.toml"
    deep.write_text('[odometers."open3d-rgbd"]\nfallback_iterations = ' + "[" * 3000 + "]" * 3000 + "\n")
    compare_refused(tmp_path, "--odometers", "open3d-rgbd", "--config", deep, words="holds a value nested too deeply")
    huge = "[" + ",".join(["5"] * 20000) + "]"  # the odometer's message cuts the value; the loader's did not
    from odolab.reporting.pipeline import ComparisonError, load_odometers

    with pytest.raises(ComparisonError) as info:
        load_odometers(["open3d-rgbd"], {"open3d-rgbd": {"fallback_iterations": [5] * 20000}})
    assert len(str(info.value)) < 500 and "fallback_iterations" in str(info.value)
    assert len(huge) > 30000


@pytest.mark.parametrize("command", ["compare", "navigate"])
def test_an_unusable_options_file_is_named_under_config(tmp_path, capsys, command):
    """'--config DIR' read '/x: is a folder; ...' without the option's name."""
    import importlib

    main = importlib.import_module(f"odolab.cli.{command}").main
    (tmp_path / "bad.toml").write_text("[odometers.icp\n")
    for path, words in [(tmp_path, "is a folder"), (tmp_path / "none.toml", "no such"), (tmp_path / "bad.toml", "")]:
        argv = ["--config", str(path), "--episodes", "1", "--max-steps", "5", "--out", str(tmp_path / "out")]
        assert run_cli(main, f"python -m odolab.{command}", argv) == 2
        err = capsys.readouterr().err.strip()
        assert len(err.splitlines()) == 1 and f"error: --config {path}" in err and words in err, err
