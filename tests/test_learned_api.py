"""What a learned odometer needs from odolab.api: specs, true motions, a pair dataset with random
access that maps (not loads) the cached episodes, and per-odometer options from the command line."""

import pickle

import numpy as np
import pytest

from odolab import api
from odolab.cli import run_cli
from odolab.compare import main
from odolab.core.parallel import SERIAL
from odolab.io.npz_mmap import mmap_npz_member
from odolab.odometry.options import OptionError, parse_assignments, read_options_file
from odolab.sim.camera import CameraSpec


@pytest.fixture(scope="module")
def cached(tmp_path_factory):
    root = tmp_path_factory.mktemp("cache")
    specs = [
        api.EpisodeSpec(split="train", index=i, max_steps=8, camera=CameraSpec(width=64, height=36)) for i in range(2)
    ]
    cache = api.EpisodeCache(root)
    api.generate_episodes(specs, cache, execution=SERIAL)
    return specs, cache


def test_episode_specs_are_deterministic_and_split_apart():
    a = api.episode_specs("train", 3, seed=2, max_steps=10)
    assert a == api.episode_specs("train", 3, seed=2, max_steps=10)
    assert [s.index for s in a] == [0, 1, 2] and {s.split for s in a} == {"train"}
    assert {s.key() for s in a}.isdisjoint(s.key() for s in api.episode_specs("val", 3, seed=2, max_steps=10))
    assert set(api.SPLITS) == {"train", "val", "test"}


def test_pair_dataset_gives_the_frames_and_true_motion_of_each_pair(cached):
    specs, cache = cached
    ds = api.PairDataset(specs, cache)
    episodes = [cache.get(s) for s in specs]
    assert len(ds) == sum(len(e) - 1 for e in episodes)
    for k in (0, len(episodes[0]) - 2, len(episodes[0]) - 1, len(ds) - 1):  # both sides of the boundary
        e, i = ds.locate(k)
        pair, ep = ds[k], episodes[e]
        assert np.array_equal(pair.prev.rgb, ep.rgb[i]) and np.array_equal(pair.cur.depth, ep.depth[i + 1])
        assert pair.action == ep.action(i)
        assert np.allclose(pair.motion, api.true_motions(ep)[i])
        assert np.allclose(pair.planar, api.transform_to_planar(api.true_motions(ep)[i]))
    assert np.allclose(ds[-1].motion, ds[len(ds) - 1].motion)
    with pytest.raises(IndexError):
        ds[len(ds)]


def test_pair_dataset_maps_the_frames_instead_of_loading_them(cached, monkeypatch):
    specs, cache = cached
    rgb = mmap_npz_member(cache.path(specs[0]), "rgb")
    assert isinstance(rgb, np.memmap) and np.array_equal(rgb, cache.get(specs[0]).rgb)
    ds = api.PairDataset(specs, cache)
    real_load = np.load

    def guarded_load(*args, **kw):  # reading a frame member through np.load would load every frame
        archive = real_load(*args, **kw)
        original = type(archive).__getitem__

        class Guard(type(archive)):
            def __getitem__(self, key):
                assert key not in ("rgb", "depth"), f"{key} loaded whole"
                return original(self, key)

        archive.__class__ = Guard
        return archive

    monkeypatch.setattr(np, "load", guarded_load)
    pair = ds[3]
    assert pair.prev.rgb.shape == (36, 64, 3) and pair.prev.rgb.flags.writeable
    clone = pickle.loads(pickle.dumps(ds))  # data-loader workers get a picklable dataset
    assert np.array_equal(clone[3].cur.depth, pair.cur.depth)


def test_pair_dataset_names_a_missing_episode(cached, tmp_path):
    specs, _ = cached
    with pytest.raises(ValueError, match="not in the cache"):
        api.PairDataset(specs, api.EpisodeCache(tmp_path))


def test_compressed_members_are_refused_with_the_file_name(tmp_path):
    path = tmp_path / "c.npz"
    np.savez_compressed(path, rgb=np.zeros((2, 3)))
    with pytest.raises(ValueError, match="compressed"):
        mmap_npz_member(path, "rgb")


def test_option_assignments_parse_toml_values_and_plain_text():
    opts = parse_assignments(["icp.max_depth=4.5", "a.b:C.flag=true", "a.b:C.path=runs/x.pt", 'n.s="q"'])
    assert opts == {"icp": {"max_depth": 4.5}, "a.b:C": {"flag": True, "path": "runs/x.pt"}, "n": {"s": "q"}}
    with pytest.raises(OptionError, match="expected NAME.key=value"):
        parse_assignments(["nodot=1"])


def test_options_file_is_toml_and_strict(tmp_path):
    good = tmp_path / "o.toml"
    good.write_text('[odometers."action-prior"]\n')
    assert read_options_file(good) == {"action-prior": {}}
    bad = tmp_path / "b.toml"
    bad.write_text("odometers = 3\nother = 1\n")
    with pytest.raises(OptionError, match="unknown top-level key 'other'"):
        read_options_file(bad)


class Scaled(api.Odometer):
    """Forward by ``step`` metres (an option)."""

    def __init__(self, step: float = 0.25):
        if not 0 < step < 1:
            raise ValueError(f"step must be in (0, 1) m, got {step}")
        self.step_m = step

    def step(self, prev, cur, action):
        return api.Estimate.from_planar(0.0, self.step_m, 0.0)


BASE = ["--episodes", "1", "--max-steps", "6", "--serial", "--quiet", "--no-cache"]


