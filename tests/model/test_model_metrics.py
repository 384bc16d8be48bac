"""model.scoring.metrics against hand-computed values; finite for zeros and huge values; clear errors."""

import math

import numpy as np
import pytest

from model.scoring import metrics


def _pair():
    """2x1 image, 3 channels; pixel 1 is background (alpha 0) and must not count."""
    pred = np.array([[[0.5, 0.2, 0.9]], [[100.0, -50.0, 7.0]]])
    target = np.array([[[0.4, 0.4, 0.4]], [[0.0, 0.0, 0.0]]])
    mask = np.array([[1.0], [0.0]])
    return pred, target, mask


def test_hand_computed_values():
    pred, target, mask = _pair()
    # person pixel: errors 0.1, 0.2, 0.5
    assert metrics.l1(pred, target, mask) == pytest.approx((0.1 + 0.2 + 0.5) / 3, rel=1e-12)
    mse = (0.01 + 0.04 + 0.25) / 3
    assert metrics.l2(pred, target, mask) == pytest.approx(mse, rel=1e-12)
    assert metrics.psnr(pred, target, mask) == pytest.approx(10 * math.log10(1.0 / mse), rel=1e-12)
    # soft coverage weights pixels: alpha 0.5 on a second pixel with error 1 everywhere
    p = np.array([[[1.0, 1.0, 1.0]], [[1.0, 1.0, 1.0]]])
    t = np.array([[[1.0, 1.0, 1.0]], [[0.0, 0.0, 0.0]]])
    assert metrics.l1(p, t, np.array([[1.0], [0.5]])) == pytest.approx(0.5 / 1.5, rel=1e-12)
    # no mask: every pixel
    assert metrics.l1(p, t) == pytest.approx(0.5, rel=1e-12)


def test_identical_images_cap_psnr_and_zeros_are_finite():
    zeros = np.zeros((4, 4, 3))
    assert metrics.l1(zeros, zeros) == 0.0 and metrics.l2(zeros, zeros) == 0.0
    assert metrics.psnr(zeros, zeros) == pytest.approx(100.0)  # MSE floored at 1e-10


def test_huge_values_stay_finite():
    big = np.full((2, 2, 3), 1e150)
    value = metrics.psnr(big, np.zeros_like(big))
    # MSE = 1e300 -> PSNR = -3000 dB exactly, no overflow in the squares
    assert math.isfinite(value) and value == pytest.approx(-3000.0, rel=1e-9)
    assert metrics.psnr(np.full((1, 1, 3), 1e300), np.zeros((1, 1, 3))) == pytest.approx(-6000.0, rel=1e-9)
    f32 = np.full((2, 2, 3), 3e38, dtype=np.float32)
    assert math.isfinite(metrics.l2(f32, -f32))


@pytest.mark.parametrize("pred, target, mask, match", [
    (np.zeros((2, 2, 3)), np.zeros((2, 3, 3)), None, "shape"),
    (np.full((2, 2, 3), np.nan), np.zeros((2, 2, 3)), None, "NaN"),
    (np.zeros((2, 2, 3)), np.zeros((2, 2, 3)), np.zeros((2, 2)), "empty"),
    (np.zeros((2, 2, 3)), np.zeros((2, 2, 3)), np.zeros((3, 2)), "mask shape"),
    (np.zeros((2, 3)), np.zeros((2, 3)), None, r"\[H, W, C\]"),
])
def test_bad_input_raises_value_error(pred, target, mask, match):
    with pytest.raises(ValueError, match=match):
        metrics.l1(pred, target, mask)


def test_luminance_ratio_is_the_weighted_mean_luminance_ratio():
    a = np.zeros((2, 2, 3))
    a[0, 0] = [1.0, 1.0, 1.0]
    b = np.full((2, 2, 3), 0.5)
    mask = np.array([[1.0, 0.0], [1.0, 0.0]])
    # masked means: a -> (1 + 0) / 2 = 0.5 luminance, b -> 0.5
    assert metrics.luminance_ratio(a, b, mask) == pytest.approx(1.0)
    assert metrics.luminance_ratio(a, b) == pytest.approx(0.25 / 0.5)
    green = np.zeros((1, 1, 3))
    green[..., 1] = 1.0
    assert metrics.luminance_ratio(green, np.ones((1, 1, 3))) == pytest.approx(0.7152)
    assert np.isnan(metrics.luminance_ratio(b, np.zeros((2, 2, 3))))


