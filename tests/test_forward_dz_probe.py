"""studies/robust_vo/forward_dz_probe: the geometric bound it reports behaves as stated (with the true
dx and yaw the median depth residual gives dz; errors in them make it worse)."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("torch")  # a declared dependency; skip only where it is truly absent

from odolab.api import Action
from odolab.core.parallel import SERIAL
from odolab.learned.training import DataConfig, TrainingData, make_training_data
from odolab.sim.episodes import NoiseConfig
from studies.robust_vo.forward_dz_probe import residual


@pytest.fixture(scope="module")
def data(tmp_path_factory) -> TrainingData:
    cfg = DataConfig(
        split="val",
        episodes=1,
        max_steps=20,
        width=96,
        height=54,
        episodes_per_shard=1,
        noise=NoiseConfig(rgb=0.0, depth=0.0, actuation=0.5),
    )
    root = tmp_path_factory.mktemp("dz-probe") / "data"
    make_training_data(cfg, root, execution=SERIAL)
    return TrainingData(root)


def test_the_depth_residual_gives_dz_when_dx_and_yaw_are_known(data):
    idx = data.select([Action.MOVE_FORWARD])
    assert len(idx) >= 5
    exact = residual(data, idx, 0.0)
    off = residual(data, idx, 0.03)
    assert np.nanmedian(exact) < 0.005  # noiseless depth: a few millimetres
    assert np.nanmean(off) > np.nanmean(exact)
