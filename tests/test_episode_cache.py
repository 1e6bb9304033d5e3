"""EpisodeCache (odolab.sim.episodes) against hostile disks (issue 56): links in an entry's place, the
temporary files of killed writers, a full disk and a read-only cache; a damaged entry named and made again."""

from __future__ import annotations

import dataclasses
import errno
import fcntl
import os
import time

import numpy as np
import pytest

from odolab.core.parallel import SERIAL
from odolab.io import atomic
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import CACHE_TEMPORARY, EpisodeCache, EpisodeSpec, render_episode, stream_episodes


@pytest.fixture(scope="module")
def tiny():
    """A 3-step episode through a 96 x 54 camera (rendered once for the module) and its spec."""
    spec = EpisodeSpec(split="test", index=0, seed=0, max_steps=3, camera=CameraSpec(width=96, height=54))
    return spec, render_episode(spec)


def test_a_link_to_nothing_in_an_entrys_place_is_replaced_not_written_through(tmp_path, tiny):
    spec, episode = tiny
    cache, outside = EpisodeCache(tmp_path / "cache"), tmp_path / "outside.npz"
    cache.root.mkdir()
    cache.path(spec).symlink_to(outside)
    assert cache.get(spec) is None and not cache.has(spec)
    assert cache.put(episode) == cache.path(spec)
    assert not outside.exists() and not os.path.lexists(outside)  # nothing created where it pointed
    assert cache.path(spec).is_file() and not cache.path(spec).is_symlink()
    assert np.array_equal(cache.get(spec).rgb, episode.rgb)


def test_a_pipe_in_an_entrys_place_is_never_opened(tmp_path, tiny):
    spec, _ = tiny
    cache = EpisodeCache(tmp_path)
    os.mkfifo(cache.path(spec))  # reading it would block for ever
    assert cache.get(spec) is None and not cache.has(spec) and cache.steps(spec) == spec.max_steps


def _temporary(folder, key: str, age_s: float, name: str = "k2j3h4_x"):
    path = folder / f".{key}.npz.{name}.tmp"
    path.write_bytes(b"half an episode")
    os.utime(path, (time.time() - age_s, time.time() - age_s))
    return path


def test_temporary_files_of_killed_writers_are_removed_by_the_next_write(tmp_path, tiny, capsys):
    spec, episode = tiny
    cache = EpisodeCache(tmp_path)
    dead = _temporary(tmp_path, spec.key(), age_s=3600)
    young = _temporary(tmp_path, spec.key(), age_s=0, name="young")  # may be a writer between create and lock
    live = _temporary(tmp_path, "0" * 16, age_s=3600, name="live")
    other = tmp_path / ".notes.txt.abc.tmp"  # not the cache's: never touched
    other.write_text("mine")
    os.utime(other, (0, 0))
    assert CACHE_TEMPORARY.fullmatch(dead.name) and not CACHE_TEMPORARY.fullmatch(other.name)
    with open(live, "rb") as writer:
        fcntl.flock(writer, fcntl.LOCK_EX)  # a live writer holds its temporary file
        cache.put(episode)
    assert not dead.exists() and young.exists() and live.exists() and other.exists()
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "removed 1 temporary file" in err[0] and str(tmp_path) in err[0]


def test_a_writer_holds_its_temporary_file_while_it_writes(tmp_path):
    with atomic.atomic_open(tmp_path / f"{'a' * 16}.npz") as f:
        (tmp,) = tmp_path.glob(".*.tmp")
        assert CACHE_TEMPORARY.fullmatch(tmp.name)
        os.utime(tmp, (0, 0))  # old, yet held: not stale
        assert atomic.remove_stale_temporaries(tmp_path, CACHE_TEMPORARY) == []
        f.write(b"x")
    assert (tmp_path / f"{'a' * 16}.npz").read_bytes() == b"x"


def _full_disk(monkeypatch, calls: list[str]) -> None:
    """Every fsync (an atomic write's last step) fails as on a full disk, after the data went out."""

    def fsync(fd: int) -> None:
        calls.append("fsync")
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    monkeypatch.setattr(atomic.os, "fsync", fsync)


