"""odolab/running/runner.py: answers copied at the step, the per-step time limit, attributes read inside a
guard, frames without depth counted, an odometer calling sys.exit failed; on a tiny synthetic sequence
(no simulator) or the 10-frame TUM folder, so each test is fast. Hostile odometers too: frames they
cannot change, transforms that are not rigid motions, a reset that raises, batched steps with honest
timing, raw estimates kept."""

from __future__ import annotations

import threading
import time
from dataclasses import dataclass, field

import numpy as np
import pytest

from odolab import api
from odolab.core.geometry import planar_to_transform
from odolab.core.parallel import SERIAL
from odolab.core.types import Action, Frame, Intrinsics
from odolab.odometry.action_prior import ActionPrior
from odolab.odometry.odometer import own_copy
from odolab.running import runner
from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec, load_episodes
from tests.helpers import TUM_DIR, run_python

PRIOR = ActionPrior.shipped()
FORWARD = planar_to_transform(0.0, 0.25, 0.0)


@dataclass
class Tiny:
    """``frames`` frames of 4 x 6 pixels, moving 0.25 m forward per step; ``empty``: frames whose depth is all 0."""

    frames: int = 7
    empty: tuple[int, ...] = ()
    intrinsics: Intrinsics = field(default_factory=lambda: Intrinsics(5.0, 5.0, 2.5, 1.5, 6, 4))
    name: str = "tiny"
    collisions: np.ndarray | None = None

    def __len__(self) -> int:
        return self.frames

    def __getitem__(self, i: int) -> Frame:
        depth = np.zeros((4, 6), np.float32) if i in self.empty else np.full((4, 6), 2.0, np.float32)
        return Frame(np.zeros((4, 6, 3), np.uint8), depth, timestamp=0.1 * i, gt_pose=self.gt_pose(i))

    def action(self, i: int) -> Action | None:
        return Action.MOVE_FORWARD

    def gt_pose(self, i: int) -> np.ndarray:
        return np.linalg.matrix_power(FORWARD, i)


class Counting(api.Odometer):
    """Answers step k as k cm forward, written into ONE array it reuses for every answer."""

    def reset(self, intrinsics):
        super().reset(intrinsics)
        self.k, self.out = 0, np.eye(4)

    def step(self, prev, cur, action):
        self.k += 1
        self.out[:] = planar_to_transform(0.0, 0.01 * self.k, 0.0)
        return api.Estimate(self.out, covariance=np.full((6, 6), float(self.k)))


def _forward(result: runner.SequenceResult) -> list[float]:
    return [float(e.transform[2, 3]) for e in result.raw]


def test_an_odometer_reusing_one_output_array_is_scored_on_each_answer():
    res = runner.run_sequence(Counting(), Tiny(), "reuse", PRIOR)
    assert _forward(res) == pytest.approx([0.01, 0.02, 0.03, 0.04, 0.05, 0.06])
    assert res.estimates[:, 2, 3] == pytest.approx([0.01, 0.02, 0.03, 0.04, 0.05, 0.06])
    assert [e.covariance[0, 0] for e in res.raw] == [1, 2, 3, 4, 5, 6]


def test_a_batched_odometer_reusing_its_buffer_across_calls_is_scored_on_each_answer():
    class Buffered(api.Odometer):
        batch_size = 2

        def reset(self, intrinsics):
            super().reset(intrinsics)
            self.k, self.buffer = 0, np.stack([np.eye(4)] * 2)

        def step_batch(self, pairs):
            out = []
            for j in range(len(pairs)):
                self.k += 1
                self.buffer[j] = planar_to_transform(0.0, 0.01 * self.k, 0.0)
                out.append(api.Estimate(self.buffer[j]))
            return out

    res = runner.run_sequence(Buffered(), Tiny(), "buffered", PRIOR)
    assert _forward(res) == pytest.approx([0.01, 0.02, 0.03, 0.04, 0.05, 0.06])