def test_compare_passes_options_to_the_constructor(tmp_path):
    import csv

    api.register_odometer("scaled", Scaled)
    api.register_odometer("scaled-too", Scaled)
    cached = ["--episodes", "1", "--max-steps", "6", "--serial", "--quiet", "--cache", str(tmp_path / "cache")]

    def dz(out):
        return {r["odometer"]: float(r["dz"]) for r in csv.DictReader(open(out / "table.csv"))}

    # each odometer gets its own options
    assert (
        run_cli(
            main,
            "odolab.compare",
            [
                "--odometers",
                "scaled,scaled-too",
                "--odometer-option",
                "scaled.step=0.1",
                "--odometer-option",
                "scaled-too.step=0.3",
                *cached,
                "--out",
                str(tmp_path / "cli"),
            ],
        )
        == 0
    )
    by_cli = dz(tmp_path / "cli")
    assert by_cli["scaled"] != by_cli["scaled-too"]
    # a TOML file gives the same, and the command line overrides it
    cfg = tmp_path / "opts.toml"
    cfg.write_text('[odometers.scaled]\nstep = 0.3\n\n[odometers."scaled-too"]\nstep = 0.5\n')
    assert (
        run_cli(
            main,
            "odolab.compare",
            [
                "--odometers",
                "scaled,scaled-too",
                "--config",
                str(cfg),
                "--odometer-option",
                "scaled-too.step=0.1",
                *cached,
                "--out",
                str(tmp_path / "file"),
            ],
        )
        == 0
    )
    by_file = dz(tmp_path / "file")
    assert by_file == {"scaled": by_cli["scaled-too"], "scaled-too": by_cli["scaled"]}


@pytest.mark.parametrize(
    "args,words",
    [
        (
            ["--odometers", "action-prior", "--odometer-option", "action-prior.nope=1"],
            "odometer 'action-prior' has no option 'nope'; it accepts: prior",
        ),
        (
            ["--odometers", "action-prior", "--odometer-option", "icp.max_depth=1"],
            "options given for 'icp', which is not among the odometers",
        ),
        (["--odometers", "action-prior", "--odometer-option", "garbage"], "expected NAME.key=value"),
        (
            [
                "--odometers",
                "examples.nominal_motion:NominalMotion",
                "--odometer-option",
                "examples.nominal_motion:NominalMotion.speed=2",
            ],
            "has no option 'speed'",
        ),
        (["--config", "/nonexistent/o.toml"], "/nonexistent/o.toml: no such options file"),
        (
            ["--odometers", "icp", "--odometer-option", "icp.max_depth=abc"],
            "odometer 'icp' option max_depth: expected a number, got 'abc'",
        ),
        (
            ["--odometers", "icp", "--odometer-option", "icp.max_iterations=2.5"],
            "odometer 'icp' option max_iterations: expected an integer, got 2.5",
        ),
        (["--odometers", "icp", "--odometer-option", "icp.max_depth=true"], "expected a number, got True"),
    ],
)
def test_bad_options_are_one_line(args, words, tmp_path, capsys):
    assert run_cli(main, "python -m odolab.compare", [*args, *BASE, "--out", str(tmp_path)]) == 2
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("python -m odolab.compare: error: ") and words in lines[0], lines


def test_a_bad_option_value_is_one_line(tmp_path):
    api.register_odometer("scaled", Scaled)
    with pytest.raises(Exception) as info:
        main(["--odometers", "scaled", "--odometer-option", "scaled.step=7", *BASE, "--out", str(tmp_path)])
    assert "could not load odometer 'scaled'" in str(info.value) and "step must be in (0, 1) m, got 7" in str(
        info.value
    )


def test_every_public_name_of_the_api_resolves():
    assert [n for n in api.__all__ if getattr(api, n, None) is None] == []
    with pytest.raises(AttributeError):
        _ = api.no_such_name


def test_a_bad_value_from_an_options_file_names_the_file(tmp_path, capsys):
    api.register_odometer("scaled", Scaled)
    cfg = tmp_path / "opts.toml"
    cfg.write_text("[odometers.scaled]\nstep = 7\n")
    assert (
        run_cli(
            main,
            "odolab.compare",
            ["--odometers", "scaled", "--config", str(cfg), *BASE, "--out", str(tmp_path / "out")],
        )
        == 2
    )
    line = capsys.readouterr().err.strip()
    assert "step must be in (0, 1) m, got 7" in line and line.split(": error: ")[1].startswith(
        f"options from --config {cfg}: "
    )


def test_numpy_scalars_set_options_as_the_numbers_they_hold():
    import numpy as np

    from odolab.odometry.options import check_options

    check_options("scaled", Scaled, {"step": np.float32(0.5)})  # accepted, as 0.5 is
    with pytest.raises(OptionError, match="expected a number"):
        check_options("scaled", Scaled, {"step": np.bool_(True)})
    odo = api.load_odometer("manhattan(action-prior)", anchor_steps=np.int64(3), min_support=np.float32(0.5))
    assert odo.anchor_steps == 3 and type(odo.anchor_steps) is int
    same = api.load_odometer("manhattan(action-prior)", anchor_steps=3, min_support=0.5)
    assert odo.identity_digest == same.identity_digest


def test_a_named_default_is_not_a_change_of_settings():
    from odolab.odometry.options import without_defaults

    assert without_defaults(Scaled, {"step": 0.25}) == {}
    assert without_defaults(Scaled, {"step": 0.3}) == {"step": 0.3}
    odo = api.load_odometer("manhattan(action-prior)")
    assert (
        api.load_odometer("manhattan(action-prior)", wall_sigma_deg=1).identity_digest == odo.identity_digest
    )  # 1 as 1.0
