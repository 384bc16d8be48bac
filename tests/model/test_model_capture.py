"""model.samples.capture: photo-like capture of training inputs (numbers from the maths of each step)."""

from __future__ import annotations

import math

import numpy as np
import pytest

from model.samples import capture
from relight.lighting import presets
from relight.imaging.colour import LUMINANCE_WEIGHTS


def _scene(size=32):
    rng = np.random.default_rng(0)
    alpha = np.zeros((1, size, size), np.float32)
    alpha[:, 8:24, 10:22] = 1.0
    image = (rng.uniform(0.1, 0.6, (3, size, size)) * alpha).astype(np.float32)
    light = rng.normal(size=(25, 3)).astype(np.float32)
    return image, alpha, light


def test_same_generator_same_photo_and_params_are_recorded():
    image, alpha, light = _scene()
    a = capture.photo_like(image.copy(), image, alpha, light, np.random.default_rng([1, 2, 3]))
    b = capture.photo_like(image.copy(), image, alpha, light, np.random.default_rng([1, 2, 3]))
    assert np.array_equal(a[0], b[0]) and a[3].as_dict() == b[3].as_dict()
    rec = a[3].as_dict()
    for key in ("background", "gains", "white_balance", "exposure_ev", "blur_px", "shot", "read", "jpeg_quality"):
        assert key in rec
    assert 35 <= rec["jpeg_quality"] <= 95 and 0 <= rec["blur_px"] <= 1.2


def test_gains_keep_image_equal_to_albedo_times_shading_and_white_balance_has_unit_luminance():
    image, alpha, light = _scene()
    rng = np.random.default_rng(5)
    for _ in range(20):
        p = capture.sample_params(rng)
        assert float(np.dot(p.white_balance, LUMINANCE_WEIGHTS)) == pytest.approx(1.0, abs=1e-12)
        assert np.allclose(p.gains, np.array(p.white_balance) * 2.0 ** p.exposure_ev, rtol=1e-12)
    # Linear in the light per channel: the gained image is what the gained light renders.
    albedo = np.full((3, 4, 4), 0.5, np.float32)
    transport = np.random.default_rng(1).uniform(0, 1, (25, 4, 4)).astype(np.float32)
    img = albedo * np.einsum("nhw,nc->chw", transport, light)
    p = capture.sample_params(np.random.default_rng(2), background_p=0.0)
    _, img2, light2, _ = capture.photo_like(img, img, np.ones((1, 4, 4), np.float32), light,
                                            np.random.default_rng(0), p)
    assert np.allclose(img2, albedo * np.einsum("nhw,nc->chw", transport, light2), rtol=1e-5, atol=1e-6)


def test_without_degradations_the_photo_is_the_gained_composite_with_a_real_background():
    _, alpha, light = _scene()
    yy, xx = np.mgrid[0:32, 0:32] / 31.0
    image = (np.stack([0.2 + 0.2 * xx, 0.3 * yy + 0.1, 0.25 + 0.0 * xx]) * alpha).astype(np.float32)  # smooth
    p = capture.sample_params(np.random.default_rng(3), background_p=1.0)
    p.blur_px, p.shot, p.read, p.jpeg_quality = 0.0, 0.0, 0.0, 100
    out, img2, _, _ = capture.photo_like(image.copy(), image, alpha, light, np.random.default_rng(0), p)
    g = np.array(p.gains, np.float32)[:, None, None]
    inside = alpha[0] == 1.0
    # Inside the person, away from its edge (JPEG blocks and 4:2:0 chroma straddle it): image x gains
    # up to 8-bit sRGB quantisation (half a step is <= 0.005 linear below 0.8) and JPEG at 100, whose
    # 4:2:0 chroma averages 2 x 2 pixels of a gradient (steps of 0.012 here) and its rounding.
    core = np.zeros_like(inside)
    core[10:22, 12:20] = True
    assert np.abs(out[:, core] - (image * g)[:, core]).max() < 0.025
    assert p.background["map"] not in presets.HELD_OUT
    assert np.abs(out[:, ~inside]).mean() > 1e-3  # a background, not black


def test_perspective_view_geometry():
    h, w = 64, 128
    pano = np.zeros((h, w, 3), np.float32)
    pano[:, : w // 2] = 1.0  # longitudes -180..0 bright, 0..180 dark
    pano[: h // 2, :, 2] = 0.5  # upper hemisphere: blue 0.5
    # Looking along phi = -90 deg (yaw -90): all bright; phi = +90: all dark.
    assert np.allclose(capture.perspective_view(pano, -90, 0, 60, 16)[0], 1.0)
    assert np.allclose(capture.perspective_view(pano, 90, 0, 60, 16)[0], 0.0)
    # Pitch 0: upper half of the view in the upper hemisphere, lower half not.
    view = capture.perspective_view(pano, 90, 0, 60, 16)
    assert np.allclose(view[2, :7], 0.5) and np.allclose(view[2, 9:], 0.0)
    const = np.full((h, w, 3), 0.25, np.float32)
    assert np.allclose(capture.perspective_view(const, 33, 10, 80, 8), 0.25)


def test_blur_noise_and_jpeg_magnitudes():
    img = np.zeros((3, 33, 33), np.float32)
    img[:, 16, 16] = 1.0
    b = capture.gaussian_blur(img, 1.0)
    assert b.sum() == pytest.approx(3.0, rel=1e-5)  # energy kept away from the edges
    # Peak of a normalized 2D Gaussian of sigma 1 sampled on the grid: (sum_k e^{-k^2/2})^-2.
    norm = sum(math.exp(-k * k / 2) for k in range(-3, 4))
    assert b[0, 16, 16] == pytest.approx(1.0 / norm**2, rel=1e-5)
    flat = np.full((3, 64, 64), 0.18, np.float32)
    p = capture.sample_params(np.random.default_rng(0), background_p=0.0)
    p.gains = [1.0, 1.0, 1.0]
    p.blur_px, p.shot, p.read, p.jpeg_quality = 0.0, 4e-4, 0.0, 95
    out = capture.photo_like(flat, flat, np.ones((1, 64, 64), np.float32), np.zeros((25, 3), np.float32),
                             np.random.default_rng(0), p)[0]
    # Noise sigma sqrt(4e-4 * 0.18) = 0.0085 linear; JPEG at 95 smooths a little of it away.
    assert 0.004 < out.std() < 0.0095
    assert abs(out.mean() - 0.18) < 0.004
    smooth = np.broadcast_to(np.linspace(0.05, 0.8, 64, dtype=np.float32)[None, None, :], (3, 64, 64))
    err = capture.jpeg_roundtrip(smooth, 35) - smooth
    assert np.sqrt((err**2).mean()) < 0.01