def test_an_answer_changed_after_its_step_is_scored_as_given():
    class Regretful(api.Odometer):
        """Returns the true motion, then spoils every earlier answer in place."""

        def reset(self, intrinsics):
            super().reset(intrinsics)
            self.given = []

        def step(self, prev, cur, action):
            for est in self.given:
                est.transform[:] = np.nan
            self.given.append(api.Estimate(FORWARD.copy()))
            return self.given[-1]

    res = runner.run_sequence(Regretful(), Tiny(), "regretful", PRIOR)
    assert res.failures == 0 and np.all(np.isfinite(res.estimates))
    assert np.allclose(res.poses, res.gt_poses)
    assert all(np.array_equal(e.transform, FORWARD) for e in res.raw)


def test_the_default_step_batch_copies_each_answer():
    odo = Counting()
    odo.reset(Tiny().intrinsics)
    out = odo.step_batch([(None, None, None)] * 3)
    assert [e.transform[2, 3] for e in out] == pytest.approx([0.01, 0.02, 0.03])
    assert odo.step_batch([]) == [] and own_copy("not an estimate") == "not an estimate"


class Stuck(api.Odometer):
    """Steps ``stuck`` (indices) wait until the test releases them; the others answer the truth."""

    def __init__(self, stuck=(), release=None):
        self.stuck, self.release, self.calls = set(stuck), release or threading.Event(), 0

    def step(self, prev, cur, action):
        self.calls += 1
        if self.calls - 1 in self.stuck:
            self.release.wait(10)
        return api.Estimate(FORWARD)


@pytest.fixture
def release():
    """An event that lets go of every step still waiting when the test ends."""
    event = threading.Event()
    yield event
    event.set()


def test_a_step_past_the_time_limit_fails_and_the_next_ones_run(release):
    t0 = time.perf_counter()
    res = runner.run_sequence(Stuck({1}, release), Tiny(), "slow", PRIOR, step_timeout=0.05)
    assert time.perf_counter() - t0 < 1.0
    assert res.failure_reasons == {"timed-out": 1} and not res.valid[1] and res.valid.sum() == 5
    assert res.step_seconds[1] == pytest.approx(0.05) and res.asked.all()
    assert res.errors == ["step 1: timed out after 0.05 s"]
    assert "timed-out" in runner.FAILURE_REASONS


def test_an_odometer_that_keeps_timing_out_is_stopped_for_the_sequence(release):
    odo = Stuck(range(100), release)
    t0 = time.perf_counter()
    res = runner.run_sequence(odo, Tiny(frames=11), "stuck", PRIOR, step_timeout=0.03)
    assert time.perf_counter() - t0 < 0.5  # 3 waits, not 10
    assert res.failure_reasons == {"timed-out": 10} and odo.calls == runner.MAX_TIMEOUTS
    assert res.asked.sum() == 3 and res.step_seconds[3:].sum() == 0
    assert "stopped for the rest of the sequence" in res.errors[-1]
    assert len(res.timestamps) == 11  # every frame was still read


def test_a_reset_past_the_time_limit_fails_the_sequence(release):
    class SlowReset(api.Odometer):
        def reset(self, intrinsics):
            release.wait(10)

        def step(self, prev, cur, action):
            raise AssertionError("never asked")

    res = runner.run_sequence(SlowReset(), Tiny(), "slow-reset", PRIOR, step_timeout=0.03)
    assert res.failure_reasons == {"timed-out": 6} and not res.asked.any()
    assert res.errors == ["reset: timed out after 0.03 s"]


def test_a_step_batch_that_yields_forever_fails_its_batch():
    class Endless(api.Odometer):
        batch_size = 3

        def step_batch(self, pairs):
            while True:
                yield api.Estimate(FORWARD)

    res = runner.run_sequence(Endless(), Tiny(), "endless", PRIOR)
    assert res.failure_reasons == {"batch-length": 6}


