"""Rotations of SH coefficients: the block-diagonal SH rotation of a 3x3 rotation, and Z turns.

Band 1 is the rotation itself in (y, z, x) order; higher bands follow from the
Ivanic-Ruedenberg recurrence. Rotating a light by R means L'(w) = L(R^T w)
(docs/conventions.md). numpy only.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from relight.lighting.sh import check_order, order_from_num_coeffs, validate_coeffs

_ROTATION_CHUNK = 128  # rotations per batch in rotation_matrix: keeps work in cache

__all__ = ["validate_rotation", "rotation_matrix", "rotate", "z_rotation"]


def validate_rotation(R, atol: float = 1e-6) -> np.ndarray:
    """Return R as float64 [..., 3, 3]; ValueError unless each is a proper rotation."""
    R = np.asarray(R, dtype=np.float64)
    if R.ndim < 2 or R.shape[-2:] != (3, 3):
        raise ValueError(f"rotation must be a 3x3 matrix (or a stack [..., 3, 3]), got shape {R.shape}")
    if not np.all(np.isfinite(R)):
        raise ValueError("rotation contains NaN or Inf")
    gram = np.matmul(R, np.swapaxes(R, -1, -2))
    if R.size and np.max(np.abs(gram - np.eye(3))) > atol:
        raise ValueError("rotation matrix is not orthogonal (R R^T != I)")
    if R.size and np.any(np.linalg.det(R) < 0):
        raise ValueError("rotation matrix has determinant -1 (a reflection)")
    return R


@functools.lru_cache(maxsize=None)
def _band_recurrence(l: int):
    """Weights and row maps of the Ivanic-Ruedenberg recurrence for band l >= 2.

    M^l_mn = u_mn U_mn + v_mn V_mn + w_mn W_mn, where U, V, W combine rows of
    P_i (i = -1, 0, 1), P_i[a, n] built from band 1 and M^{l-1}
    (J. Ivanic, K. Ruedenberg, J. Phys. Chem. 100 (1996) 6342, with the
    1998 erratum). Returned per m (rows) and n (columns) for the whole band.
    """
    m = np.arange(-l, l + 1)
    mm, nn = np.meshgrid(m, m, indexing="ij")
    d = (mm == 0).astype(float)
    am = np.abs(mm)
    denom = np.where(np.abs(nn) == l, 2 * l * (2 * l - 1), (l + nn) * (l - nn)).astype(float)
    u = np.sqrt((l + mm) * (l - mm) / denom)
    v = 0.5 * np.sqrt((1 + d) * (l + am - 1) * (l + am) / denom) * (1 - 2 * d)
    w = -0.5 * np.sqrt(np.maximum((l - am - 1) * (l - am), 0) / denom) * (1 - d)

    def row(a):  # index of P's row a in [-(l-1), l-1]; clipped rows get weight 0
        return np.clip(a + l - 1, 0, 2 * l - 2)

    one = (m == 1).astype(float)
    minus_one = (m == -1).astype(float)
    # V: m = 0: P1[1] + P-1[-1]; m > 0: sqrt(1+d_m1) P1[m-1] - (1-d_m1) P-1[1-m];
    #    m < 0: (1-d_m,-1) P1[m+1] + sqrt(1+d_m,-1) P-1[-m-1]
    v_rows = (row(np.where(m == 0, 1, np.where(m > 0, m - 1, m + 1))),
              row(np.where(m == 0, -1, np.where(m > 0, 1 - m, -m - 1))))
    v_weights = (np.where(m == 0, 1.0, np.where(m > 0, np.sqrt(1 + one), 1 - minus_one))[:, None],
                 np.where(m == 0, 1.0, np.where(m > 0, -(1 - one), np.sqrt(1 + minus_one)))[:, None])
    # W (m != 0): m > 0: P1[m+1] + P-1[-m-1]; m < 0: P1[m-1] - P-1[1-m]
    w_first = np.where(m > 0, m + 1, m - 1)
    w_rows = (row(w_first), row(np.where(m > 0, -m - 1, 1 - m)))
    w_sign = np.where(m > 0, 1.0, -1.0)[:, None]
    w = np.where(((np.abs(w_first) <= l - 1) & (m != 0))[:, None], w, 0.0)
    u = np.where((np.abs(m) <= l - 1)[:, None], u, 0.0)
    return u, v, w, row(m), v_rows, v_weights, w_rows, w_sign


def _rotation_blocks(r: np.ndarray, order: int, out: np.ndarray) -> None:
    """Fill out [k, n, n] with the SH rotation of band-1 matrices r [k, 3, 3]."""
    k = r.shape[0]
    out[:, 0, 0] = 1.0
    if order == 0:
        return
    out[:, 1:4, 1:4] = r
    prev = r
    for l in range(2, order + 1):
        u, v, w, u_rows, v_rows, v_weights, w_rows, w_sign = _band_recurrence(l)
        P = []
        for i in range(3):  # i = -1, 0, 1
            ri = r[:, i]  # r(i, -1), r(i, 0), r(i, 1)
            Pi = np.empty((k, 2 * l - 1, 2 * l + 1))
            Pi[:, :, 1:-1] = ri[:, 1, None, None] * prev
            Pi[:, :, -1] = ri[:, 2, None] * prev[:, :, -1] - ri[:, 0, None] * prev[:, :, 0]
            Pi[:, :, 0] = ri[:, 2, None] * prev[:, :, 0] + ri[:, 0, None] * prev[:, :, -1]
            P.append(Pi)
        p_minus, p_zero, p_plus = P
        V = v_weights[0] * p_plus[:, v_rows[0]] + v_weights[1] * p_minus[:, v_rows[1]]
        W = p_plus[:, w_rows[0]] + w_sign * p_minus[:, w_rows[1]]
        block = u * p_zero[:, u_rows] + v * V + w * W
        out[:, l * l : (l + 1) ** 2, l * l : (l + 1) ** 2] = block
        prev = block


def rotation_matrix(R, order: int) -> np.ndarray:
    """Block-diagonal matrix M [n, n] with coeffs_rotated = M @ coeffs.

    Rotating a light by R means L'(w) = L(R^T w). Band 1 is R itself in the
    (y, z, x) order of Y_{1,-1..1}; higher bands follow from the
    Ivanic-Ruedenberg recurrence (exact up to round-off, ~1e-14 at order 8).
    A stack R [..., 3, 3] gives M [..., n, n].
    """
    order = check_order(order)
    R = validate_rotation(R)
    n = (order + 1) ** 2
    stack = R.reshape(-1, 3, 3)
    yzx = [1, 2, 0]
    band1 = stack[:, yzx][:, :, yzx]
    M = np.zeros((stack.shape[0], n, n))
    for start in range(0, stack.shape[0], _ROTATION_CHUNK):
        chunk = slice(start, start + _ROTATION_CHUNK)
        _rotation_blocks(band1[chunk], order, M[chunk])
    return M.reshape(R.shape[:-2] + (n, n))


def rotate(coeffs, R) -> np.ndarray:
    """Rotate SH light coefficients [n, 3] by the 3x3 rotation R."""
    c = validate_coeffs(coeffs)
    R = np.asarray(R)
    if R.shape != (3, 3):
        raise ValueError(f"rotation must be a 3x3 matrix, got shape {R.shape}")
    order = order_from_num_coeffs(c.shape[0])
    return rotation_matrix(R, order) @ c


def z_rotation(degrees: float) -> np.ndarray:
    """3x3 rotation of the light by `degrees` about world +Z (right-handed).

    Positive angles turn light from +X towards +Y; in Blender's equirect
    mapping the map content moves left (towards smaller u).
    """
    try:
        angle = math.radians(float(degrees))
    except (TypeError, ValueError):
        raise ValueError(f"rotation angle must be a number, got {degrees!r}") from None
    if not math.isfinite(angle):
        raise ValueError(f"rotation angle must be finite, got {degrees!r}")
    c, s = math.cos(angle), math.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
