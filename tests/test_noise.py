"""Noise models against their formulas (docs/reference-facts.md section 2), by statistics over many samples."""

import numpy as np
import pytest
from scipy.stats import norm

from odolab.core.types import Action
from odolab.sim.noise import ActuationNoise, GaussianTable, RedwoodDepthNoise, RGBNoise, habitat_normalized_depth
from odolab.sim.redwood import load_table, surrogate_table

TRUNC3_VAR = 1 - 2 * 3 * norm.pdf(3) / (norm.cdf(3) - norm.cdf(-3))  # variance factor of a +-3 sigma cut


def test_gaussian_table_is_standard_normal():
    z = GaussianTable().draw(np.random.default_rng(0), (400_000,))
    assert z.dtype == np.float32
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1) < 0.01
    for q in (0.01, 0.1, 0.5, 0.9, 0.99):
        assert np.quantile(z, q) == pytest.approx(norm.ppf(q), abs=0.02)


def test_rgb_noise_std_and_mean():
    img = np.full((300, 400, 3), 128, np.uint8)
    out = RGBNoise().apply(img, np.random.default_rng(1)).astype(float)
    # clip(img/255 + 0.1 N) * 255, stored as uint8 (truncation: mean drops by 0.5)
    assert out.mean() == pytest.approx(127.5, abs=0.15)
    assert out.std() == pytest.approx(np.sqrt(25.5**2 + 1 / 12), rel=0.01)


def test_rgb_noise_clips_and_zero_multiplier_is_exact():
    img = np.full((100, 100, 3), 250, np.uint8)
    out = RGBNoise().apply(img, np.random.default_rng(2))
    assert out.max() == 255 and (out == 255).mean() > 0.3
    assert np.array_equal(RGBNoise(multiplier=0).apply(img, np.random.default_rng(2)), img)


def test_redwood_disparity_quantisation_matches_formula():
    d = 2.0
    depth = np.full((480, 640), d, np.float32)
    out = RedwoodDepthNoise(use_distortion=False).apply(depth, np.random.default_rng(3))
    denom = np.round(35.130 * 8 / out).astype(int)
    assert np.allclose(35.130 * 8 / denom, out, rtol=1e-6)  # every value is a quantisation level
    # denom = round((35.13/d + 0.027778 N) * 8): P(denom = k) from the normal CDF
    centre = 35.130 / d * 8
    sigma = 0.027778 * 8
    n = out.size
    for k in (140, 141):
        p = norm.cdf((k + 0.5 - centre) / sigma) - norm.cdf((k - 0.5 - centre) / sigma)
        assert (denom == k).sum() == pytest.approx(p * n, abs=5 * np.sqrt(n * p * (1 - p)) + 1)


def test_redwood_jitter_and_downsampling():
    H, W = 400, 64
    b = 32  # even column where the depth steps from 1 m to 3 m
    depth = np.where(np.arange(W)[None, :] < b, 1.0, 3.0).astype(np.float32).repeat(H, 0)
    out = RedwoodDepthNoise(use_distortion=False).apply(depth, np.random.default_rng(4))
    far = out > 2.0
    # column b-1 reads column b (then rounded down to even b) iff 0.25 N >= 0.5, i.e. N >= 2
    assert far[:, b - 1].mean() == pytest.approx(norm.sf(2.0), abs=0.02)
    assert not far[:, b - 2].any() and far[:, b + 2].all()
    # column b reads b-1 -> b-2 (near) iff N <= -2
    assert (~far[:, b]).mean() == pytest.approx(norm.cdf(-2.0), abs=0.02)


def test_redwood_far_and_missing_give_no_reading():
    depth = np.full((50, 50), 12.0, np.float32)
    depth[:, :10] = 0.0
    out = RedwoodDepthNoise().apply(depth, np.random.default_rng(5))
    assert np.all(out[:, 12:] == 0) and np.all(out[:, :8] == 0)
    clean = RedwoodDepthNoise(multiplier=0).apply(np.full((4, 4), 3.3, np.float32), np.random.default_rng(0))
    assert np.all(clean == np.float32(3.3))


def _habitat_redwood_reference(depth, table, rng, multiplier=1.0):
    """habitat-sim's RedwoodNoiseModelCPUImpl._simulate, pixel by pixel, then habitat-lab's clip to
    [0.1, 10] m (holes and readings below 0.1 m as 0): an independent transcription."""
    H, W = depth.shape
    ymax, xmax = H - 1.0, W - 1.0
    rand = rng.standard_normal((H, W, 3))
    out = np.zeros((H, W))
    for j in range(H):
        for i in range(W):
            y = int(min(max(j + rand[j, i, 0] * 0.25 * multiplier, 0.0), ymax) + 0.5)
            x = int(min(max(i + rand[j, i, 1] * 0.25 * multiplier, 0.0), xmax) + 0.5)
            d = depth[y - y % 2, x - x % 2]
            if d >= 10.0 or d <= 0:
                continue
            xx, yy = int(x / xmax * 639.0 + 0.5) // 8, int(y / ymax * 479.0 + 0.5) // 6
            i2 = int((d + 1) / 2)
            i1 = i2 - 1
            a = (d - (i1 * 2.0 + 1.0)) / 2.0
            f = (1.0 - a) * table[yy, xx, min(max(i1, 0), 4)] + a * table[yy, xx, min(i2, 4)]
            if f < 1e-5:
                continue
            denom = round((35.130 / (d / f) + rand[j, i, 2] * 0.027778 * multiplier) * 8.0)
            if denom > 1e-5:
                out[j, i] = min(35.130 * 8.0 / denom, 10.0)
    out[out < 0.1] = 0.0
    return out