def test_reset_and_steps_share_one_worker_thread_and_numbers_match_the_unlimited_run():
    class Where(Counting):
        def reset(self, intrinsics):
            super().reset(intrinsics)
            self.threads_seen = [threading.get_ident()]

        def step(self, prev, cur, action):
            self.threads_seen.append(threading.get_ident())
            return super().step(prev, cur, action)

    limited, unlimited = Where(), Where()
    a = runner.run_sequence(limited, Tiny(), "w", PRIOR, step_timeout=60.0)
    b = runner.run_sequence(unlimited, Tiny(), "w", PRIOR, step_timeout=None)
    assert len(set(limited.threads_seen)) == 1 and limited.threads_seen[0] != threading.get_ident()
    assert set(unlimited.threads_seen) == {threading.get_ident()}
    assert np.array_equal(a.estimates, b.estimates) and np.array_equal(a.poses, b.poses)


def test_a_step_is_timed_in_its_own_thread_as_without_a_limit():
    class Sleepy(api.Odometer):
        def step(self, prev, cur, action):
            time.sleep(0.02)
            return api.Estimate(FORWARD)

    for timeout in (None, 60.0):
        res = runner.run_sequence(Sleepy(), Tiny(frames=3), "sleepy", PRIOR, step_timeout=timeout)
        assert np.all((res.step_seconds > 0.019) & (res.step_seconds < 0.03))


def test_an_interrupt_raised_in_a_step_is_not_swallowed():
    class Interrupted(api.Odometer):
        def step(self, prev, cur, action):
            raise KeyboardInterrupt

    for timeout in (None, 60.0):
        with pytest.raises(KeyboardInterrupt):
            runner.run_sequence(Interrupted(), Tiny(), "ctrl-c", PRIOR, step_timeout=timeout)


def test_sys_exit_in_a_step_is_a_failure_of_that_step():
    class Exits(api.Odometer):
        def step(self, prev, cur, action):
            raise SystemExit(3)

    res = runner.run_sequence(Exits(), Tiny(), "exits", PRIOR)
    assert res.failure_reasons == {"raised": 6} and res.errors[0] == "step 0: SystemExit: 3"


class RaisingOracle(api.Odometer):
    @property
    def oracle(self):
        raise RuntimeError("cannot tell")

    def step(self, prev, cur, action):
        return api.Estimate(FORWARD)


def _with_attribute(name, value):
    class Odd(api.Odometer):
        def step(self, prev, cur, action):
            return api.Estimate(FORWARD)

    setattr(Odd, name, value)
    return Odd()


@pytest.mark.parametrize(
    "odometer,message",
    [
        (_with_attribute("batch_size", float("nan")), "batch_size must be a whole number in [1, 1000000], got nan"),
        (_with_attribute("batch_size", 0), "batch_size must be a whole number in [1, 1000000], got 0"),
        (_with_attribute("batch_size", "4"), "batch_size must be a whole number in [1, 1000000], got '4'"),
        (_with_attribute("threads", float("inf")), "threads must be a whole number in [1, 256], got inf"),
        (_with_attribute("oracle", "no"), "oracle must be True or False, got 'no'"),
        (RaisingOracle(), "reading oracle raised RuntimeError: cannot tell"),
    ],
)
def test_an_unusable_attribute_fails_that_odometer_not_the_run(odometer, message):
    results = runner.run({"odd": odometer, "ground-truth": api.load_odometer("ground-truth")}, [Tiny()])
    odd, truth = results
    assert odd.failure_reasons == {"bad-attribute": 6} and odd.errors == [f"attributes: {message}"]
    assert not odd.asked.any() and not odd.oracle and len(odd.timestamps) == 7
    assert truth.failures == 0


def test_whole_float_attributes_are_accepted():
    res = runner.run_sequence(_with_attribute("batch_size", 2.0), Tiny(), "two", PRIOR)
    assert res.failures == 0 and runner.read_attributes(_with_attribute("oracle", 1)).oracle is True


def test_frames_without_any_depth_are_counted():
    assert runner.run_sequence(Counting(), Tiny(empty=(0, 4)), "c", PRIOR).empty_depth == 2
    assert runner.run_sequence(RaisingOracle(), Tiny(empty=(3,)), "c", PRIOR).empty_depth == 1
    assert runner.run_sequence(Counting(), Tiny(), "c", PRIOR).empty_depth == 0


