"""odolab/learned/depth_corrector: the U-Net answers the input depth until trained, ``denoised(X)`` answers
exactly X with an untrained model, a model file that does not fit its network is refused in one
line, the validation rows are what they say, and a tiny training run resumes and exports."""

from __future__ import annotations

import numpy as np
import pytest
import torch

from odolab.api import load_odometer
from odolab.learned.depth_corrector.checkpoint import load_model, save_model
from odolab.learned.depth_corrector.config import CorrectorModel, CorrectorTraining
from odolab.learned.depth_corrector.model import DepthCorrectorNet, base_spread, pixel_place
from odolab.learned.depth_corrector.train import bin_labels, depth_edges, depth_error_rows
from odolab.learned.training import CheckpointError, DataConfig
from odolab.sim.episodes import EpisodeSpec, render_episode
from tests.conftest import SMALL_CAMERA

TINY = CorrectorModel(base=2, levels=2)


def _untrained(path, model: CorrectorModel = TINY) -> str:
    torch.manual_seed(0)
    save_model(path, CorrectorTraining(model=model), DepthCorrectorNet(model), {"note": "untrained"})
    return str(path)


@pytest.fixture(scope="module")
def episode():
    """A 5-step episode through a 96 x 54 camera: ``denoised`` resizes it to the model's 341 x 192."""
    return render_episode(EpisodeSpec(split="val", index=0, seed=0, max_steps=5, camera=SMALL_CAMERA))


def test_an_untrained_network_answers_the_input_depth_and_the_base_spread():
    net = DepthCorrectorNet(TINY).eval()
    rgb = torch.randint(0, 255, (2, 30, 45, 3), dtype=torch.uint8)
    depth = torch.rand(2, 30, 45) * 6 * (torch.rand(2, 30, 45) > 0.1)
    with torch.inference_mode():
        corrected, spread = net(rgb, depth, pixel_place(30, 45)[None].expand(2, -1, -1, -1))
    assert torch.equal(corrected, depth)  # the last layer starts at zero: exactly the input (0 stays 0)
    assert torch.allclose(spread, base_spread(depth))


def test_pixel_place_of_a_window_is_its_place_in_the_full_frame():
    full = pixel_place(192, 341)
    window = pixel_place(20, 30, top=50, left=100, full=(192, 341))
    assert torch.equal(window, full[:, 50:70, 100:130])
    assert full[0].min() > -1 and full[0].max() < 1 and full[0, 0, 0] < full[0, 0, 1]  # x grows to the right


def test_denoised_with_an_untrained_model_answers_exactly_its_inner_odometer(tmp_path, episode):
    model = _untrained(tmp_path / "untrained.pt", CorrectorModel(base=2, levels=2))
    inner = load_odometer("icp")
    wrapped = load_odometer("denoised(icp)", checkpoint=model)
    assert wrapped.oracle is False and wrapped.identity_digest != inner.identity_digest
    for odo in (inner, wrapped):
        odo.reset(episode.intrinsics)
    for i in range(len(episode) - 1):
        a = inner.step(episode[i], episode[i + 1], episode.action(i))
        b = wrapped.step(episode[i], episode[i + 1], episode.action(i))
        assert a.valid == b.valid and np.array_equal(a.transform, b.transform)


def test_denoised_takes_one_inner_odometer_and_a_spread_in_metres(tmp_path):
    model = _untrained(tmp_path / "m.pt")
    with pytest.raises(ValueError, match=r"denoised takes one inner odometer, e.g. denoised\(open3d-rgbd\), got 2"):
        load_odometer("denoised(icp,open3d-rgbd)", checkpoint=model)
    with pytest.raises(ValueError, match=r"max_spread must be in \[0, 100\], got -1"):
        load_odometer("denoised(icp)", checkpoint=model, max_spread=-1)


def test_a_model_file_that_does_not_fit_its_network_is_refused_in_one_line(tmp_path):
    path = tmp_path / "bad.pt"
    _untrained(path)
    doc = torch.load(path, weights_only=True)
    doc["model"]["base"] = 3  # the weights are of base 2
    torch.save(doc, path)
    with pytest.raises(CheckpointError) as err:
        load_model(path)
    said = str(err.value)
    assert "\n" not in said and str(path) in said and "do not fit" in said


def test_depth_edges_mark_both_sides_of_a_jump_and_of_a_hole():
    d = np.full((5, 6), 2.0, np.float32)
    d[:, 3:] = 3.0  # a jump between columns 2 and 3
    d[0, 0] = 0.0  # a hole
    edges = depth_edges(d)
    assert edges[:, 2].all() and edges[:, 3].all() and not edges[2:, 0].any() and not edges[:, 5].any()
    assert edges[0, 0] and edges[0, 1] and edges[1, 0]