@pytest.mark.parametrize("d", [1.5, 3.0, 5.5, 8.5])
def test_redwood_distortion_matches_habitat_statistics(d):
    """Hole share and location, bias and spread per depth, against the pixel-by-pixel reference."""
    table = surrogate_table()
    depth = np.full((192, 341), d, np.float32)
    ours = RedwoodDepthNoise(distortion=table).apply(depth, np.random.default_rng(7))
    ref = _habitat_redwood_reference(depth, table.factors, np.random.default_rng(8))
    for out in (ours, ref):
        assert 0.10 < (out == 0).mean() < 0.125  # the hole band: ~11 % of a 341 x 192 frame
    # holes where the table's hole cells are: the borders, widest on the right
    assert (ours[:, -15:] == 0).mean() > 0.95 and (ours[10:-10, 10:-25] == 0).mean() < 0.001
    assert abs((ours == 0).mean() - (ref == 0).mean()) < 0.004
    assert np.mean((ours == 0) == (ref == 0)) > 0.99
    a, b = ours[ours > 0] / d - 1, ref[ref > 0] / d - 1
    assert abs(a.mean() - b.mean()) < 0.002 + 0.1 * abs(b.mean())
    assert a.std() == pytest.approx(b.std(), rel=0.05)


def test_redwood_distortion_widens_the_spread_beyond_3m():
    """The table adds a cell-dependent scale error: within 1 % on average, but beyond 3 m it at
    least doubles the spread of the disparity noise alone (measured on habitat-sim's table:
    0.025 vs 0.004 at 5.5 m, 0.033 vs 0.010 at 9 m)."""
    table = surrogate_table()
    for d in (2.0, 5.5, 9.0):
        depth = np.full((192, 341), d, np.float32)
        rel = {}
        for use in (True, False):
            out = RedwoodDepthNoise(distortion=table if use else None, use_distortion=use).apply(
                depth, np.random.default_rng(9)
            )
            rel[use] = out[out > 0] / d - 1
        assert abs(rel[True].mean()) < 0.01
        if d > 3:
            assert rel[True].std() > 2 * rel[False].std()


def test_redwood_table_files_are_checked(tmp_path):
    good = tmp_path / "table.npy"
    np.save(good, np.ones((80, 400), np.float32))
    assert load_table(good).factors.shape == (80, 80, 5)
    bad = tmp_path / "bad.npy"
    np.save(bad, np.ones((80, 80), np.float32))
    with pytest.raises(ValueError, match="bad.npy.*32000"):
        load_table(bad)
    junk = tmp_path / "junk.npy"
    junk.write_bytes(b"not numpy")
    with pytest.raises(ValueError, match="junk.npy"):
        load_table(junk)


def test_range_clip_like_habitat_lab():
    depth = np.full((40, 40), 9.99, np.float32)
    out = RedwoodDepthNoise(use_distortion=False).apply(depth, np.random.default_rng(10))
    assert out.max() <= 10.0 and (out == 10.0).any()  # noisy readings past 10 m are clipped to 10 m
    assert np.allclose(habitat_normalized_depth(np.array([0.0, 0.1, 5.05, 10.0])), [0, 0, 0.5, 1])


def _samples(action, n=20_000, mult=0.5):
    rng = np.random.default_rng(6)
    noise = ActuationNoise("proportional", mult)
    return np.array([[m.forward, m.right, m.yaw] for m in (noise.sample(action, rng) for _ in range(n))])


def test_actuation_forward_statistics():
    s = _samples(Action.MOVE_FORWARD)
    mean = np.array([0.25 + 0.5 * 0.017, 0.5 * 0.042, 0.5 * 0.031])
    std = 0.5 * np.sqrt([0.007, 0.023, 0.026]) * np.sqrt(TRUNC3_VAR)
    assert s.mean(0) == pytest.approx(mean, abs=4 * std.max() / np.sqrt(len(s)))
    assert s.std(0) == pytest.approx(std, rel=0.03)
    # truncated at +-3 sigma around the mean
    assert np.all(np.abs(s - mean) <= 3 * 0.5 * np.sqrt([0.007, 0.023, 0.026]) + 1e-12)


def test_actuation_turns_overshoot_symmetrically():
    left, right = _samples(Action.TURN_LEFT), _samples(Action.TURN_RIGHT)
    turn = np.radians(30)
    assert left[:, 2].mean() == pytest.approx(turn + 0.5 * 0.043, abs=0.002)
    assert right[:, 2].mean() == pytest.approx(-turn - 0.5 * 0.043, abs=0.002)
    assert left[:, 2].std() == pytest.approx(0.5 * np.sqrt(0.017 * TRUNC3_VAR), rel=0.03)
    assert left[:, 0].mean() == pytest.approx(0.5 * 0.001, abs=0.001)


def test_zero_multiplier_is_exact_motion():
    s = _samples(Action.TURN_RIGHT, n=10, mult=0.0)
    assert np.allclose(s, [0.0, 0.0, -np.radians(30)])
    with pytest.raises(ValueError, match="controller"):
        ActuationNoise("pid")


def test_a_bad_table_named_by_the_environment_is_one_line(tmp_path, monkeypatch):
    from odolab.sim.redwood import default_table

    bad = tmp_path / "table.npy"
    bad.write_text("not numpy")
    monkeypatch.setenv("ODOLAB_REDWOOD_TABLE", str(bad))
    with pytest.raises(ValueError, match=r"^ODOLAB_REDWOOD_TABLE: .*table.npy: not a .npy file"):
        default_table()
    np.save(bad, np.ones(3, np.float32))
    with pytest.raises(ValueError, match="expected 32000 float values"):
        default_table()
