"""Texture tiles: the spectral Gaussian filter against scipy's, equalisation, and the tiles themselves."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
import scipy.ndimage

from odolab.sim import textures
from odolab.sim.textures import _equalise, gaussian_filter, make_tiles

#: sha256 of ``make_tiles()``'s bytes: the tiles every committed episode was rendered with.
DEFAULT_TILES_SHA256 = "00bbb02afcef1e108ab15442e130d081f7934ba69fd519e73203bb49018cf130"


@pytest.mark.parametrize("sigma", [0.8, 1.0, 3.0, 9.0, 27.0, (0.8, 12.0), (5.0, 2.0), 0.0, (0.0, 3.0)])
@pytest.mark.parametrize("shape", [(64, 64), (48, 80), (512, 512)])
def test_gaussian_filter_matches_scipy_wrap(sigma, shape):
    img = np.random.default_rng(3).standard_normal(shape)
    want = scipy.ndimage.gaussian_filter(img, sigma, mode="wrap")
    np.testing.assert_allclose(gaussian_filter(img, sigma), want, rtol=0, atol=1e-12)


def test_gaussian_filter_kernel_longer_than_image_wraps_like_scipy():
    img = np.random.default_rng(4).standard_normal((16, 24))  # radius 36 > both sizes
    want = scipy.ndimage.gaussian_filter(img, 9.0, mode="wrap")
    np.testing.assert_allclose(gaussian_filter(img, 9.0), want, rtol=0, atol=1e-12)


def test_gaussian_filter_refuses_other_modes():
    with pytest.raises(ValueError, match="wrap"):
        gaussian_filter(np.zeros((8, 8)), 1.0, mode="reflect")


def test_equalise_is_the_stable_rank_with_ties():
    img = np.random.default_rng(5).integers(0, 7, size=(9, 11)).astype(float)  # many ties
    ranks = np.argsort(np.argsort(img, axis=None, kind="stable"), kind="stable")
    np.testing.assert_array_equal(_equalise(img), (ranks / (img.size - 1)).reshape(img.shape))


def test_make_tiles_same_as_with_scipys_filter(monkeypatch):
    ours = make_tiles.__wrapped__(count=6)  # one tile of each pattern
    monkeypatch.setattr(textures, "gaussian_filter", scipy.ndimage.gaussian_filter)
    np.testing.assert_array_equal(ours, textures.make_tiles.__wrapped__(count=6))


def test_make_tiles_default_bytes_unchanged():
    tiles = make_tiles()
    assert tiles.shape == (12, 512, 512) and tiles.dtype == np.float32 and not tiles.flags.writeable
    assert hashlib.sha256(tiles.tobytes()).hexdigest() == DEFAULT_TILES_SHA256
