"""Data-parallel training on Ray Train: two workers sharing each batch, one on each node of a two-node
local cluster, follow one worker."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("ray.train.torch")

from odolab.core.parallel import SERIAL, Execution
from odolab.learned.robust_vo import train as trainer
from odolab.learned.robust_vo.config import ModelConfig, StageConfig, TrainConfig
from odolab.learned.training import ComputeConfig, make_training_data
from odolab.sim.training_data import DataConfig

pytestmark = pytest.mark.slow

W, H = 64, 36
#: Relative difference allowed between the validation errors of 1 and 2 workers. Two workers differ
#: from one only by the order of floating-point sums and by the input normaliser's statistics (the
#: average of two halves' running statistics, where one worker merges the whole batch's).
TOLERANCE = 0.05


def _recipe(root) -> TrainConfig:
    data = DataConfig(split="train", episodes=2, max_steps=16, width=W, height=H, episodes_per_shard=1)
    model = ModelConfig(width=W, height=H, base_planes=8, groups=4, hidden=32, compress_channels=8, dropout=0.0)
    stages = (StageConfig("forward", ("move_forward",), 2, lr=1e-3, batch=8),)
    return TrainConfig(
        model=model,
        stages=stages,
        train_data=data,
        val_data=dataclasses.replace(data, split="val", episodes=1),
        data_root=str(root),
        val_pairs=20,
        seed=3,
        compute=ComputeConfig(precision="fp32", loader_workers=0),
    )


@pytest.fixture(scope="module")
def recipe(tmp_path_factory) -> TrainConfig:
    cfg = _recipe(tmp_path_factory.mktemp("dp-data"))
    for data in (cfg.train_data, cfg.val_data):
        make_training_data(data, cfg.data_folder(data), execution=SERIAL)
    return cfg


def _train(cfg: TrainConfig, root, ray_address: str | None = None, **kw) -> dict:
    done = trainer.run(
        cfg,
        work=root / "work",
        reports=root / "reports",
        export=root / "model.pt",
        device=torch.device("cpu"),
        hours=None,
        execution=Execution(ray_address=ray_address, parallel=False, progress=False),
        **kw,
    )
    assert done and (root / "model.pt").is_file()
    return {"status": json.loads((root / "reports" / "training.json").read_text())}


def _val_errors(root) -> np.ndarray:
    import csv

    with open(root / "reports" / "curves.csv", encoding="utf-8") as f:
        rows = [r for r in csv.DictReader(f) if r["split"] == "val"]
    last = max(int(r["epoch"]) for r in rows)
    return np.array([float(r["mae"]) for r in rows if int(r["epoch"]) == last])


def test_two_workers_on_a_two_node_cluster_follow_one_worker(recipe, tmp_path, ray_cluster):
    import ray

    one = _train(recipe, tmp_path / "one")
    try:
        ray.init(address=ray_cluster, include_dashboard=False, log_to_driver=False)
        assert len([n for n in ray.nodes() if n["Alive"]]) == 2  # one CPU each: a worker per node
        two = _train(recipe, tmp_path / "two", workers=2, ray_address=ray_cluster)
    finally:
        ray.shutdown()
    assert two["status"]["compute"]["workers"] == 2
    one_err, two_err = _val_errors(tmp_path / "one"), _val_errors(tmp_path / "two")
    assert one_err.shape == two_err.shape and one_err.size
    np.testing.assert_allclose(two_err, one_err, rtol=TOLERANCE)
    # the same samples were seen: every worker's share of every batch counts once
    seen = [r["status"]["stages"]["forward"]["pairs_seen"] for r in (one, two)]
    assert seen[0] == seen[1] > 0