def test_one_frame_is_zero_steps_and_no_frame_is_refused():
    res = runner.run_sequence(Counting(), Tiny(frames=1), "one", PRIOR)
    assert res.estimates.shape == (0, 4, 4) and res.poses.shape == (1, 4, 4) and res.failure_reasons == {}
    with pytest.raises(ValueError, match="sequence 'tiny' has no frames"):
        runner.run_sequence(Counting(), Tiny(frames=0), "none", PRIOR)


def test_oracle_only_fields_are_removed_for_other_odometers():
    frame = Tiny()[2]
    assert runner.guarded_frame(frame, oracle=False).gt_pose is None
    seen = runner.guarded_frame(frame, oracle=True).gt_pose
    assert np.array_equal(seen, frame.gt_pose) and not seen.flags.writeable
    assert runner.ORACLE_ONLY_FIELDS == ("gt_pose", "clean_depth")
    from odolab.core.types import Frame

    simulated = Frame(frame.rgb, frame.depth, gt_pose=frame.gt_pose, clean_depth=frame.depth + 0.1)
    assert runner.guarded_frame(simulated, oracle=False).clean_depth is None
    assert np.array_equal(runner.guarded_frame(simulated, oracle=True).clean_depth, frame.depth + 0.1)


def test_a_batch_answered_with_one_reused_array_fails_as_shared_array_but_a_generator_may_reuse():
    class ListReuse(api.Odometer):
        batch_size = 3

        def step_batch(self, pairs):
            self.buffer, answers = np.eye(4), []
            for k, _ in enumerate(pairs):
                self.buffer[2, 3] = 0.1 * (k + 1)  # each pair's own motion, written into one array
                answers.append(api.Estimate(self.buffer))
            return answers

    class GeneratorReuse(ListReuse):
        def step_batch(self, pairs):
            buffer = np.eye(4)
            for _ in pairs:
                buffer[:] = FORWARD
                yield api.Estimate(buffer)
                buffer[:] = np.nan  # changed after it was read: the runner's copy keeps the answer

    res = runner.run_sequence(ListReuse(), Tiny(), "list", PRIOR)
    assert res.failure_reasons == {"shared-array": 6} and not res.valid.any()
    res = runner.run_sequence(GeneratorReuse(), Tiny(), "generator", PRIOR)
    assert res.valid.all() and np.allclose(res.estimates, FORWARD)


def test_an_odometer_calling_sys_exit_fails_its_steps_not_the_comparison():
    from odolab.api import Estimate, Odometer, load_tum_sequence, run_odometers

    class Quitter(Odometer):
        def step(self, prev, cur, action) -> Estimate:
            raise SystemExit(0)

    class QuitsOnReset(Odometer):
        def reset(self, intrinsics) -> None:
            raise SystemExit(3)

    seq = load_tum_sequence(TUM_DIR)
    a, b = run_odometers({"quitter": Quitter(), "reset": QuitsOnReset()}, [seq])
    assert a.failures == b.failures == len(seq) - 1
    assert "SystemExit" in a.errors[0] and "SystemExit" in b.errors[0]


def _pairs(n: int) -> list[tuple[Frame, Frame, Action]]:
    seq = Tiny(frames=n + 1)
    return [(seq[i], seq[i + 1], Action.MOVE_FORWARD) for i in range(n)]


