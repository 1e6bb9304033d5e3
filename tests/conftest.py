"""Shared fixtures: tiny cameras and short episodes keep the suite fast on 2 cores."""

from __future__ import annotations

import shutil
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest

from odolab.sim.camera import CameraSpec
from odolab.sim.episodes import EpisodeSpec
from tests.helpers import TUM_DIR, BlindComposite, Truth

SMALL_CAMERA = CameraSpec(width=96, height=54)


@pytest.fixture
def small_spec() -> EpisodeSpec:
    """A 15-step test-split episode seen through a 96 x 54 camera."""
    return EpisodeSpec(split="test", index=0, seed=0, max_steps=15, camera=SMALL_CAMERA)


@pytest.fixture(autouse=True)
def _registered_odometers_are_the_tests_own():
    """An odometer a test registers is gone after it: no test sees another's (odolab.odometry.odometer.REGISTRY)."""
    from odolab.odometry.odometer import REGISTRY

    before = dict(REGISTRY._extra)
    yield
    REGISTRY._extra.clear()
    REGISTRY._extra.update(before)


@pytest.fixture()
def oracle_calibration(tmp_path) -> str:
    """A fusion calibration of the action prior and ``test-truth`` (an oracle); registers ``test-truth``
    and ``test-blind``, a composite that hides its input's oracle nature."""
    from odolab.api import register_odometer
    from odolab.fusion.calibration import Calibration, InputCalibration

    fixed = {a: [0.01, 0.01, 0.01, 0.02, 0.02, 0.02] for a in ("move_forward", "turn_left", "turn_right")}
    one = InputCalibration(fixed, {a: None for a in fixed}, {a: 100 for a in fixed})
    path = tmp_path / "cal.json"
    Calibration({"action-prior": one, "test-truth": one}).save(path)
    register_odometer("test-truth", Truth)
    register_odometer("test-blind", BlindComposite)
    return str(path)


@pytest.fixture()
def millimetre_folder(tmp_path) -> Path:
    """The 10-frame TUM sequence with its depth rewritten in millimetres, in a folder whose name
    names no TUM camera."""
    import cv2

    dst = tmp_path / "my_recording"
    shutil.copytree(TUM_DIR, dst)
    for png in (dst / "depth").glob("*.png"):
        raw = cv2.imread(str(png), cv2.IMREAD_UNCHANGED)
        cv2.imwrite(str(png), np.round(raw / 5.0).astype(np.uint16))
    return dst


@pytest.fixture(scope="session")
def ray_cluster() -> Iterator[str]:
    """A local Ray cluster of two nodes with one CPU each (``ray.cluster_utils``), started once for the
    tests that run on a cluster; its address. Those tests run last (:func:`pytest_collection_modifyitems`),
    so its idle daemons slow no other test; each test disconnects (``ray.shutdown``) when it is done."""
    cluster_utils = pytest.importorskip("ray.cluster_utils")
    import ray

    cluster = cluster_utils.Cluster(initialize_head=True, head_node_args={"num_cpus": 1})
    try:
        cluster.add_node(num_cpus=1)
        cluster.wait_for_nodes()
        yield cluster.address
    finally:
        ray.shutdown()
        cluster.shutdown()


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    """The tests on the shared Ray cluster run last, one after another (the sort keeps each group's order)."""
    items.sort(key=lambda item: "ray_cluster" in getattr(item, "fixturenames", ()))
