"""odolab/learned/pose_corrector: an untrained ``corrected(X)`` answers exactly X, where X fails it answers
the corrected action prior (valid), its covariance is a 6x6 symmetric positive definite matrix, a
model file that does not fit its network (or was trained for another X) is refused in one line,
X's estimates on the training pairs are stored once and reused (refused for another X), and a tiny
training run resumes and exports."""

from __future__ import annotations

import csv
from pathlib import Path
from typing import ClassVar

import numpy as np
import pytest
import torch

from odolab.api import Action, Estimate, Odometer, load_odometer, register_odometer, transform_to_planar
from odolab.core.parallel import SERIAL
from odolab.learned.pose_corrector.checkpoint import load_model, save_model, shipped_model
from odolab.learned.pose_corrector.config import PoseCorrectorModel, PoseCorrectorTraining, load_training
from odolab.learned.pose_corrector.estimates import EstimatesError, estimates_folder, make_estimates
from odolab.learned.pose_corrector.model import PoseCorrectorNet, apply_correction, pair_inputs
from odolab.learned.pose_corrector.train import COLLIDED, correction_rows, pair_targets
from odolab.learned.robust_vo.odometer import PLANAR_VARIANCE
from odolab.learned.training import CheckpointError, DataConfig
from odolab.sim.episodes import EpisodeSpec, render_episode
from odolab.sim.training_data import TrainingData, make_training_data
from tests.conftest import SMALL_CAMERA

TINY = PoseCorrectorModel(width=48, height=32, base=2, hidden=8)


def _model(path, inner: str = "icp", model: PoseCorrectorModel = TINY, head_seed: int | None = None) -> str:
    """A model file for ``inner``: untrained (its head at zero), or with a random head."""
    torch.manual_seed(0)
    net = PoseCorrectorNet(model)
    if head_seed is not None:
        torch.manual_seed(head_seed)
        with torch.no_grad():
            net.head.weight.normal_(0.0, 0.5)
            net.head.bias.normal_(0.0, 0.5)
    save_model(path, PoseCorrectorTraining(model=model, inner=inner), net, {"note": "test"})
    return str(path)


@pytest.fixture(scope="module")
def episode():
    """A 6-step episode through a 96 x 54 camera (icp fails on some of its steps at this size)."""
    return render_episode(EpisodeSpec(split="val", index=0, seed=0, max_steps=6, camera=SMALL_CAMERA))


def test_an_untrained_network_answers_no_correction_with_the_base_variance():
    net = PoseCorrectorNet(TINY).eval()
    images, vector = torch.randn(3, 10, 32, 48), torch.randn(3, 7)
    with torch.inference_mode():
        correction, log_variance = net(images, vector)
    assert torch.equal(correction, torch.zeros(3, 3))
    std = torch.exp(0.5 * log_variance)
    assert torch.allclose(std, torch.tensor([TINY.base_std_translation] * 2 + [TINY.base_std_rotation]).expand(3, 3))


def test_apply_correction_adds_to_the_planar_motion_and_keeps_the_rest():
    T = np.eye(4)
    T[:3, :3] = np.array([[0.8, 0.0, -0.6], [0.0, 1.0, 0.0], [0.6, 0.0, 0.8]]) @ np.array(
        [[1.0, 0.0, 0.0], [0.0, np.cos(0.05), -np.sin(0.05)], [0.0, np.sin(0.05), np.cos(0.05)]]
    )  # a turn with some pitch
    T[:3, 3] = [0.02, -0.01, 0.2]
    out = apply_correction(T, np.array([0.01, -0.03, 0.1]))
    assert np.allclose(transform_to_planar(out), transform_to_planar(T) + [0.01, -0.03, 0.1])
    assert np.allclose(out[:3, :3].T @ out[:3, :3], np.eye(3)) and out[1, 3] == T[1, 3]
    assert np.array_equal(apply_correction(T, np.zeros(3)), T)  # no correction: the same values


