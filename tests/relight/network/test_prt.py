"""relight.network.prt (rendering layer, network input) and relight.imaging.colour."""

import numpy as np
import pytest
from numpy.polynomial.legendre import leggauss

from relight.imaging import colour
from relight.network import prt
from relight.lighting import sh

RNG = np.random.default_rng(7)


def hemisphere_quadrature(n, count=24):
    """Directions and weights on the hemisphere around unit n: Gauss-Legendre
    in cos(theta) in [0, 1] x trapezoid in azimuth. The clamped-cosine
    integrand is a polynomial there, so this is exact for count >= order + 2."""
    t, w = leggauss(count)
    t, w = 0.5 * (t + 1), 0.5 * w
    n_phi = 2 * count + 1
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    a = np.cross(n, [1.0, 0, 0] if abs(n[0]) < 0.9 else [0, 1.0, 0])
    a /= np.linalg.norm(a)
    b = np.cross(n, a)
    r = np.sqrt(1 - t**2)
    d = (
        r[:, None, None] * (np.cos(phi)[None, :, None] * a + np.sin(phi)[None, :, None] * b)
        + t[:, None, None] * n
    ).reshape(-1, 3)
    weights = (w[:, None] * np.full(n_phi, 2 * np.pi / n_phi)).reshape(-1)
    cosines = np.repeat(t, n_phi)
    return d, weights, cosines


def test_lambert_transport_is_the_clamped_cosine_integral():
    # T_lm(n) = (1/pi) int max(0, n.w) Y_lm(w) dw, integrated directly
    order = 8
    for n in RNG.normal(size=(4, 3)):
        n = n / np.linalg.norm(n)
        d, w, cos = hemisphere_quadrature(n)
        direct = (sh.sh_basis(d, order) * (w * cos / np.pi)[:, None]).sum(axis=0)
        np.testing.assert_allclose(prt.lambert_transport(n, order), direct, atol=1e-13)


def test_white_lambert_under_unit_radiance_gives_one():
    # constant radiance 1: L_00 = int Y_00 = 4 pi / (2 sqrt(pi)), all else 0
    L = np.zeros((25, 3))
    L[0] = 2 * np.sqrt(np.pi)
    n = RNG.normal(size=(10, 3))
    s = prt.shading(prt.lambert_transport(n, 4), L)
    np.testing.assert_allclose(s, 1.0, atol=1e-12)


def test_shading_and_render_against_explicit_sums():
    n, H, W = 9, 3, 4
    T = RNG.normal(size=(H, W, n))
    E = RNG.normal(size=(H, W, n))
    L = RNG.normal(size=(n, 3))
    albedo = RNG.random((H, W, 3))
    expected = np.zeros((H, W, 3))
    for i in range(H):
        for j in range(W):
            for c in range(3):
                expected[i, j, c] = albedo[i, j, c] * sum(T[i, j, k] * L[k, c] for k in range(n)) + sum(
                    E[i, j, k] * L[k, c] for k in range(n)
                )
    np.testing.assert_allclose(prt.render(albedo, T, E, L), expected, atol=1e-13)
    np.testing.assert_allclose(prt.render(albedo, T, None, L), albedo * prt.shading(T, L), atol=1e-15)


def test_render_keeps_float32():
    T = RNG.normal(size=(2, 2, 4)).astype(np.float32)
    L = RNG.normal(size=(4, 3)).astype(np.float32)
    a = RNG.random((2, 2, 3)).astype(np.float32)
    L64 = L.astype(np.float64)
    assert prt.render(a, T, T, L).dtype == np.float32
    assert prt.render(a, T, None, L64).dtype == np.float32  # the light does not promote
    # float32 dot products of 4 O(1) terms: error ~ 4 * 6e-8 * |T||L|, far below 1e-5
    np.testing.assert_allclose(prt.shading(T, L64), prt.shading(T.astype(np.float64), L64), rtol=0, atol=1e-5)
    assert prt.shading(T.astype(np.float64), L).dtype == np.float64