def test_depth_error_rows_bin_by_true_distance_over_pixels_with_both_readings():
    clean = np.array([[0.5, 1.5, 2.5, 5.5, 0.0, 1.5]], np.float32)
    noisy = np.array([[0.6, 1.2, 0.0, 5.0, 1.0, 1.5]], np.float32)
    corrected = np.array([[0.5, 1.4, 0.0, 5.4, 1.0, 1.5]], np.float32)
    rows = {r["where"]: r for r in depth_error_rows(noisy, corrected, clean)}
    assert rows["all"]["pixels"] == 4  # no reading in the noisy (2.5) or the true depth (0.0): left out
    assert rows["1-2 m"]["pixels"] == 2 and rows["1-2 m"]["mae_noisy"] == pytest.approx(0.15)
    assert rows["1-2 m"]["mae_corrected"] == pytest.approx(0.05)
    assert rows["5+ m"]["mae_noisy"] == pytest.approx(0.5) and "2-3 m" not in rows
    assert bin_labels() == ["0-1 m", "1-2 m", "2-3 m", "3-4 m", "4-5 m", "5+ m"]


def test_a_recipe_needs_clean_depth_and_a_crop_that_fits():
    with pytest.raises(ValueError, match="train data: clean_depth must be true"):
        CorrectorTraining(train_data=DataConfig(width=341, height=192))
    with pytest.raises(ValueError, match=r"the crop \(400 x 96 px\) must fit the model's 341 x 192"):
        CorrectorTraining(crop_width=400)


@pytest.mark.slow
def test_a_tiny_training_resumes_lowers_the_error_and_exports(tmp_path, monkeypatch):
    from odolab.core.parallel import SERIAL
    from odolab.learned.depth_corrector.train import run

    data = {"episodes": 2, "max_steps": 4, "width": 64, "height": 40, "clean_depth": True}
    cfg = CorrectorTraining(
        model=CorrectorModel(width=64, height=40, base=4, levels=2),
        train_data=DataConfig(split="train", **data),
        val_data=DataConfig(split="val", **data),
        data_root=str(tmp_path / "data"),
        crop_height=32,
        crop_width=48,
        batch=4,
        epochs=2,
        frames_per_epoch=16,
        lr=5e-3,
    )
    kw = {"work": tmp_path / "work", "reports": tmp_path / "rep", "export": tmp_path / "model.pt"}
    assert run(cfg, device=torch.device("cpu"), hours=None, execution=SERIAL, **kw)
    rows = (tmp_path / "rep" / "curves.csv").read_text().splitlines()
    assert rows[0].startswith("epoch,split,loss,frames") and any(",val," in r and ",all," in r for r in rows)
    cfg_back, _net, info = load_model(tmp_path / "model.pt")
    assert cfg_back == cfg.model and info["training"]["epochs_done"] == 2
    more = CorrectorTraining(**{**cfg.__dict__, "epochs": 3})
    assert run(more, device=torch.device("cpu"), hours=None, execution=SERIAL, **{**kw, "export": tmp_path / "m3.pt"})
    assert load_model(tmp_path / "m3.pt")[2]["training"]["epochs_done"] == 3  # resumed: one more epoch
    # interrupted (Ctrl-C): the figure, redrawn after an epoch at most once a minute, is drawn as it stops
    from odolab.learned.training import EpochLoop

    figure = tmp_path / "rep" / "curves.png"
    figure.write_bytes(b"drawn a moment ago")

    def interrupted(*args, **kwargs):
        raise KeyboardInterrupt

    monkeypatch.setattr(EpochLoop, "run", interrupted)
    with pytest.raises(KeyboardInterrupt):
        run(more, device=torch.device("cpu"), hours=None, execution=SERIAL, **{**kw, "export": tmp_path / "m4.pt"})
    assert figure.read_bytes().startswith(b"\x89PNG")


def test_noiseless_depth_is_an_oracle_that_gives_its_inner_odometer_the_simulators_depth(episode):
    from odolab.api import Frame

    odo = load_odometer("noiseless-depth(icp)")
    assert odo.oracle is True and load_odometer("icp").oracle is False
    inner = load_odometer("icp")
    for o in (odo, inner):
        o.reset(episode.intrinsics)
    frames = [episode[i] for i in range(len(episode))]
    assert all(f.clean_depth is not None and f.clean_depth.shape == f.depth.shape for f in frames)
    assert any(not np.array_equal(f.clean_depth, f.depth) for f in frames)  # the noise is there to remove
    clean = [Frame(f.rgb, f.clean_depth, f.timestamp, f.gt_pose) for f in frames]
    for i in range(len(frames) - 1):
        a = odo.step(frames[i], frames[i + 1], episode.action(i))
        b = inner.step(clean[i], clean[i + 1], episode.action(i))
        assert a.valid == b.valid and np.array_equal(a.transform, b.transform)
    with pytest.raises(ValueError, match="noiseless-depth: this frame has no noiseless depth"):
        odo.step(clean[0], clean[1], episode.action(0))