def test_pair_inputs_of_a_pair_warped_by_its_true_motion_show_no_depth_change():
    rng = np.random.default_rng(0)
    depth = torch.from_numpy(rng.uniform(2.0, 3.0, (1, 32, 48)).astype(np.float32))
    rgb = torch.from_numpy(rng.integers(0, 256, (1, 32, 48, 3), dtype=np.uint8))
    from odolab.api import Intrinsics

    K = Intrinsics(40.0, 40.0, 23.5, 15.5, 48, 32)
    images, vector = pair_inputs(
        rgb, depth, rgb, depth, torch.eye(4)[None], np.array([Action.TURN_LEFT.value]), torch.tensor([True]), K, TINY
    )
    assert images.shape == (1, 10, 32, 48) and torch.equal(images[0, 9], torch.zeros(32, 48))
    assert torch.equal(vector[0], torch.tensor([0.0, 1.0, 0.0, 1.0, 0.0, 0.0, 0.0]))  # turn_left, X failed


def test_corrected_with_an_untrained_model_answers_exactly_its_inner_odometer(tmp_path, episode):
    inner = load_odometer("icp")
    wrapped = load_odometer("corrected(icp)", checkpoint=_model(tmp_path / "m.pt"))
    assert wrapped.composite and wrapped.oracle is False and wrapped.identity_digest != inner.identity_digest
    for odo in (inner, wrapped):
        odo.reset(episode.intrinsics)
    answered = 0
    for i in range(len(episode) - 1):
        a = inner.step(episode[i], episode[i + 1], episode.action(i))
        b = wrapped.step(episode[i], episode[i + 1], episode.action(i))
        assert b.valid
        if a.valid:
            answered += 1
            assert np.array_equal(a.transform, b.transform)  # bit for bit
    assert answered >= 1


class _Failing(Odometer):
    """Fails each step in turn: raises, answers valid=False, answers no rigid motion."""

    def __init__(self) -> None:
        self.calls = 0

    def step(self, prev, cur, action):
        self.calls += 1
        kind = self.calls % 3
        if kind == 1:
            raise RuntimeError("lost track")
        if kind == 2:
            return Estimate.invalid()
        return Estimate(np.diag([2.0, 1.0, 1.0, 1.0]))  # a stretch, not a rotation


def test_where_x_fails_the_answer_is_the_corrected_action_prior_and_valid(tmp_path, episode):
    register_odometer("failing", _Failing)
    odo = load_odometer("corrected(failing)", checkpoint=_model(tmp_path / "m.pt", inner="failing"))
    prior = load_odometer("action-prior")
    odo.reset(episode.intrinsics)
    for i in range(3):
        est = odo.step(episode[i], episode[i + 1], episode.action(i))
        assert est.valid and np.array_equal(est.transform, prior.step(None, None, episode.action(i)).transform)
    assert odo.inner_failures == {"raised RuntimeError": 1, "not-valid": 1, "not-a-rotation": 1}


def test_the_covariance_is_a_6x6_symmetric_positive_definite_matrix_of_the_learned_variance(tmp_path, episode):
    odo = load_odometer("corrected(icp)", checkpoint=_model(tmp_path / "m.pt", head_seed=1))
    odo.reset(episode.intrinsics)
    for i in range(2):
        est = odo.step(episode[i], episode[i + 1], episode.action(i))
        cov = est.covariance
        assert cov.shape == (6, 6) and np.array_equal(cov, cov.T) and np.linalg.eigvalsh(cov).min() > 0
        # (rx, ry, rz, tx, ty, tz): ry carries dyaw's learned variance, tx dx's and tz dz's
        learned = cov[[3, 5, 1], [3, 5, 1]]
        base = [TINY.base_std_translation**2] * 2 + [TINY.base_std_rotation**2]
        assert np.all(learned > 0) and not np.allclose(learned, base)
        assert np.all(cov[[0, 2, 4], [0, 2, 4]] == PLANAR_VARIANCE)


def test_a_model_file_that_does_not_fit_its_network_is_refused_in_one_line(tmp_path):
    path = tmp_path / "bad.pt"
    _model(path)
    doc = torch.load(path, weights_only=True)
    doc["model"]["base"] = 3  # the weights are of base 2
    torch.save(doc, path)
    with pytest.raises(CheckpointError) as err:
        load_model(path)
    said = str(err.value)
    assert "\n" not in said and str(path) in said and "do not fit" in said