def test_a_full_disk_skips_the_cache_write_with_one_warning_and_keeps_the_results(tmp_path, tiny, monkeypatch, capsys):
    spec, episode = tiny
    specs = [spec, dataclasses.replace(spec, index=1)]
    cache, calls = EpisodeCache(tmp_path), []
    _full_disk(monkeypatch, calls)
    got = list(stream_episodes(specs, cache, execution=SERIAL))
    assert len(got) == 2 and np.array_equal(got[0].rgb, episode.rgb)
    assert calls == ["fsync"]  # tried once, then not again for every episode
    assert os.listdir(tmp_path) == []  # nothing half-written left
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot write the episode cache" in err[0] and "No space left on device" in err[0]
    assert "results are kept" in err[0]
    assert cache.has(spec) and cache.steps(spec) == len(episode.actions)  # kept in memory for this run
    assert np.array_equal(cache.get(specs[1]).rgb, got[1].rgb)
    other = EpisodeCache(tmp_path)  # another process's cache (a Ray task), another episode: the same line
    other.put(dataclasses.replace(episode, spec=specs[1]))
    assert capsys.readouterr().err.strip() == err[0]


def test_an_entry_the_cache_cannot_write_is_named_in_its_warning(tmp_path, tiny, capsys):
    spec, episode = tiny
    cache = EpisodeCache(tmp_path)
    cache.path(spec).mkdir(parents=True)  # a folder in the entry's place: this entry's problem, not the cache's
    assert cache.put(episode) is None
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and f"({cache.path(spec).name}: " in err[0]


def test_a_read_only_cache_holding_every_episode_is_read(tmp_path, tiny, monkeypatch, capsys):
    spec, episode = tiny
    EpisodeCache(tmp_path).put(episode)

    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, os.strerror(errno.EROFS))

    monkeypatch.setattr(atomic.tempfile, "mkstemp", read_only)  # no file can be made there
    (back,) = stream_episodes([spec], EpisodeCache(tmp_path), execution=SERIAL)
    assert np.array_equal(back.rgb, episode.rgb) and capsys.readouterr().err == ""


def test_the_noiseless_depth_goes_through_the_cache_and_reaches_frames_in_metres(tmp_path, tiny):
    spec, episode = tiny
    assert episode.clean_depth_mm is not None and episode.clean_depth_mm.dtype == np.uint16
    cache = EpisodeCache(tmp_path / "cache")
    cache.put(episode)
    back = cache.get(spec)
    assert np.array_equal(back.clean_depth_mm, episode.clean_depth_mm)
    frame = back[1]
    assert frame.clean_depth.dtype == np.float32
    assert np.array_equal(frame.clean_depth, episode.clean_depth_mm[1] * np.float32(0.001))


@pytest.mark.parametrize("damage", ["truncated", "bad crc"])
def test_damaged_cache_entry_is_named_and_regenerated(tmp_path, small_spec, capsys, damage):
    import dataclasses

    from odolab.sim.episodes import EpisodeCache, load_episodes, render_episode

    small_spec = dataclasses.replace(small_spec, max_steps=4)
    cache = EpisodeCache(tmp_path)
    path = cache.put(render_episode(small_spec))
    good = path.read_bytes()
    k = len(good) // 3  # inside the rgb member: the zip directory stays readable, the CRC fails
    path.write_bytes(
        good[: len(good) // 2] if damage == "truncated" else good[:k] + bytes([good[k] ^ 0xFF]) + good[k + 1 :]
    )
    capsys.readouterr()
    (ep,) = load_episodes([small_spec], cache, execution=SERIAL)
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and str(path) in err[0] and "damaged" in err[0]
    assert path.read_bytes() == good  # regenerated, bit for bit, and written back
    assert cache.get(small_spec) is not None and np.array_equal(ep.rgb, cache.get(small_spec).rgb)