def test_spatial_change_ignores_colour_and_exposure_but_sees_moving_light():
    rng = np.random.default_rng(5)
    a = rng.uniform(0.1, 1.0, (16, 16, 3))
    # the same image recoloured and re-exposed: no spatial change, to rounding
    assert metrics.spatial_change(a, a * np.array([0.5, 2.0, 1.3])) < 1e-12
    # light that moves from the left half to the right half: a large change
    left = np.zeros((16, 16, 3))
    left[:, :8] = 1.0
    right = np.zeros((16, 16, 3))
    right[:, 8:] = 1.0
    assert metrics.spatial_change(left, right) == pytest.approx(1.0)


def test_colour_cast_is_zero_up_to_exposure_and_the_angle_between_mean_colours():
    rng = np.random.default_rng(0)
    photo = rng.uniform(0.1, 1.0, (16, 16, 3))
    mask = np.zeros((16, 16))
    mask[4:12, 4:12] = 1.0
    assert metrics.colour_cast_deg(3.7 * photo, photo, mask) < 1e-6
    # a pure-red image against a pure-green one: orthogonal mean colours
    red = np.zeros((4, 4, 3))
    red[..., 0] = 1.0
    green = np.roll(red, 1, axis=-1)
    assert abs(metrics.colour_cast_deg(red, green) - 90.0) < 1e-9
    # grey against (1, 1, 0): arccos(2 / (sqrt(3) sqrt(2)))
    grey = np.ones((4, 4, 3))
    yellow = grey * np.array([1.0, 1.0, 0.0])
    expected = np.degrees(np.arccos(2.0 / np.sqrt(6.0)))
    assert abs(metrics.colour_cast_deg(yellow, grey) - expected) < 1e-9
    # only the masked pixels count
    outside = photo.copy()
    outside[mask == 0] = [1.0, 0.0, 0.0]
    assert metrics.colour_cast_deg(outside, photo, mask) < 1e-6
    with pytest.raises(ValueError):
        metrics.colour_cast_deg(photo, photo, np.zeros((16, 16)))


def test_scale_invariant_psnr_ignores_colour_and_level_only():
    rng = np.random.default_rng(3)
    target = rng.uniform(0.05, 1.0, (16, 12, 3))
    mask = (rng.uniform(size=(16, 12)) > 0.3).astype(np.float32)
    recoloured = target * np.array([2.0, 0.5, 1.3])
    assert metrics.psnr(recoloured, target, mask) < 15
    assert metrics.scale_invariant_psnr(recoloured, target, mask) == pytest.approx(100.0)  # MSE floor
    # a pattern error is not forgiven: the gains are the least-squares ones, so the score is
    # the PSNR of k * pred with k_c = sum(w p t) / sum(w p^2), computed here by hand
    wrong = target[::-1] * 0.7
    k = (mask[..., None] * wrong * target).sum((0, 1)) / (mask[..., None] * wrong * wrong).sum((0, 1))
    mse = (mask[..., None] * (k * wrong - target) ** 2).sum() / (3 * mask.sum())
    assert metrics.scale_invariant_psnr(wrong, target, mask) == pytest.approx(10 * math.log10(1 / mse), rel=1e-9)
    assert metrics.scale_invariant_psnr(wrong, target, mask) >= metrics.psnr(wrong, target, mask)
    assert set(metrics.all_metrics(wrong, target, mask)) == {"l1", "l2", "psnr", "si_psnr"}


def _response_images(seed: int = 0, shape=(24, 32)):
    """A grey photo, a true log change x (centred, RMS 0.3) and a noise n orthogonal to x and to
    the constant (so the derivation's expectations hold exactly, not only on average)."""
    rng = np.random.default_rng(seed)
    photo = rng.uniform(0.05, 0.9, shape)[..., None] * np.ones(3)
    x = rng.normal(0.0, 1.0, shape)
    x -= x.mean()
    x *= 0.3 / np.sqrt((x * x).mean())
    n = rng.normal(0.0, 1.0, shape)
    n -= n.mean()
    n -= (n * x).sum() / (x * x).sum() * x
    return photo, x, n / np.sqrt((n * n).mean())


