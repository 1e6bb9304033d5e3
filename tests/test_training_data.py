"""odolab/sim/training_data.py: shards made once and resumed, refused when made otherwise, frames resized
with holes kept, windows of consecutive pairs, a damaged shard named when first read (checked once per
process)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from odolab.core.parallel import SERIAL
from odolab.sim import training_data as td
from odolab.sim.training_data import DataConfig, TrainingData, make_training_data, resize_frame
from tests.helpers import one_line_error

CFG = DataConfig(split="train", episodes=3, max_steps=6, width=40, height=24, episodes_per_shard=2)


@pytest.fixture(scope="module")
def folder(tmp_path_factory):
    root = tmp_path_factory.mktemp("data") / "train"
    make_training_data(CFG, root, execution=SERIAL)
    return root


def test_a_folder_lists_its_shards_and_counts(folder):
    doc = json.loads((folder / td.MANIFEST).read_text())
    assert len(doc["shards"]) == 2  # 3 episodes, 2 per shard
    data = TrainingData(folder)
    assert sum(data.counts().values()) == len(data) == sum(sum(s["pairs"].values()) for s in doc["shards"].values())
    assert data.config == CFG


def test_an_interrupted_run_makes_only_the_missing_shard(folder, monkeypatch):
    shards = sorted(folder.glob("shard-*.npz"))
    before = {p.name: p.read_bytes() for p in shards}
    shards[1].unlink()
    with pytest.raises(ValueError, match="1 of 2 shards missing"):
        TrainingData(folder)
    rendered = []
    real = td._render_shard
    monkeypatch.setattr(td, "_render_shard", lambda job: rendered.append(len(job[1])) or real(job))
    make_training_data(CFG, folder, execution=SERIAL)
    assert rendered == [1]  # the third episode only
    assert {p.name: p.read_bytes() for p in sorted(folder.glob("shard-*.npz"))} == before  # same bytes again


def test_a_folder_made_otherwise_is_refused(folder):
    with pytest.raises(ValueError, match=r"another config: width \(folder 40, asked 64\)"):
        make_training_data(
            DataConfig(split="train", episodes=3, max_steps=6, width=64, height=24, episodes_per_shard=2),
            folder,
            execution=SERIAL,
        )


def test_a_damaged_shard_or_manifest_is_named(folder, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(folder, copy)
    shard = min(copy.glob("shard-*.npz"))
    shard.write_bytes(b"garbage")
    with pytest.raises(ValueError, match=f"{shard.name}: unreadable shard"):
        TrainingData(copy)
    (copy / td.MANIFEST).write_text("{not json")
    with pytest.raises(ValueError, match="not a readable training-data manifest"):
        TrainingData(copy)
    with pytest.raises(ValueError, match="no dataset.json"):
        TrainingData(tmp_path)


def test_windows_are_runs_of_consecutive_pairs_of_one_episode(folder):
    data = TrainingData(folder)
    for length in (2, 3, 5):
        for k in data.windows(length):
            f = data.pairs[k]
            run = data.pairs[k : k + length - 1]
            assert np.array_equal(run, f + np.arange(length - 1))
            assert len(set(data.episode[f : f + length])) == 1
    assert len(data.windows(2)) == len(data)
    with pytest.raises(ValueError):
        data.windows(1)


def test_resize_keeps_holes_as_holes_and_averages_readings():
    depth = np.full((48, 80), 2.0, np.float32)
    depth[:, :40] = 0.0  # left half: no reading
    depth[:24, 60:] = 4.0
    depth[24:, 40:42] = 0.0  # a thin hole column: under half of each output pixel
    rgb = np.zeros((48, 80, 3), np.uint8)
    small_rgb, small = resize_frame(rgb, depth, 20, 12)
    assert small_rgb.shape == (12, 20, 3) and small.shape == (12, 20)
    assert np.all(small[:, :10] == 0)
    assert np.allclose(small[:6, 15:], 4.0) and np.allclose(small[6:, 10], 2.0)


def test_bad_data_configs_name_the_field():
    with pytest.raises(ValueError, match="split must be one of"):
        DataConfig(split="holdout")
    with pytest.raises(ValueError, match=r"episodes must be in \[1, 1000000\], got 0"):
        DataConfig(episodes=0)
    with pytest.raises(ValueError, match=r"episodes must be a whole number in \[1, 1000000\], got 1.5"):
        DataConfig(episodes=1.5)
    with pytest.raises(ValueError, match=r"width must be in \[1, 341\], got 400"):  # the camera's width
        DataConfig(width=400)
    with pytest.raises(ValueError, match="x.json: unknown field"):
        DataConfig.from_dict({"colour": 1}, "x.json")


def test_the_cli_makes_data_and_refuses_bad_options(tmp_path, capsys):
    from odolab.cli import run_cli
    from odolab.cli.training_data import main as make_data

    out = tmp_path / "d"
    args = [
        "--split",
        "val",
        "--episodes",
        "1",
        "--max-steps",
        "3",
        "--width",
        "32",
        "--height",
        "18",
        "--serial",
        "--out",
        str(out),
    ]
    assert run_cli(make_data, "python -m odolab.training_data", args) == 0
    assert "pairs" in capsys.readouterr().out
    assert run_cli(make_data, "python -m odolab.training_data", args[:-2] + ["--width", "500", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--width" in err and "Traceback" not in err


def test_a_killed_runs_leftovers_are_cleared_and_a_bad_manifest_named(folder, tmp_path):
    import shutil

    copy = tmp_path / "c"
    shutil.copytree(folder, copy)
    orphan = copy / ".shard-00001-abc.npz.xyz.tmp"
    orphan.write_bytes(b"half a shard")
    make_training_data(CFG, copy, execution=SERIAL)
    assert not orphan.exists()
    (copy / td.MANIFEST).write_text('{"format": 1, "shards": {}}')
    with pytest.raises(ValueError, match="no config or shards"):
        make_training_data(CFG, copy, execution=SERIAL)


@pytest.mark.slow
def test_a_second_maker_of_a_folder_waits_for_the_first(tmp_path, capsys):
    """Two runs sharing a data_root (two trainings, a study's rows) never render into one folder at
    once: the second waits while the first holds it, then finds the shards made."""
    import threading

    root = tmp_path / "d"
    root.mkdir()
    cfg = DataConfig(split="train", episodes=1, max_steps=4, width=40, height=24, episodes_per_shard=1)
    made: list[dict] = []
    with td.making(root):
        second = threading.Thread(target=lambda: made.append(make_training_data(cfg, root, execution=SERIAL)))
        second.start()
        second.join(timeout=3)
        assert second.is_alive() and not made  # waiting, nothing written
        assert not list(root.glob("shard-*"))
        assert "another process is making this data; waiting for it" in capsys.readouterr().err
        td._make(cfg, root, None, "boxes", SERIAL)  # the first maker's own work, the folder held
    second.join(timeout=60)
    assert not second.is_alive() and len(made[0]["shards"]) == 1


def test_a_hand_edited_config_is_named_as_such_not_as_missing_shards(folder, tmp_path):
    """Shard names come from the config: an edited dataset.json no longer names its shards, and the
    message says so instead of asking to make shards that are there."""
    import shutil

    copy = tmp_path / "edited"
    shutil.copytree(folder, copy)
    doc = json.loads((copy / td.MANIFEST).read_text())
    doc["config"]["width"] += 16
    (copy / td.MANIFEST).write_text(json.dumps(doc))
    with pytest.raises(ValueError, match="its config does not describe the shards it lists") as info:
        TrainingData(copy)
    assert "missing" not in str(info.value)


def test_a_manifest_naming_a_path_outside_its_folder_is_refused_and_nothing_is_deleted(folder, tmp_path):
    import shutil

    copy = tmp_path / "data"
    shutil.copytree(folder, copy)
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    doc = json.loads((copy / td.MANIFEST).read_text())
    for name in ("../victim.txt", str(victim)):
        doc["shards"] = {**{k: v for k, v in doc["shards"].items() if k.startswith("shard-")}, name: {"index": 9}}
        (copy / td.MANIFEST).write_text(json.dumps(doc))
        for call in (lambda: make_training_data(CFG, copy, execution=SERIAL), lambda: TrainingData(copy)):
            with pytest.raises(ValueError, match=r"field shards: expected shard file names .* got '"):
                call()
        assert victim.read_text() == "keep me"


def test_clean_depth_is_stored_beside_the_noisy_depth_of_the_same_frames(tmp_path):
    plain = DataConfig(split="train", episodes=1, max_steps=4, width=40, height=24)
    both = DataConfig(split="train", episodes=1, max_steps=4, width=40, height=24, clean_depth=True)
    assert plain.shard_name(0, plain.specs) != both.shard_name(0, both.specs)
    make_training_data(plain, tmp_path / "plain", execution=SERIAL)
    make_training_data(both, tmp_path / "both", execution=SERIAL)
    a, b = TrainingData(tmp_path / "plain"), TrainingData(tmp_path / "both")
    frames = np.arange(len(b.poses))
    rgb_a, depth_a = a.frames(frames)
    rgb_b, depth_b = b.frames(frames)
    assert np.array_equal(rgb_a, rgb_b) and np.array_equal(depth_a, depth_b)  # the same noisy frames
    clean = b.clean_depths(frames)
    assert clean.shape == depth_b.shape and (clean > 0).mean() > 0.5
    both_valid = (clean > 0) & (depth_b > 0)
    assert 0 < np.abs(clean - depth_b)[both_valid].mean() < 0.5  # noise, but the same scene
    with pytest.raises(ValueError, match="made without clean_depth"):
        a.clean_depths(frames)


@pytest.fixture(scope="module")
def shards(tmp_path_factory) -> Path:
    from odolab.sim.training_data import DataConfig, make_training_data

    root = tmp_path_factory.mktemp("data") / "train"
    make_training_data(
        DataConfig(split="train", episodes=2, max_steps=4, width=24, height=16, episodes_per_shard=1),
        root,
        execution=SERIAL,
    )
    return root


def _flip_a_frame_byte(shard: Path) -> None:
    from odolab.io.npz_mmap import mmap_npz_member

    offset = mmap_npz_member(shard, "rgb").offset + 5  # a pixel of the first frame: np.load never reads it
    data = bytearray(shard.read_bytes())
    data[offset] ^= 0x10
    shard.write_bytes(bytes(data))


@pytest.mark.parametrize("old", [False, True], ids=["checksum in the manifest", "shard made before checksums"])
def test_a_shard_with_a_flipped_byte_is_named_when_its_frames_are_first_read(shards, tmp_path, old):
    import json

    from odolab.sim.training_data import MANIFEST, DamagedShardError, TrainingData

    copy = tmp_path / "copy"
    shutil.copytree(shards, copy)
    doc = json.loads((copy / MANIFEST).read_text())
    assert all(isinstance(e["crc32"], int) for e in doc["shards"].values())  # written with each shard
    if old:
        for entry in doc["shards"].values():
            del entry["crc32"]
        (copy / MANIFEST).write_text(json.dumps(doc))
    data = TrainingData(copy)
    data.frames(np.arange(len(data.poses)))  # intact: read without complaint
    shard = copy / data.shards[0]
    _flip_a_frame_byte(shard)
    damaged = TrainingData(copy)  # the small arrays are intact: opening is not the check
    with pytest.raises(DamagedShardError, match=f"{shard.name}: damaged: "):
        damaged.frames(np.array([0]))


def test_a_shard_is_checked_once_per_process(shards, monkeypatch):
    from odolab.sim import training_data as td

    calls = []
    real = td.file_crc32
    monkeypatch.setattr(td, "file_crc32", lambda path, *a: calls.append(path) or real(path, *a))
    data = td.TrainingData(shards)
    for _ in range(3):
        data.pair_batch(np.arange(len(data)))
    assert sorted(calls) == sorted(shards / n for n in data.shards)  # each shard once, not once per batch
    import pickle

    worker = pickle.loads(pickle.dumps(data))  # a loader worker's copy keeps what was checked
    worker.frames(np.array([0]))
    assert len(calls) == len(data.shards)
    td.TrainingData(shards).frames(np.array([0]))  # a new opening checks again
    assert len(calls) == len(data.shards) + 1


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
