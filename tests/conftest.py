"""Shared fixtures: tiny cameras and short episodes keep the suite fast on 2 cores."""

from __future__ import annotations

import pytest

from odolab.episodes import EpisodeSpec
from odolab.sim.camera import CameraSpec

SMALL_CAMERA = CameraSpec(width=96, height=54)


@pytest.fixture
def small_spec() -> EpisodeSpec:
    """A 15-step test-split episode seen through a 96 x 54 camera."""
    return EpisodeSpec(split="test", index=0, seed=0, max_steps=15, camera=SMALL_CAMERA)


@pytest.fixture(autouse=True)
def _registered_odometers_are_the_tests_own():
    """An odometer a test registers is gone after it: no test sees another's (odolab.odometer.REGISTRY)."""
    from odolab.odometer import REGISTRY

    before = dict(REGISTRY._extra)
    yield
    REGISTRY._extra.clear()
    REGISTRY._extra.update(before)