def test_step_by_step_guards_a_closed_loop_as_the_runner_guards_a_sequence(release):
    """StepByStep (navigation, probes): a hanging step times out and is stopped after three timeouts,
    a raising reset or attribute fails every step, answers are copies, frames hide the truth."""
    with runner.StepByStep(Stuck(range(100), release), "stuck", step_timeout=0.03) as asked:
        assert asked.reset(Tiny().intrinsics)
        t0 = time.perf_counter()
        answers = [asked.step(asked.frame(p), asked.frame(c), a) for p, c, a in _pairs(6)]
        assert time.perf_counter() - t0 < 0.5 and answers == [None] * 6  # 3 waits, not 6
        assert asked.reasons == {"timed-out": 6} and asked.odometer.calls == runner.MAX_TIMEOUTS
        assert asked.errors == [f"step {i}: timed out after 0.03 s" for i in range(2)] + [
            "step 2: timed out after 0.03 s; stopped"
        ]

    class BadReset(api.Odometer):
        def reset(self, intrinsics):
            raise OSError("no camera")

        def step(self, prev, cur, action):
            raise AssertionError("never asked")

    for odometer, reason, error in [
        (BadReset(), "reset-raised", "reset: OSError: no camera"),
        (RaisingOracle(), "bad-attribute", "attributes: reading oracle raised RuntimeError: cannot tell"),
    ]:
        with runner.StepByStep(odometer, "odd") as asked:
            assert not asked.reset(Tiny().intrinsics)
            assert [asked.step(*pair) for pair in _pairs(2)] == [None, None]
            assert asked.reasons == {reason: 2} and asked.errors == [error]

    reused = np.eye(4)

    class Reusing(api.Odometer):
        def step(self, prev, cur, action):
            assert prev.gt_pose is None
            reused[2, 3] += 0.25
            return api.Estimate(reused)

    class BatchOnly(api.Odometer):  # answers through step_batch alone, as the runner asks it
        batch_size = 4

        def step_batch(self, pairs):
            return [api.Estimate(FORWARD) for _ in pairs]

    class Unprintable(Exception):
        def __str__(self):
            raise RuntimeError("no text")

    class RaisesOddly(api.Odometer):
        def step(self, prev, cur, action):
            raise [GeneratorExit(), Unprintable()][int(cur.timestamp * 10) % 2]

    with runner.StepByStep(BatchOnly(), "batch-only") as asked:
        assert [asked.step(*pair) is not None for pair in _pairs(2)] == [True, True]
    with runner.StepByStep(RaisesOddly(), "odd") as asked:  # failed steps, not a traceback
        assert [asked.step(*pair) for pair in _pairs(2)] == [None, None] and asked.reasons == {"raised": 2}
        assert "Unprintable: (its message could not be read)" in " ".join(asked.errors)

    with runner.StepByStep(Reusing(), "reusing") as asked:
        asked.reset(Tiny().intrinsics)
        got = [asked.step(asked.frame(p), asked.frame(c), a) for p, c, a in _pairs(3)]
        assert [e.transform[2, 3] for e in got] == [0.25, 0.5, 0.75] and not asked.reasons


def test_step_by_step_leaves_the_odometer_to_the_callers_thread_to_free():
    """The worker thread that makes the timed calls keeps nothing of the last one: an odometer the
    caller lets go is freed there and then, in the caller's thread (torch aborts the process when a
    daemon thread frees its tensors as the interpreter exits)."""
    freed_in: list[str] = []

    class Freed(api.Odometer):
        def step(self, prev, cur, action):
            return api.Estimate(FORWARD)

        def __del__(self):
            freed_in.append(threading.current_thread().name)

    with runner.StepByStep(Freed(), "freed", step_timeout=5.0) as asked:
        assert asked.reset(Tiny().intrinsics)
        assert [asked.step(*pair) is not None for pair in _pairs(3)] == [True] * 3
    del asked  # at once: the worker thread may not have woken to the queue's end yet
    assert freed_in == [threading.current_thread().name]