def test_a_model_of_another_x_or_none_shipped_is_refused_in_one_line(tmp_path):
    path = _model(tmp_path / "icp.pt", inner="icp")
    with pytest.raises(ValueError, match=r"a model trained to correct 'icp', not 'open3d-rgbd'") as err:
        load_odometer("corrected(open3d-rgbd)", checkpoint=path)
    assert "\n" not in str(err.value)
    name = "feature-essential"
    assert not shipped_model(name).exists()
    with pytest.raises(ValueError, match=r"no shipped model for feature-essential .*train one .*checkpoint="):
        load_odometer(f"corrected({name})")
    with pytest.raises(ValueError, match=r"corrected takes one inner odometer.*got 2"):
        load_odometer("corrected(icp,open3d-rgbd)", checkpoint=path)


def test_the_shipped_recipe_is_the_defaults_and_names_its_x():
    cfg = load_training("studies/pose_corrector/shipped.toml")
    assert cfg == PoseCorrectorTraining() and cfg.inner == "open3d-rgbd"
    assert (cfg.train_data.width, cfg.train_data.height) == (341, 192)  # X runs on the camera's frames
    with pytest.raises(ValueError, match="recipe: inner must name the odometer to correct"):
        PoseCorrectorTraining(inner=" ")


def test_correction_rows_compare_corrected_x_alone_and_the_prior_per_action():
    truth = np.array([[0.0, 0.25, 0.0], [0.0, 0.10, 0.0], [0.0, 0.0, 0.5]])
    inner = truth + [[0.02, 0.0, 0.0], [0.0, 0.04, 0.0], [0.0, 0.0, -0.02]]
    corrected = truth + [[0.01, 0.0, 0.0], [0.0, 0.01, 0.0], [0.0, 0.0, 0.01]]
    actions = np.array([Action.MOVE_FORWARD.value, Action.MOVE_FORWARD.value, Action.TURN_LEFT.value])
    rows = correction_rows(
        corrected,
        inner,
        truth,
        actions,
        np.array([False, True, False]),
        np.array([False, True, False]),
        np.full((3, 3), 0.02),
    )
    by = {(r["action"], r["component"]): r for r in rows}
    assert by[("move_forward", "dx")]["pairs"] == 2 and by[("move_forward", "dx")]["mae"] == pytest.approx(0.005)
    assert by[("move_forward", "dx")]["inner_mae"] == pytest.approx(0.01)
    assert by[(COLLIDED, "dz")]["pairs"] == 1 and by[(COLLIDED, "dz")]["inner_mae"] == pytest.approx(0.04)
    assert by[(COLLIDED, "dz")]["inner_failed"] == 1 and by[("turn_left", "dyaw")]["mae"] == pytest.approx(0.01)
    assert ("turn_right", "dx") not in by and by[("turn_left", "dyaw")]["std"] == pytest.approx(0.02)


class _Counting(Odometer):
    """Answers the identity and records its calls (class-wide, as the estimates' tasks build their own)."""

    steps: ClassVar[list[tuple[str, float]]] = []
    resets: ClassVar[int] = 0

    def __init__(self, tag: str = "a") -> None:
        self.tag = tag
        self.identity_digest = f"counting-{tag}"

    def reset(self, intrinsics):
        super().reset(intrinsics)
        type(self).resets += 1

    def step(self, prev, cur, action):
        type(self).steps.append((self.tag, cur.timestamp))
        return Estimate(np.eye(4))


@pytest.fixture(scope="module")
def tiny_data(tmp_path_factory):
    """Two 3-step train episodes at 64 x 40, one per shard."""
    root = tmp_path_factory.mktemp("data") / "train"
    make_training_data(
        DataConfig(split="train", episodes=2, max_steps=3, width=64, height=40, episodes_per_shard=1),
        root,
        execution=SERIAL,
    )
    return root


