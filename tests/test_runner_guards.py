"""The runner against hostile or unusual odometers: frames they cannot change, transforms that are
not rigid motions, a reset that raises, batched steps with honest timing, raw estimates kept."""

import time

import numpy as np
import pytest

from odolab import api
from odolab.core.parallel import SERIAL
from odolab.odometry.action_prior import ActionPrior
from odolab.running import runner
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec, load_episodes

PRIOR = ActionPrior.shipped()


@pytest.fixture(scope="module")
def episode():
    spec = EpisodeSpec(split="test", index=1, max_steps=12, camera=CameraSpec(width=64, height=36))
    return load_episodes([spec], None, execution=SERIAL)[0]


class Vandal(api.Odometer):
    """Zeroes the depth it is given (in place), then answers identity."""

    def step(self, prev, cur, action):
        cur.depth[:] = 0.0
        return api.Estimate(np.eye(4))


class DepthRecorder(api.Odometer):
    """Answers identity and remembers the sum of every current depth image it saw."""

    def reset(self, intrinsics):
        super().reset(intrinsics)
        self.seen = []

    def step(self, prev, cur, action):
        self.seen.append(float(cur.depth.sum()))
        return api.Estimate(np.eye(4))


def test_an_odometer_cannot_change_the_frames_the_next_one_sees(episode):
    before = episode.depth.copy()
    vandal = runner.run_sequence(Vandal(), episode, "vandal", PRIOR)
    n = len(episode) - 1
    assert vandal.failure_reasons == {"raised": n} and "read-only" in vandal.errors[0]
    assert np.array_equal(episode.depth, before)
    rec = DepthRecorder()
    runner.run_sequence(rec, episode, "recorder", PRIOR)
    assert rec.seen == pytest.approx([float(episode.depth[i + 1].sum()) for i in range(n)])
    assert min(rec.seen) > 0


def test_frames_given_to_an_odometer_are_read_only_copies(episode):
    frame = runner.guarded_frame(episode[0], oracle=False)
    assert not frame.rgb.flags.writeable and not frame.depth.flags.writeable and frame.gt_pose is None
    frame.depth.flags.writeable = True  # even a determined odometer only changes its own copy
    frame.depth[:] = 0
    assert episode.depth[0].sum() > 0


def _fixed(transform):
    class Fixed(api.Odometer):
        def step(self, prev, cur, action):
            return api.Estimate(np.array(transform, dtype=float))

    return Fixed()


def _with(R=None, t=(0, 0, 0.25), bottom=(0, 0, 0, 1)):
    T = np.eye(4)
    T[:3, :3], T[:3, 3], T[3] = np.eye(3) if R is None else R, t, bottom
    return T


@pytest.mark.parametrize(
    "transform,reason",
    [
        (_with(R=np.diag([1.0, 1.0, -1.0])), "not-a-rotation"),  # a reflection (det -1)
        (_with(R=1.01 * np.eye(3)), "not-a-rotation"),  # scaled by 1 %
        (_with(R=[[1, 0.01, 0], [0, 1, 0], [0, 0, 1]]), "not-a-rotation"),  # sheared
        (_with(bottom=(0, 0, 0.1, 1)), "bad-bottom-row"),
        (_with(t=(0, 0, 1e200)), "absurd-translation"),
        (_with(t=(0, 0, runner.MAX_STEP_TRANSLATION * 1.01)), "absurd-translation"),
        (_with(t=(0, np.nan, 0)), "non-finite"),
    ],
)
def test_a_valid_step_that_is_not_a_rigid_motion_is_a_counted_failure(episode, transform, reason):
    res = runner.run_sequence(_fixed(transform), episode, "bad", PRIOR)
    n = len(episode) - 1
    assert res.failure_reasons == {reason: n} and res.failures == n
    assert np.all(np.abs(res.poses[:, :3, 3]) < 1e3)  # the prior's motion was integrated instead
    assert reason in runner.FAILURE_REASONS


def test_a_rigid_motion_near_the_bounds_is_accepted(episode):
    c, s = np.cos(0.3), np.sin(0.3)
    R = np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]], dtype=np.float32)  # float32 round-off is fine
    res = runner.run_sequence(_fixed(_with(R=R, t=(0, 0, 0.99 * runner.MAX_STEP_TRANSLATION))), episode, "ok", PRIOR)
    assert res.failures == 0 and res.failure_reasons == {}


class BrokenReset(api.Odometer):
    def reset(self, intrinsics):
        raise OSError("checkpoint missing")

    def step(self, prev, cur, action):  # never reached
        return api.Estimate(np.eye(4))