@pytest.mark.parametrize("k", [1.0, 0.44, 2.5, -0.7])
def test_light_response_of_k_times_the_true_change_is_slope_k_correlation_one(k):
    photo, x, _ = _response_images()
    target = photo * np.exp(x)[..., None]
    # an exposure change on top (a constant log change) is no pattern: means are removed
    relit = photo * np.exp(k * x + 0.8)[..., None]
    r = metrics.light_response(photo, relit, target)
    assert r.slope == pytest.approx(k, abs=1e-9)
    assert r.correlation == pytest.approx(np.sign(k), abs=1e-9)
    assert r.pixels == x.size


@pytest.mark.parametrize("k, sn", [(1.0, 0.3), (0.5, 0.3), (1.0, 0.1), (0.44, 0.6)])
def test_light_response_noise_keeps_the_slope_and_lowers_the_correlation_as_derived(k, sn):
    """y = k x + n, n uncorrelated with x: slope k, correlation k sx / sqrt(k^2 sx^2 + sn^2)."""
    photo, x, n = _response_images(1)
    sx = 0.3
    relit = photo * np.exp(k * x + sn * n)[..., None]
    r = metrics.light_response(photo, relit, photo * np.exp(x)[..., None])
    assert r.slope == pytest.approx(k, abs=1e-9)
    assert r.correlation == pytest.approx(k * sx / np.sqrt(k * k * sx * sx + sn * sn), abs=1e-9)


def test_light_response_counts_only_the_masks_pixels_weighted():
    """Outside the mask the relit change may be anything; a weight of 2 counts a pixel twice."""
    photo, x, _ = _response_images(2)
    mask = np.zeros(x.shape)
    mask[:, :16] = 1.0
    relit = photo * np.exp(np.where(mask > 0, 0.6 * x, -3.0 * x))[..., None]
    r = metrics.light_response(photo, relit, photo * np.exp(x)[..., None], mask)
    assert r.slope == pytest.approx(0.6, abs=1e-9) and r.pixels == 24 * 16
    # weighted least squares: the same pixel set duplicated equals a weight of 2
    a, b, t = photo[:, :2], relit[:, :2], (photo * np.exp(x)[..., None])[:, :2]
    w = np.array([[2.0, 1.0]] * 24)
    doubled = metrics.light_response(np.concatenate([a, a[:, :1]], 1), np.concatenate([b, b[:, :1]], 1),
                                     np.concatenate([t, t[:, :1]], 1))
    assert metrics.light_response(a, b, t, w).slope == pytest.approx(doubled.slope, abs=1e-12)


def test_light_response_degenerate_inputs():
    photo, x, _ = _response_images(3)
    target = photo * np.exp(x)[..., None]
    # the photo returned as it is (identity, or an exposure change of it): no response, 0 and 0
    assert metrics.light_response(photo, photo, target)[:2] == (0.0, 0.0)
    assert metrics.light_response(photo, photo * 1.7, target)[:2] == (0.0, 0.0)
    # nothing to follow (the truth is the photo up to exposure): NaN, left out of means
    none = metrics.light_response(photo, photo * np.exp(x)[..., None], photo * 2.0)
    assert np.isnan(none.slope) and np.isnan(none.correlation)
    # black pixels are floored (LOG_FLOOR), not -inf
    dark = metrics.light_response(photo * 0.0, photo, target)
    assert np.isfinite(dark.slope) and np.isfinite(dark.correlation)
    with pytest.raises(ValueError, match="mask is empty"):
        metrics.light_response(photo, photo, target, np.zeros(x.shape))
    bad = target.copy()
    bad[0, 0, 1] = np.nan
    for args in ((bad, photo, target), (photo, bad, target), (photo, photo, bad)):
        with pytest.raises(ValueError, match="NaN or Inf"):
            metrics.light_response(*args)
    with pytest.raises(ValueError, match="shape"):
        metrics.light_response(photo, photo[:, :3], target)
