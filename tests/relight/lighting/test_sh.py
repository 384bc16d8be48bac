"""relight.lighting.sh and relight.lighting.sh_projection: basis, quadrature, projection, convolution, exposure."""

import math

import numpy as np
import pytest
from numpy.polynomial.legendre import leggauss
from scipy.special import eval_legendre, sph_harm_y

from relight.lighting import sh, sh_projection

RNG = np.random.default_rng(1234)


def random_dirs(n, rng=RNG):
    d = rng.normal(size=(n, 3))
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def real_sh_from_scipy(l, m, theta, phi):
    """Our real SH from scipy's complex Y_l^|m| (which includes the
    Condon-Shortley phase (-1)^m): multiply by (-1)^m to remove it, then
    Y_l0 = Re, Y_lm = sqrt(2) Re, Y_l,-m = sqrt(2) Im."""
    c = sph_harm_y(l, abs(m), theta, phi) * (-1.0) ** abs(m)
    if m == 0:
        return c.real
    return math.sqrt(2.0) * (c.real if m > 0 else c.imag)


def sphere_quadrature(order):
    """Gauss-Legendre in z (order+1 nodes) x trapezoid in phi (2*order+1 nodes):
    exact for polynomials of degree <= 2*order+1 on the sphere."""
    z, wz = leggauss(order + 1)
    n_phi = 2 * order + 1
    phi = 2 * np.pi * np.arange(n_phi) / n_phi
    r = np.sqrt(1 - z**2)
    dirs = np.stack(
        [r[:, None] * np.cos(phi), r[:, None] * np.sin(phi), np.broadcast_to(z[:, None], (z.size, n_phi))], -1
    ).reshape(-1, 3)
    weights = (wz[:, None] * np.full(n_phi, 2 * np.pi / n_phi)).reshape(-1)
    return dirs, weights


# ---------------------------------------------------------------- basis


def test_num_coeffs_and_inverse():
    assert [sh.num_coeffs(n) for n in range(5)] == [1, 4, 9, 16, 25]
    for n in range(20):
        assert sh.order_from_num_coeffs((n + 1) ** 2) == n
    for bad in (0, 2, 10, 24):
        with pytest.raises(ValueError, match="not \\(order\\+1\\)\\^2"):
            sh.order_from_num_coeffs(bad)


def test_basis_matches_scipy_up_to_order_12():
    dirs = np.concatenate([random_dirs(400), [[0, 0, 1], [0, 0, -1], [1, 0, 0], [0, 1, 0]]])
    theta = np.arccos(np.clip(dirs[:, 2], -1, 1))
    phi = np.arctan2(dirs[:, 1], dirs[:, 0])
    order = 12
    Y = sh.sh_basis(dirs, order)
    for l in range(order + 1):
        for m in range(-l, l + 1):
            expected = real_sh_from_scipy(l, m, theta, phi)
            # both are O(1) values from stable recurrences: agree to round-off
            np.testing.assert_allclose(Y[:, l * l + l + m], expected, rtol=0, atol=1e-12)


def test_basis_stable_at_high_order():
    # the normalized recurrences never form factorials: no overflow or
    # cancellation even at l = 64 (values stay O(sqrt(l)))
    dirs = random_dirs(40)
    theta, phi = np.arccos(dirs[:, 2]), np.arctan2(dirs[:, 1], dirs[:, 0])
    l = sh.MAX_ORDER
    Y = sh.sh_basis(dirs, l)
    for m in (-l, -37, -1, 0, 5, 40, l):
        np.testing.assert_allclose(Y[:, l * l + l + m], real_sh_from_scipy(l, m, theta, phi), atol=1e-12)


def test_low_order_closed_forms_and_signs():
    d = random_dirs(50)
    x, y, z = d.T
    Y = sh.sh_basis(d, 2)
    c1 = math.sqrt(3 / (4 * math.pi))
    np.testing.assert_allclose(Y[:, 0], 1 / (2 * math.sqrt(math.pi)), atol=1e-15)
    np.testing.assert_allclose(Y[:, 1], c1 * y, atol=1e-15)  # Y_{1,-1} ~ +y
    np.testing.assert_allclose(Y[:, 2], c1 * z, atol=1e-15)  # Y_{1,0} ~ +z
    np.testing.assert_allclose(Y[:, 3], c1 * x, atol=1e-15)  # Y_{1,1} ~ +x (no CS minus)
    c2 = 0.5 * math.sqrt(15 / math.pi)
    np.testing.assert_allclose(Y[:, 4], c2 * x * y, atol=1e-14)
    np.testing.assert_allclose(Y[:, 8], 0.5 * c2 * (x * x - y * y), atol=1e-14)


