"""relight.lighting.sh_rotation: exactness, composition, equivariance with map rotation."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from relight.lighting import sh, sh_projection, sh_rotation

RNG = np.random.default_rng(99)


def quaternion_to_matrix(q):
    """Rotation matrices [..., 3, 3] from (not necessarily unit) quaternions [..., 4] (w, x, y, z)."""
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    w, x, y, z = np.moveaxis(q, -1, 0)
    return np.stack(
        [
            1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w),
            2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w),
            2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y),
        ],
        axis=-1,
    ).reshape(q.shape[:-1] + (3, 3))


def random_rotations(n, rng=RNG):
    return quaternion_to_matrix(rng.normal(size=(n, 4)))


def rotation_by_fit(R, order):
    """Independent reference: Y(R^T p) = Y(p) M restricted to each band,
    solved by least squares on 3(order+1)^2 random directions."""
    p = np.random.default_rng(0).normal(size=(3 * (order + 1) ** 2, 3))
    basis, rotated = sh.sh_basis(p, order), sh.sh_basis(p @ R, order)  # rows of p @ R: R^T p
    M = np.zeros(((order + 1) ** 2,) * 2)
    for l in range(order + 1):
        s = slice(l * l, (l + 1) ** 2)
        M[s, s] = np.linalg.lstsq(basis[:, s], rotated[:, s], rcond=None)[0]
    return M


@pytest.mark.parametrize("order", [0, 1, 2, 5, 8, 12])
def test_recurrence_matches_least_squares_fit(order):
    special = [np.eye(3), sh_rotation.z_rotation(180), np.diag([-1.0, 1.0, -1.0]), np.diag([1.0, -1.0, -1.0]),
               quaternion_to_matrix([1.0, 0.0, 1e-9, 0.0])]  # near identity about Y
    for R in list(random_rotations(4)) + special:
        # both are round-off accurate; the fit's conditioning costs a few ulps per band
        np.testing.assert_allclose(sh_rotation.rotation_matrix(R, order), rotation_by_fit(R, order), atol=1e-11)


def test_identity_and_orthogonality():
    order = 8
    np.testing.assert_allclose(sh_rotation.rotation_matrix(np.eye(3), order), np.eye(81), atol=1e-13)
    for R in random_rotations(5):
        M = sh_rotation.rotation_matrix(R, order)
        np.testing.assert_allclose(M @ M.T, np.eye(81), atol=1e-12)
        # block diagonal: no leakage between bands
        for l in range(order + 1):
            s = slice(l * l, (l + 1) ** 2)
            off = M[s].copy()
            off[:, s] = 0
            assert np.abs(off).max() == 0


def test_high_order_rotation_stays_exact():
    order = 32
    R = random_rotations(1)[0]
    M = sh_rotation.rotation_matrix(R, order)
    n = (order + 1) ** 2
    assert np.abs(M @ M.T - np.eye(n)).max() < 1e-12
    p = RNG.normal(size=3)
    np.testing.assert_allclose(M @ sh.sh_basis(p, order), sh.sh_basis(R @ p, order), atol=1e-12)


def test_band_one_is_the_rotation_itself():
    # (Y_{1,-1}, Y_{1,0}, Y_{1,1}) ~ (y, z, x): band 1 is R in that axis order
    R = random_rotations(1)[0]
    perm = [1, 2, 0]
    np.testing.assert_allclose(sh_rotation.rotation_matrix(R, 1)[1:, 1:], R[np.ix_(perm, perm)], atol=1e-14)


def test_rotation_moves_a_lobe_to_the_rotated_direction():
    # the coefficients of a delta light at p are Y(p); rotated, it sits at R p
    order = 8
    for R, p in zip(random_rotations(4), RNG.normal(size=(4, 3))):
        np.testing.assert_allclose(
            sh_rotation.rotation_matrix(R, order) @ sh.sh_basis(p, order), sh.sh_basis(R @ p, order), atol=1e-13
        )


def test_pointwise_equivariance():
    # (M c) evaluated at d equals c evaluated at R^T d, for every direction
    order = 8
    c = RNG.normal(size=81)
    d = RNG.normal(size=(300, 3))
    for R in random_rotations(3):
        lhs = sh.sh_basis(d, order) @ (sh_rotation.rotation_matrix(R, order) @ c)
        rhs = sh.sh_basis(d @ R, order) @ c  # rows of d @ R are R^T d
        np.testing.assert_allclose(lhs, rhs, atol=1e-12)


def test_composition():
    order = 8
    R1, R2 = random_rotations(2)
    np.testing.assert_allclose(
        sh_rotation.rotation_matrix(R1 @ R2, order),
        sh_rotation.rotation_matrix(R1, order) @ sh_rotation.rotation_matrix(R2, order),
        atol=1e-13,
    )


def test_ten_thousand_composed_rotations_stay_orthogonal():
    order = 8
    Rs = random_rotations(10_000)
    Ms = sh_rotation.rotation_matrix(Rs, order)  # batched
    np.testing.assert_array_equal(Ms[17], sh_rotation.rotation_matrix(Rs[17], order))
    product = np.eye(81)
    R_total = np.eye(3)
    for M, R in zip(Ms, Rs):
        product = M @ product
        R_total = R @ R_total
    # each factor is orthogonal to ~1e-15; errors add up linearly: ~1e-11
    assert np.abs(product @ product.T - np.eye(81)).max() < 1e-9
    assert np.abs(product - sh_rotation.rotation_matrix(R_total, order)).max() < 1e-9


def test_z_rotation_equals_integer_pixel_shift():
    # rotating the light by +360*k/W degrees about Z maps L'(phi) = L(phi - theta);
    # with u = 0.5 - phi/2pi that reads column c from column c + k: np.roll(-k).
    # The equirect quadrature is exactly invariant under this shift, so only
    # round-off remains.
    H, W, order = 32, 64, 8
    img = RNG.random((H, W, 3))
    c = sh_projection.project_equirect(img, order, precision="float64")
    for k in (1, 5, 16, 40):
        degrees = 360.0 * k / W
        shifted = sh_projection.project_equirect(np.roll(img, -k, axis=1), order, precision="float64")
        np.testing.assert_allclose(sh_rotation.rotate(c, sh_rotation.z_rotation(degrees)), shifted, atol=1e-11)


def test_z_rotation_direction():
    R = sh_rotation.z_rotation(90)
    np.testing.assert_allclose(R @ [1, 0, 0], [0, 1, 0], atol=1e-15)  # +X light goes to +Y
    np.testing.assert_allclose(sh_rotation.z_rotation(-30) @ sh_rotation.z_rotation(30), np.eye(3), atol=1e-15)
    for bad in ("ninety", float("nan"), None):
        with pytest.raises(ValueError, match="angle"):
            sh_rotation.z_rotation(bad)


def test_general_rotation_matches_resampled_analytic_map():
    # a band-limited light f = sum c_k Y_k, resampled rotated on the grid,
    # projects to M c up to the quadrature error of the order-4 x order-4
    # products (see test_sh.quadrature_bound): measured ~1e-4, bound 1e-2
    H, W, order = 256, 512, 4
    c = RNG.normal(size=(25, 3)) * 0.2
    c[0] = 12.0  # keep the light positive so clamping is not involved
    R = random_rotations(1)[0]
    dirs, _ = sh_projection.equirect_directions(H, W)
    rotated_map = sh.sh_basis(dirs @ R, order) @ c  # f(R^T d)
    assert rotated_map.min() > 0
    projected = sh_projection.project_equirect(rotated_map, order, precision="float64")
    expected = sh_rotation.rotate(c, R)
    error = np.abs(projected - expected).max()
    delta = np.pi / H
    bound = 2 * np.pi * np.pi * delta**2 / 12 * (8 + 32) * (9 / (4 * np.pi)) * np.abs(c).sum(axis=0).max()
    assert error < bound, (error, bound)
    # and a 90 degree mistake would be caught by a wide margin
    wrong = sh_rotation.rotate(c, R @ sh_rotation.z_rotation(90))
    assert np.abs(projected - wrong).max() > 100 * error


def test_rotate_matches_matrix():
    c = RNG.normal(size=(16, 3))
    R = random_rotations(1)[0]
    np.testing.assert_allclose(sh_rotation.rotate(c, R), sh_rotation.rotation_matrix(R, 3) @ c, atol=1e-15)


rotations = st.lists(st.floats(-1, 1, allow_nan=False), min_size=4, max_size=4).filter(
    lambda q: sum(v * v for v in q) > 1e-2
)


@settings(max_examples=40, deadline=None)
@given(q=rotations, seed=st.integers(0, 2**32 - 1), order=st.integers(0, 8))
def test_property_rotation_preserves_band_energy(q, seed, order):
    c = np.random.default_rng(seed).normal(size=((order + 1) ** 2, 3))
    out = sh_rotation.rotate(c, quaternion_to_matrix(q))
    for l in range(order + 1):
        s = slice(l * l, (l + 1) ** 2)
        e_in, e_out = np.sum(c[s] ** 2, axis=0), np.sum(out[s] ** 2, axis=0)
        np.testing.assert_allclose(e_out, e_in, rtol=1e-12, atol=1e-14)


@settings(max_examples=40, deadline=None)
@given(q=rotations, seed=st.integers(0, 2**32 - 1), order=st.integers(0, 8))
def test_property_rotate_then_inverse_is_identity(q, seed, order):
    c = np.random.default_rng(seed).normal(size=((order + 1) ** 2, 3))
    R = quaternion_to_matrix(q)
    np.testing.assert_allclose(sh_rotation.rotate(sh_rotation.rotate(c, R), R.T), c, atol=1e-12)


@pytest.mark.parametrize(
    "R, match",
    [
        (np.eye(2), "3x3"),
        (np.diag([1.0, 1.0, -1.0]), "reflection"),
        (np.eye(3) * 2, "not orthogonal"),
        (np.full((3, 3), np.nan), "NaN"),
        (np.ones((4, 4)), "3x3"),
    ],
)
def test_rotation_bad_input(R, match):
    with pytest.raises(ValueError, match=match):
        sh_rotation.rotation_matrix(R, 2)
    with pytest.raises(ValueError, match=match):
        sh_rotation.rotate(np.ones((9, 3)), R)


def test_rotate_bad_coeffs():
    with pytest.raises(ValueError, match="not \\(order"):
        sh_rotation.rotate(np.ones((8, 3)), np.eye(3))
    with pytest.raises(ValueError, match="shape"):
        sh_rotation.rotate(np.ones(9), np.eye(3))
    with pytest.raises(ValueError, match="NaN"):
        sh_rotation.rotate(np.full((9, 3), math.nan), np.eye(3))
