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