@pytest.mark.slow
def test_a_command_left_with_a_call_still_running_exits_with_its_code(tmp_path):
    """A torch step that ran past its time limit and still runs when the command ends: the runner
    says so (calls_still_running) and exit_process leaves at once with the command's code, where
    the interpreter's exit would abort the process (exit 134) as the step returned into it."""
    done = run_python(
        tmp_path,
        "import os, sys, torch\n"
        "sys.path.insert(0, os.getcwd())  # the repository's root: its tests package\n"
        "from odolab import api\n"
        "from odolab.cli.args import exit_process\n"
        "from odolab.running import runner\n"
        "from tests.test_runner import Tiny, FORWARD\n"
        "torch.set_num_threads(1)\n"
        "class Slow(api.Odometer):\n"
        "    def step(self, prev, cur, action):\n"
        "        a = torch.rand(1500, 1500)\n"
        "        for _ in range(30):\n"
        "            a = torch.mm(a, a) / 1500.0\n"
        "        return api.Estimate(FORWARD)\n"
        "seq = Tiny()\n"
        "with runner.StepByStep(Slow(), 'slow', step_timeout=0.05) as asked:\n"
        "    asked.reset(seq.intrinsics)\n"
        "    print(asked.step(asked.frame(seq[0]), asked.frame(seq[1]), seq.action(0)))\n"
        "print(runner.calls_still_running(), flush=True)\n"
        "exit_process(3)\n",
    )
    assert (done.returncode, done.stdout.split()) == (3, ["None", "True"]), done.stderr[-2000:]


def test_an_odometer_that_hangs_on_every_other_step_is_stopped_too(release):
    """Timeouts count in all, not only in a row: a sequence waits at most MAX_TIMEOUTS time limits."""
    odo = Stuck(range(0, 100, 2), release)
    res = runner.run_sequence(odo, Tiny(frames=11), "every-other", PRIOR, step_timeout=0.03)
    assert res.failure_reasons["timed-out"] == 10 - 2 and odo.calls == 2 * runner.MAX_TIMEOUTS - 1


def test_an_answer_is_read_once_so_it_cannot_tell_the_checks_one_motion_and_the_path_another():
    """own_copy reads valid and transform once, in the step's own thread: a valid that is no bool
    fails its step (its truth value is never asked); an object array that answers 0 m then 1e6 m
    is scored as the 0 m it first said; a complex transform fails."""

    class Flip:
        calls = 0

        def __float__(self):
            Flip.calls += 1
            return 0.0 if Flip.calls == 1 else 1e6

    class Exits:
        def __bool__(self):
            raise SystemExit(9)

    class Odd(api.Odometer):
        def step(self, prev, cur, action):
            if cur.timestamp < 0.15:
                return api.Estimate(FORWARD, valid=Exits())
            t = np.array(FORWARD, dtype=object)
            Flip.calls = 0
            t[0, 3] = Flip()
            return api.Estimate(t)

    res = runner.run_sequence(Odd(), Tiny(frames=3), "odd", PRIOR)
    assert res.failure_reasons == {"raised": 1} and "valid must be True or False, got Exits" in res.errors[0]
    assert res.valid[1] and res.estimates[1][0, 3] == 0.0 and abs(res.poses[-1][0, 3]) < 1.0
    with pytest.raises(TypeError, match="must be real"):
        own_copy(api.Estimate(FORWARD.astype(complex)))
    assert own_copy(api.Estimate(FORWARD, valid=np.bool_(False))).valid is False


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


def _fixed(transform):
    class Fixed(api.Odometer):
        def step(self, prev, cur, action):
            return api.Estimate(np.array(transform, dtype=float))

    return Fixed()


def _with(R=None, t=(0, 0, 0.25), bottom=(0, 0, 0, 1)):
    T = np.eye(4)
    T[:3, :3], T[:3, 3], T[3] = np.eye(3) if R is None else R, t, bottom
    return T


class BrokenReset(api.Odometer):
    def reset(self, intrinsics):
        raise OSError("checkpoint missing")

    def step(self, prev, cur, action):  # never reached
        return api.Estimate(np.eye(4))


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


def test_a_reset_that_raises_fails_that_sequence_not_the_run(episode):
    odometers = {"broken": BrokenReset(), "ground-truth": api.load_odometer("ground-truth")}
    results = runner.run(odometers, [episode, episode])
    n = len(episode) - 1
    broken = [r for r in results if r.odometer == "broken"]
    assert len(broken) == 2 and all(r.failure_reasons == {"reset-raised": n} for r in broken)
    assert "checkpoint missing" in broken[0].errors[0]
    assert all(r.failures == 0 for r in results if r.odometer == "ground-truth")


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