def test_a_reset_that_raises_fails_that_sequence_not_the_run(episode):
    odometers = {"broken": BrokenReset(), "ground-truth": api.load_odometer("ground-truth")}
    results = runner.run(odometers, [episode, episode])
    n = len(episode) - 1
    broken = [r for r in results if r.odometer == "broken"]
    assert len(broken) == 2 and all(r.failure_reasons == {"reset-raised": n} for r in broken)
    assert "checkpoint missing" in broken[0].errors[0]
    assert all(r.failures == 0 for r in results if r.odometer == "ground-truth")


class SlowBatch(api.Odometer):
    """Batches of 4; each batch call sleeps 40 ms; returns covariances it invents per step."""

    batch_size = 4

    def reset(self, intrinsics):
        super().reset(intrinsics)
        self.calls = []

    def step(self, prev, cur, action):
        raise AssertionError("the runner must use step_batch")

    def step_batch(self, pairs):
        self.calls.append(len(pairs))
        time.sleep(0.04)
        return [api.Estimate(np.eye(4), covariance=np.eye(6) * (k + 1)) for k in range(len(pairs))]


def test_batched_steps_share_the_batch_time_and_raw_estimates_are_kept(episode):
    odo = SlowBatch()
    res = runner.run_sequence(odo, episode, "batch", PRIOR)
    n = len(episode) - 1
    assert sum(odo.calls) == n and max(odo.calls) == 4 and len(odo.calls) == -(-n // 4)
    # per-step time = batch time / pairs in the batch: a full batch of 4 gives ~10 ms per step
    assert 0.009 < res.step_seconds[0] < 0.03 and res.step_seconds[0] == res.step_seconds[3]
    assert len(res.raw) == n and all(isinstance(e, api.Estimate) for e in res.raw)
    assert res.raw[1].covariance[0, 0] == 2.0  # second pair of the first batch


def test_a_batch_of_the_wrong_length_fails_its_steps(episode):
    class Short(SlowBatch):
        def step_batch(self, pairs):
            return super().step_batch(pairs)[:-1]

    res = runner.run_sequence(Short(), episode, "short", PRIOR)
    assert res.failure_reasons == {"batch-length": len(episode) - 1}


def test_the_default_step_batch_calls_step_in_order():
    class Count(api.Odometer):
        def step(self, prev, cur, action):
            return api.Estimate.from_planar(0, float(prev), 0)

    out = Count().step_batch([(1, None, None), (2, None, None)])
    assert [e.planar[1] for e in out] == pytest.approx([1.0, 2.0])


def test_progress_reaches_an_observer(episode):
    class Listener:
        def __init__(self):
            self.events = []

        def start(self, total):
            self.events.append(("start", total))

        def advance(self, name, steps):
            self.events.append((name, steps))

        def close(self):
            self.events.append(("close",))

    ear = Listener()
    runner.run({"ground-truth": api.load_odometer("ground-truth")}, [episode], observer=ear)
    n = len(episode) - 1
    assert ear.events[0] == ("start", n) and ear.events[-1] == ("close",)
    assert sum(e[1] for e in ear.events[1:-1]) == n


def test_a_comparison_without_an_episode_cache_tells_its_progress_the_total_at_the_start():
    from odolab.api import SERIAL, ComparisonConfig, run_comparison

    class Listener:
        def __init__(self):
            self.total = "not told"

        def start(self, total):
            self.total = total

        def advance(self, name, steps):
            pass

        def close(self):
            pass

    ear = Listener()
    config = ComparisonConfig(odometers=["ground-truth"], episodes=2, max_steps=4, cache=None, execution=SERIAL)
    result = run_comparison(config, observer=ear)
    assert ear.total == sum(len(r.actions) for r in result.results) and ear.total > 0


def test_compare_prints_failure_reasons(tmp_path, capsys):
    from odolab.cli import run_cli
    from odolab.compare import main

    api.register_odometer("broken-reset", BrokenReset)
    args = [
        "--odometers",
        "broken-reset,action-prior",
        "--episodes",
        "1",
        "--max-steps",
        "5",
        "--serial",
        "--quiet",
        "--no-cache",
        "--out",
        str(tmp_path),
    ]
    assert run_cli(main, "odolab.compare", args) == 0
    out = capsys.readouterr().out
    assert "note: broken-reset failed steps by reason: reset-raised 5" in out
    assert "action-prior failed" not in out