@pytest.mark.parametrize(
    "albedo, T, E, L, match",
    [
        (np.ones((2, 2, 3)), np.ones((2, 2, 9)), None, np.ones((10, 3)), "order"),
        (np.ones((2, 2, 3)), np.ones((2, 2, 9)), None, np.ones((9, 4)), "light"),
        (np.ones((2, 2, 3)), np.ones((2, 2, 4)), None, np.ones((9, 3)), "transport"),
        (np.ones((2, 3, 3)), np.ones((2, 2, 9)), None, np.ones((9, 3)), "albedo"),
        (np.ones((2, 2, 3)), np.ones((2, 2, 9)), np.ones((2, 1, 9)), np.ones((9, 3)), "residual"),
        (np.ones((2, 2, 3)), np.ones((2, 2, 9)), None, np.full((9, 3), np.nan), "NaN"),
    ],
)
def test_render_bad_input(albedo, T, E, L, match):
    with pytest.raises(ValueError, match=match):
        prt.render(albedo, T, E, L)


# ---------------------------------------------------------------- colour


def test_srgb_known_values_and_round_trip():
    lin = np.array([0.0, 0.0031308, 0.18, 0.5, 1.0])
    enc = colour.srgb_encode(lin)
    # IEC 61966-2-1: 0.0031308 -> 0.04045 (both branches meet), 0.5 -> 0.735357
    np.testing.assert_allclose(enc, [0.0, 0.0404499, 0.4613561, 0.7353570, 1.0], atol=2e-7)
    x = np.linspace(0, 1, 1001)
    np.testing.assert_allclose(colour.srgb_decode(colour.srgb_encode(x)), x, atol=1e-12)
    assert np.all(np.diff(colour.srgb_encode(x)) > 0)
    np.testing.assert_allclose(colour.srgb_encode([-1.0, 2.0]), [0.0, 1.0], atol=1e-15)  # clipped
    assert colour.srgb_encode(np.float32(0.5)).dtype == np.float32


def test_luminance():
    np.testing.assert_allclose(colour.luminance([1.0, 1.0, 1.0]), 1.0, atol=1e-15)
    np.testing.assert_allclose(colour.luminance(np.eye(3)), [0.2126, 0.7152, 0.0722])
    with pytest.raises(ValueError, match="shape"):
        colour.luminance(np.ones((4, 2)))
    with pytest.raises(ValueError, match="numeric"):
        colour.srgb_encode(np.array(["a"]))


# ---------------------------------------------------------------- network input


def test_to_network_input():
    img = np.array([[[0.0, 0.5, 1.0], [2.0, -1.0, 0.18]]])
    out = prt.to_network_input(img)
    assert out.dtype == np.float32 and out.shape == img.shape
    expected = np.array([[[-1.0, 2 * 0.735357 - 1, 1.0], [1.0, -1.0, 2 * 0.4613561 - 1]]])
    np.testing.assert_allclose(out, expected, atol=1e-6)
    mask = np.array([[1.0, 0.0]])
    masked = prt.to_network_input(img, mask)
    np.testing.assert_allclose(masked[0, 0], out[0, 0])
    np.testing.assert_array_equal(masked[0, 1], 0.0)
    np.testing.assert_allclose(prt.to_network_input(img, mask[..., None]), masked)


@pytest.mark.parametrize(
    "img, mask, match",
    [
        (np.ones((2, 2)), None, "shape"),
        (np.full((2, 2, 3), np.nan), None, "NaN"),
        (np.ones((2, 2, 3)), np.ones((2, 3)), "mask"),
        (np.ones((2, 2, 3)), np.full((2, 2), 1.5), "mask values"),
    ],
)
def test_to_network_input_bad_input(img, mask, match):
    with pytest.raises(ValueError, match=match):
        prt.to_network_input(img, mask)