def test_basis_shape_normalizes_and_batches():
    d = random_dirs(12).reshape(3, 4, 3)
    Y = sh.sh_basis(d * 7.5, 3)  # non-unit directions are normalized
    assert Y.shape == (3, 4, 16)
    np.testing.assert_allclose(Y, sh.sh_basis(d, 3), atol=1e-14)
    assert sh.sh_basis([0, 0, 2], 1).shape == (4,)


def test_orthonormal_by_exact_quadrature():
    order = 8
    dirs, w = sphere_quadrature(2 * order)  # products have degree <= 2*order
    Y = sh.sh_basis(dirs, order)
    gram = Y.T @ (Y * w[:, None])
    np.testing.assert_allclose(gram, np.eye(81), atol=1e-12)


@pytest.mark.parametrize(
    "dirs, order, match",
    [
        (np.zeros((3, 2)), 2, "shape"),
        (np.array([[0.0, 0.0, 0.0]]), 2, "zero vector"),
        (np.array([[np.nan, 0.0, 1.0]]), 2, "NaN"),
        (np.array([[0.0, 0.0, 1.0]]), -1, "order"),
        (np.array([[0.0, 0.0, 1.0]]), 2.5, "integer"),
        (np.array([[0.0, 0.0, 1.0]]), 65, "order"),
    ],
)
def test_basis_bad_input(dirs, order, match):
    with pytest.raises(ValueError, match=match):
        sh.sh_basis(dirs, order)


# ---------------------------------------------------------------- equirect