def test_stored_estimates_are_made_once_per_episode_in_order_and_reused(tmp_path, tiny_data):
    register_odometer("counting", _Counting)
    _Counting.steps, _Counting.resets = [], 0
    made = make_estimates(tiny_data, "counting", execution=SERIAL)
    data = TrainingData(tiny_data)
    assert len(made.valid) == len(data) == 6 and made.valid.all()
    assert _Counting.resets == 2 and [t for _, t in _Counting.steps] == [1.0, 2.0, 3.0] * 2  # reset per episode
    again = make_estimates(tiny_data, "counting", execution=SERIAL)
    assert len(_Counting.steps) == 6 and np.array_equal(again.transform, made.transform)  # X not run again
    folder = estimates_folder(tiny_data, "counting")
    (folder / data.shards[1]).unlink()  # an interrupted run: the chunk it lacks, and only it, is made
    make_estimates(tiny_data, "counting", execution=SERIAL)
    assert len(_Counting.steps) == 9
    targets = pair_targets(data, again)
    assert np.allclose(targets.residual, data.pair_planar)  # X answered no motion: the residual is the truth


def test_stored_estimates_of_another_x_are_refused_in_one_line(tmp_path, tiny_data):
    register_odometer("counting", _Counting)
    make_estimates(tiny_data, "counting", execution=SERIAL)
    options = tmp_path / "options.toml"
    options.write_text('[odometers."counting"]\ntag = "b"\n')
    _Counting.steps = []
    with pytest.raises(EstimatesError) as err:
        make_estimates(tiny_data, "counting", str(options), execution=SERIAL)
    said = str(err.value)
    assert "\n" not in said and "counting-a" in said and "counting-b" in said and "delete" in said
    assert _Counting.steps == []


def _tiny_recipe(root: Path, inner: str, **kw) -> PoseCorrectorTraining:
    """A recipe of 2 train and 2 val episodes of 4 steps at 64 x 40, data under ``root``."""
    data = {"episodes": 2, "max_steps": 4, "width": 64, "height": 40, "episodes_per_shard": 1}
    return PoseCorrectorTraining(
        model=TINY,
        train_data=DataConfig(split="train", **data),
        val_data=DataConfig(split="val", **data),
        data_root=str(root),
        inner=inner,
        **kw,
    )


@pytest.mark.slow
def test_a_tiny_training_resumes_and_exports_a_model_corrected_x_loads(tmp_path, episode):
    from odolab.learned.pose_corrector.train import run

    cfg = _tiny_recipe(tmp_path / "data", "icp", batch=4, epochs=2, pairs_per_epoch=8)
    kw = {"work": tmp_path / "work", "reports": tmp_path / "rep", "export": tmp_path / "model.pt"}
    assert run(cfg, device=torch.device("cpu"), hours=None, execution=SERIAL, **kw)
    with open(tmp_path / "rep" / "curves.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    val = [r for r in rows if r["split"] == "val" and r["action"] == "move_forward" and r["component"] == "dz"]
    assert len(val) == 2 and all(float(r["mae"]) >= 0 and float(r["inner_mae"]) >= 0 for r in val)
    assert (tmp_path / "rep" / "curves.png").is_file()
    cfg_back, _net, info = load_model(tmp_path / "model.pt")
    assert cfg_back == cfg.model and info["training"]["epochs_done"] == 2 and info["recipe"]["inner"] == "icp"
    more = PoseCorrectorTraining(**{**cfg.__dict__, "epochs": 3})
    assert run(more, device=torch.device("cpu"), hours=None, execution=SERIAL, **{**kw, "export": tmp_path / "m3.pt"})
    assert load_model(tmp_path / "m3.pt")[2]["training"]["epochs_done"] == 3  # resumed: one more epoch
    odo = load_odometer("corrected(icp)", checkpoint=str(tmp_path / "m3.pt"))
    odo.reset(episode.intrinsics)
    assert odo.step(episode[0], episode[1], episode.action(0)).valid


@pytest.mark.parametrize("inner", ["nosuch", "fused(icp", "denoised(nosuch)"])
def test_an_x_that_cannot_be_built_is_refused_before_any_data_is_made(tmp_path, inner):
    from odolab.learned.pose_corrector.train import run

    cfg = _tiny_recipe(tmp_path / "data", inner)
    kw = {"work": tmp_path / "work", "reports": tmp_path / "rep", "export": tmp_path / "model.pt"}
    with pytest.raises(ValueError, match=r"recipe: inner = .*unknown odometer"):
        run(cfg, device=torch.device("cpu"), hours=None, execution=SERIAL, **kw)
    assert not (tmp_path / "data").exists()