def test_equirect_mapping_is_blenders():
    H, W = 16, 32
    dirs, omega = sh_projection.equirect_directions(H, W)
    assert dirs.shape == (H, W, 3) and omega.shape == (H,)
    np.testing.assert_allclose(np.linalg.norm(dirs, axis=-1), 1, atol=1e-15)
    # u = 0.5 - atan2(y, x) / 2pi at texel centres (c + 0.5) / W, modulo 1
    u = (0.5 - np.arctan2(dirs[..., 1], dirs[..., 0]) / (2 * np.pi)) % 1.0
    np.testing.assert_allclose(u, np.broadcast_to((np.arange(W) + 0.5) / W, (H, W)), atol=1e-14)
    # v = 0.5 + elevation / pi, v = 1 at the top of row 0
    v = 0.5 + np.arcsin(dirs[..., 2]) / np.pi
    np.testing.assert_allclose(v, np.broadcast_to(1 - (np.arange(H)[:, None] + 0.5) / H, (H, W)), atol=1e-14)
    # the image centre looks along +X, a quarter from the left along +Y
    assert dirs[H // 2, W // 2, 0] > 0.99 and dirs[H // 2, W // 4, 1] > 0.98


def test_equirect_solid_angles_exact():
    for H, W in ((1, 2), (7, 14), (256, 512)):
        _, omega = sh_projection.equirect_directions(H, W)
        # band areas telescope: sum = 2 pi (sin(pi/2) - sin(-pi/2)) = 4 pi
        assert abs(omega.sum() * W - 4 * np.pi) < 1e-12
        np.testing.assert_allclose(omega, omega[::-1], rtol=1e-12)  # symmetric about the equator
    _, omega = sh_projection.equirect_directions(4, 8)
    e = np.radians([90, 45, 0, -45, -90])
    np.testing.assert_allclose(omega, 2 * np.pi / 8 * (np.sin(e[:-1]) - np.sin(e[1:])), rtol=1e-14)


@pytest.mark.parametrize("h, w", [(0, 2), (2, -1), (2.0, 4), (True, 2)])
def test_equirect_bad_size(h, w):
    with pytest.raises(ValueError, match="positive integer"):
        sh_projection.equirect_directions(h, w)


def quadrature_bound(H, degree, peak):
    """Error bound for summing a function of elevation that is a trigonometric
    polynomial of `degree` and |f| <= peak over the equirect rows: per row the
    exact band weight is used with f at the row centre, so the error is
    int (f(e) - f(e_r)) cos e de; Taylor to second order with Bernstein's
    inequality |f'| <= d*peak, |f''| <= d^2*peak gives, to leading order in
    Delta = pi/H and summed over the pi/Delta rows,
    <= pi * Delta^2 / 12 * (d + d^2 / 2) * peak. Times 2 pi for the azimuth."""
    delta = np.pi / H
    return 2 * np.pi * np.pi * delta**2 / 12 * (degree + degree**2 / 2) * peak


def test_project_constant_map():
    H, W, order = 256, 512, 6
    colour = np.array([0.5, 1.0, 2.0])
    img = np.broadcast_to(colour, (H, W, 3)).astype(np.float32)
    c = sh_projection.project_equirect(img, order, precision="float64")
    # solid angles sum to 4 pi exactly, so L00 = 4 pi c Y00 = 2 sqrt(pi) c to round-off
    np.testing.assert_allclose(c[0], 2 * np.sqrt(np.pi) * colour, rtol=1e-13)
    peak = max(math.sqrt((2 * l + 1) / (4 * math.pi)) for l in range(order + 1))
    tol = quadrature_bound(H, order, peak) * colour.max()
    print("constant map: max |L_lm|, l > 0:", np.abs(c[1:]).max(), "bound", tol)
    assert np.abs(c[1:]).max() < tol
    assert tol < 2e-3 * c[0].max()  # the bound is tight enough to mean something


def test_project_single_lobe_gives_unit_coefficient():
    H, W, order = 256, 512, 4
    dirs, _ = sh_projection.equirect_directions(H, W)
    Y = sh.sh_basis(dirs, order)
    peak = math.sqrt((2 * order + 1) / (4 * math.pi))
    # product of two order-<=4 harmonics: trig degree 8 in elevation, peak^2;
    # the quadrature integrates over phi in [0, 2pi) (factor 2 pi)
    tol = quadrature_bound(H, 2 * order, peak**2)
    for k in (0, 2, 7, 12, 24):
        img = np.repeat(Y[..., k : k + 1], 3, axis=2)  # negative lobes are ...
        img_pos = np.maximum(img, 0)  # ... clamped, so project the two halves
        img_neg = np.maximum(-img, 0)
        c = sh_projection.project_equirect(img_pos, order, precision="float64") - sh_projection.project_equirect(
            img_neg, order, precision="float64"
        )
        expected = np.zeros((25, 3))
        expected[k] = 1
        print("lobe", k, "max error", np.abs(c - expected).max(), "bound", tol)
        np.testing.assert_allclose(c, expected, atol=tol)
    assert tol < 0.01


def test_project_cap_matches_funk_hecke():
    """A uniform cap of half-angle a around s has L_lm = h_l Y_lm(s) with
    h_0 = 2 pi (1 - cos a), h_l = 2 pi (P_{l-1}(cos a) - P_{l+1}(cos a)) / (2l+1)."""
    H, W, order = 256, 512, 4
    s = np.array([0.3, -0.5, 0.6])
    s /= np.linalg.norm(s)
    a = np.radians(12.0)
    radiance = 5.0
    dirs, _ = sh_projection.equirect_directions(H, W)
    img = np.zeros((H, W, 3), np.float32)
    img[dirs @ s >= np.cos(a)] = radiance
    c = sh_projection.project_equirect(img, order, precision="float64")
    t = np.cos(a)
    h = np.array(
        [2 * np.pi * (1 - t)]
        + [2 * np.pi * (eval_legendre(l - 1, t) - eval_legendre(l + 1, t)) / (2 * l + 1) for l in range(1, order + 1)]
    )
    expected = radiance * np.repeat(h, 2 * np.arange(order + 1) + 1) * sh.sh_basis(s, order)
    # texels whose centre classification can be wrong lie within one texel
    # diagonal (sqrt(2) pi / H at most) of the rim: area <= 2 pi sin a * that
    peak = math.sqrt((2 * order + 1) / (4 * math.pi))
    tol = radiance * peak * 2 * np.pi * np.sin(a) * np.sqrt(2) * np.pi / H
    np.testing.assert_allclose(c, np.repeat(expected[:, None], 3, axis=1), atol=tol)
    # and the small-sun limit L_lm ~ solid angle * radiance * Y_lm(s): for
    # l <= 1 the exact factor is h_1 / h_0 = (1 + cos a) / 2 = 0.989 here
    np.testing.assert_allclose(c[:4, 0], 2 * np.pi * (1 - t) * radiance * sh.sh_basis(s, 1), rtol=0.02)


def test_project_float32_close_to_float64():
    img = RNG.random((128, 256, 3)).astype(np.float32) * 10
    c64 = sh_projection.project_equirect(img, 8, precision="float64")
    c32 = sh_projection.project_equirect(img, 8)
    # float32 sums of 256 values per row: relative error ~ 256 * 6e-8 worst case
    assert np.abs(c32 - c64).max() < 256 * 6e-8 * np.abs(c64).max()


def test_project_clamps_negatives_and_drops_alpha():
    img = RNG.random((8, 16, 4))
    neg = img.copy()
    neg[0, 0, :3] = -5.0
    clamped = neg.copy()
    clamped[0, 0, :3] = 0.0
    np.testing.assert_allclose(
        sh_projection.project_equirect(neg, 2, precision="float64"),
        sh_projection.project_equirect(clamped[..., :3], 2, precision="float64"),
        atol=1e-12,
    )
    # a non-finite alpha channel is ignored, like any alpha
    alpha_nan = clamped.copy()
    alpha_nan[1, 1, 3] = np.nan
    np.testing.assert_allclose(
        sh_projection.project_equirect(alpha_nan, 2, precision="float64"),
        sh_projection.project_equirect(clamped[..., :3], 2, precision="float64"),
        atol=1e-12,
    )


@pytest.mark.parametrize(
    "img, match",
    [
        (np.ones((8, 16)), "rank"),
        (np.ones((8, 16, 2)), "channels"),
        (np.ones((8, 16, 5)), "channels"),
        (np.ones((0, 16, 3)), "empty"),
        (np.full((8, 16, 3), np.nan), "NaN"),
        (np.full((8, 16, 3), np.inf), "NaN or Inf"),
        (np.concatenate([np.ones((8, 16, 3)), np.full((8, 16, 1), -np.inf)], axis=2)[..., [0, 3, 1]], "NaN or Inf"),
        (np.full((8, 16, 3), "x"), "real numbers"),
    ],
)
def test_project_bad_input(img, match):
    with pytest.raises(ValueError, match=match):
        sh_projection.project_equirect(img, 2)


def test_project_bad_precision():
    with pytest.raises(ValueError, match="precision"):
        sh_projection.project_equirect(np.ones((4, 8, 3)), 2, precision="half")
    huge = np.full((4, 8, 3), 1e39)  # finite in float64, Inf in float32
    with pytest.raises(ValueError, match="beyond float32 range"):
        sh_projection.project_equirect(huge, 0)
    c = sh_projection.project_equirect(huge, 0, precision="float64")
    np.testing.assert_allclose(c[0], 2 * np.sqrt(np.pi) * 1e39, rtol=1e-13)


# ---------------------------------------------------------------- convolution


def test_clamped_cosine_known_values():
    A = sh.clamped_cosine_coeffs(8)
    expected = [np.pi, 2 * np.pi / 3, np.pi / 4, 0, -np.pi / 24, 0, np.pi / 64, 0, -5 * np.pi / 640]
    np.testing.assert_allclose(A, expected, rtol=1e-14, atol=1e-15)


def test_clamped_cosine_against_legendre_quadrature():
    # A_l = 2 pi int_0^1 t P_l(t) dt; the integrand is a polynomial of degree
    # l+1 on [0, 1], so 20-node Gauss-Legendre is exact up to round-off
    order = 20
    t, w = leggauss(20)
    t, w = 0.5 * (t + 1), 0.5 * w
    numeric = [2 * np.pi * np.sum(w * t * eval_legendre(l, t)) for l in range(order + 1)]
    np.testing.assert_allclose(sh.clamped_cosine_coeffs(order), numeric, atol=1e-14)


def test_windows():
    for order in (2, 4, 8):
        l = np.arange(order + 1)
        np.testing.assert_allclose(sh.window(order), 0.5 * (1 + np.cos(np.pi * l / (order + 1))), atol=1e-15)
        x = np.pi * l[1:] / (order + 1)
        np.testing.assert_allclose(sh.window(order, "lanczos")[1:], np.sin(x) / x, atol=1e-15)
        for kind in ("hanning", "lanczos"):
            w = sh.window(order, kind)
            assert w[0] == 1 and np.all(np.diff(w) < 0) and w[-1] > 0
    c = np.ones((9, 3))
    np.testing.assert_allclose(sh.apply_window(c)[:, 0], np.repeat(sh.window(2), [1, 3, 5]))
    with pytest.raises(ValueError, match="window kind"):
        sh.window(4, "gauss")


# ---------------------------------------------------------------- exposure


def test_mean_luminance_of_constant_map():
    colour = np.array([0.2, 0.5, 1.5])
    c = sh_projection.project_equirect(np.broadcast_to(colour, (16, 32, 3)), 4, precision="float64")
    expected = 0.2126 * 0.2 + 0.7152 * 0.5 + 0.0722 * 1.5
    assert abs(sh.mean_luminance(c) - expected) < 1e-13


def test_normalize_reference():
    c = RNG.random((25, 3)) + 0.1
    out, scale = sh.normalize_reference(c)
    assert abs(sh.mean_luminance(out) - 0.8) < 1e-13
    np.testing.assert_allclose(out, c * scale, rtol=1e-15)
    out, _ = sh.normalize_reference(c, target=0.7)
    assert abs(sh.mean_luminance(out) - 0.7) < 1e-13


@pytest.mark.parametrize(
    "coeffs, target, match",
    [
        (np.zeros((9, 3)), 0.8, "mean luminance"),
        (np.ones((9, 3)), 0.0, "target"),
        (np.ones((9, 3)), float("nan"), "target"),
        (np.ones((9, 3)), "bright", "target"),
        (np.ones((10, 3)), 0.8, "not \\(order"),
        (np.ones((9, 4)), 0.8, "shape"),
        (np.full((9, 3), np.inf), 0.8, "NaN or Inf"),
    ],
)
def test_normalize_bad_input(coeffs, target, match):
    with pytest.raises(ValueError, match=match):
        sh.normalize_reference(coeffs, target)


def test_projection_error_converges_at_second_order():
    # the leading quadrature error term is O(Delta^2): halving the texel size
    # must divide the error by ~4 (a first-order mistake in the row weights
    # or texel centres would give ~2)
    k, order = 12, 4
    errors = []
    for H in (32, 64, 128):
        dirs, _ = sh_projection.equirect_directions(H, 2 * H)
        lobe = sh.sh_basis(dirs, order)[..., k : k + 1]
        img = np.repeat(lobe, 3, axis=2)
        c = (sh_projection.project_equirect(np.maximum(img, 0), order, precision="float64")
             - sh_projection.project_equirect(np.maximum(-img, 0), order, precision="float64"))
        expected = np.zeros((25, 3))
        expected[k] = 1
        errors.append(np.abs(c - expected).max())
    for coarse, fine in zip(errors, errors[1:]):
        assert 3.5 < coarse / fine < 4.5, errors


def test_a_light_is_scaled_once_and_every_rotation_keeps_the_scale():
    # issue 39: SHLight finds the scale to the reference once; normalizing again after each
    # rotation (as before) gives the same coefficients bit for bit (a Z rotation keeps band 0)
    from relight.lighting.light import SHLight
    from relight.lighting.sh_rotation import rotation_matrix, z_rotation

    base = RNG.random((25, 3)) + 0.1
    light = SHLight(base, sh.REFERENCE_LUMINANCE)
    for degrees in (0.0, 30.0, 77.7, -5.0, 123456.7):
        rotated = base if degrees == 0.0 else rotation_matrix(z_rotation(degrees), 4) @ base
        np.testing.assert_array_equal(light.at(degrees), sh.normalize_reference(rotated)[0])
    assert sh.REFERENCE_LUMINANCE == 0.8
    with pytest.raises(ValueError, match="mean luminance"):  # a black light with a target: refused at once
        SHLight(np.zeros((9, 3)), 0.8)
    with pytest.raises(ValueError, match="NaN or Inf"):
        SHLight(np.full((9, 3), np.nan))
