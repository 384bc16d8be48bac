"""Real spherical harmonics: basis, equirect projection, rotation, convolution.

Conventions (docs/conventions.md): real, orthonormal SH without the
Condon-Shortley phase, index k = l*l + l + m, Y_{1,-1} ~ y, Y_{1,0} ~ z,
Y_{1,1} ~ x. Equirectangular maps use Blender's Environment Texture default
mapping. numpy only.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from relight.colour import LUMINANCE_WEIGHTS

MAX_ORDER = 64  # recurrences are stable far beyond this; the cap catches typos
_ROTATION_CHUNK = 128  # rotations per batch in rotation_matrix: keeps work in cache

__all__ = [
    "num_coeffs",
    "order_from_num_coeffs",
    "sh_basis",
    "equirect_directions",
    "project_equirect",
    "rotation_matrix",
    "rotate",
    "z_rotation",
    "clamped_cosine_coeffs",
    "window",
    "apply_window",
    "mean_luminance",
    "normalize_reference",
    "validate_coeffs",
    "validate_rotation",
]


# ---------------------------------------------------------------- sizes


def _check_order(order) -> int:
    if isinstance(order, bool) or not isinstance(order, (int, np.integer)):
        raise ValueError(f"SH order must be an integer, got {order!r}")
    if not 0 <= order <= MAX_ORDER:
        raise ValueError(f"SH order must be in [0, {MAX_ORDER}], got {order}")
    return int(order)


def num_coeffs(order: int) -> int:
    """Number of SH coefficients up to and including band `order`."""
    order = _check_order(order)
    return (order + 1) ** 2


def order_from_num_coeffs(n: int) -> int:
    """Inverse of num_coeffs; ValueError unless n is a perfect square."""
    root = math.isqrt(int(n)) if n >= 1 else 0
    if n < 1 or root * root != n:
        raise ValueError(f"{n} SH coefficients is not (order+1)^2 for any order")
    return root - 1


def validate_coeffs(coeffs, name: str = "coeffs") -> np.ndarray:
    """Return coeffs as float64 [n, 3]; ValueError on wrong shape or non-finite."""
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"{name} must have shape [(order+1)^2, 3], got {c.shape}")
    order_from_num_coeffs(c.shape[0])
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name} contains NaN or Inf")
    return c


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


# ---------------------------------------------------------------- basis


@functools.lru_cache(maxsize=None)
def _legendre_factors(order: int):
    """Coefficients of the normalized associated-Legendre recurrences.

    q_lm(z) = K_lm P_lm(z) / sin(theta)^m with K_lm the orthonormal factor
    sqrt((2l+1)/(4 pi) (l-m)!/(l+m)!), computed without factorials:
      q_00 = 1/sqrt(4 pi),  q_mm = q_{m-1,m-1} sqrt((2m+1)/(2m)),
      q_{m+1,m} = sqrt(2m+3) z q_mm,
      q_lm = a_lm z q_{l-1,m} - b_lm q_{l-2,m}.
    """
    diag = np.empty(order + 1)
    diag[0] = 1.0 / math.sqrt(4.0 * math.pi)
    for m in range(1, order + 1):
        diag[m] = diag[m - 1] * math.sqrt((2 * m + 1) / (2 * m))
    a = np.zeros((order + 1, order + 1))
    b = np.zeros((order + 1, order + 1))
    for m in range(order + 1):
        for l in range(m + 2, order + 1):
            d = l * l - m * m
            a[l, m] = math.sqrt((4 * l * l - 1) / d)
            b[l, m] = math.sqrt(((l - 1) ** 2 - m * m) * (2 * l + 1) / ((2 * l - 3) * d))
    return diag, a, b


def _legendre_table(z: np.ndarray, order: int) -> list[list[np.ndarray]]:
    """q[m][l - m] = q_lm(z) for 0 <= m <= l <= order (see _legendre_factors)."""
    diag, a, b = _legendre_factors(order)
    table = []
    for m in range(order + 1):
        col = [np.full_like(z, diag[m])]
        if m + 1 <= order:
            col.append(math.sqrt(2 * m + 3) * z * col[0])
        for l in range(m + 2, order + 1):
            col.append(a[l, m] * z * col[-1] - b[l, m] * col[-2])
        table.append(col)
    return table


def _azimuth_table(x: np.ndarray, y: np.ndarray, order: int):
    """(C_m, S_m) with C_m + i S_m = (x + i y)^m = sin(theta)^m e^{i m phi}."""
    cos_m = [np.ones_like(x)]
    sin_m = [np.zeros_like(x)]
    for _ in range(order):
        c, s = cos_m[-1], sin_m[-1]
        cos_m.append(x * c - y * s)
        sin_m.append(x * s + y * c)
    return cos_m, sin_m


def sh_basis(dirs, order: int) -> np.ndarray:
    """Real orthonormal SH Y_k(dirs) for k < (order+1)^2; dirs [..., 3] (normalized here).

    Computed from polynomials in x, y, z (no trigonometry), float64.
    """
    order = _check_order(order)
    d = np.asarray(dirs, dtype=np.float64)
    if d.ndim < 1 or d.shape[-1] != 3:
        raise ValueError(f"directions must have shape [..., 3], got {d.shape}")
    if not np.all(np.isfinite(d)):
        raise ValueError("directions contain NaN or Inf")
    norm = np.linalg.norm(d, axis=-1, keepdims=True)
    if np.any(norm == 0):
        raise ValueError("directions contain a zero vector")
    d = d / norm
    x, y, z = d[..., 0], d[..., 1], d[..., 2]
    q = _legendre_table(z, order)
    cos_m, sin_m = _azimuth_table(x, y, order)
    out = np.empty(d.shape[:-1] + ((order + 1) ** 2,), dtype=np.float64)
    sqrt2 = math.sqrt(2.0)
    for l in range(order + 1):
        centre = l * l + l
        out[..., centre] = q[0][l]
        for m in range(1, l + 1):
            p = sqrt2 * q[m][l - m]
            out[..., centre + m] = p * cos_m[m]
            out[..., centre - m] = p * sin_m[m]
    return out


# ---------------------------------------------------------------- equirect


def _check_size(height, width) -> tuple[int, int]:
    for name, v in (("height", height), ("width", width)):
        if isinstance(v, bool) or not isinstance(v, (int, np.integer)) or v < 1:
            raise ValueError(f"equirect {name} must be a positive integer, got {v!r}")
    return int(height), int(width)


@functools.lru_cache(maxsize=8)
def _equirect_axes(height: int, width: int):
    """Per-column azimuth, per-row elevation at texel centres, per-row solid angle."""
    u = (np.arange(width) + 0.5) / width
    phi = (0.5 - u) * 2.0 * math.pi  # Blender: u = 0.5 - phi / (2 pi)
    v_top = 1.0 - np.arange(height) / height  # row 0 is the top (v = 1)
    v_bottom = 1.0 - (np.arange(height) + 1) / height
    v_centre = 0.5 * (v_top + v_bottom)
    elevation = (v_centre - 0.5) * math.pi  # Blender: v = 0.5 + e / pi
    e_top = (v_top - 0.5) * math.pi
    e_bottom = (v_bottom - 0.5) * math.pi
    # exact area of each texel's latitude band, split evenly over the columns
    solid_angle = (2.0 * math.pi / width) * (np.sin(e_top) - np.sin(e_bottom))
    for arr in (phi, elevation, solid_angle):
        arr.flags.writeable = False
    return phi, elevation, solid_angle


def equirect_directions(height: int, width: int):
    """Unit directions at texel centres [H, W, 3] and per-row texel solid angle [H].

    Blender's mapping: u = 0.5 - atan2(y, x) / (2 pi), v = 0.5 + elevation / pi,
    with v = 1 on image row 0. Solid angles sum to 4 pi exactly.
    """
    height, width = _check_size(height, width)
    phi, elevation, solid_angle = _equirect_axes(height, width)
    ce = np.cos(elevation)[:, None]
    dirs = np.empty((height, width, 3))
    dirs[..., 0] = ce * np.cos(phi)[None, :]
    dirs[..., 1] = ce * np.sin(phi)[None, :]
    dirs[..., 2] = np.sin(elevation)[:, None]
    return dirs, solid_angle.copy()


@functools.lru_cache(maxsize=8)
def _projection_factors(height: int, width: int, order: int):
    """Separable projection factors for an H x W map.

    On the equirect grid Y_lm = q_lm(z_row) cos(elev)^|m| * trig(m phi_col):
    azimuth [W, 2*order+1] columns (1, cos phi, sin phi, cos 2phi, ...), and
    per azimuth column a, (k, weights [H, len(k)]): the coefficients k that
    use column a and their row weights q * cos(elev)^|m| * solid angle. Each
    coefficient uses one column, so this holds H * n row weights, not the
    H * n * (2 order + 1) of the dense form (2.2 GB at order 64 on 256 rows).
    """
    phi, elevation, solid_angle = _equirect_axes(height, width)
    n_az = 2 * order + 1
    azimuth = np.empty((width, n_az))
    azimuth[:, 0] = 1.0
    for m in range(1, order + 1):
        azimuth[:, 2 * m - 1] = np.cos(m * phi)
        azimuth[:, 2 * m] = np.sin(m * phi)
    q = _legendre_table(np.sin(elevation), order)
    ce = np.cos(elevation)
    sqrt2 = math.sqrt(2.0)
    n = (order + 1) ** 2
    weights = np.empty((height, n))
    column = np.empty(n, dtype=np.intp)
    for l in range(order + 1):
        centre = l * l + l
        weights[:, centre], column[centre] = q[0][l] * solid_angle, 0
        for m in range(1, l + 1):
            w = sqrt2 * q[m][l - m] * ce**m * solid_angle
            weights[:, centre + m], column[centre + m] = w, 2 * m - 1
            weights[:, centre - m], column[centre - m] = w, 2 * m
    groups = []
    for a in range(n_az):
        k = np.flatnonzero(column == a)
        w = np.ascontiguousarray(weights[:, k])
        k.flags.writeable = w.flags.writeable = False
        groups.append((k, w))
    azimuth.flags.writeable = False
    return azimuth, tuple(groups)


@functools.lru_cache(maxsize=2)
def _projection_tables(height: int, width: int, order: int):
    """The dense form of _projection_factors: azimuth [W, 2*order+1] and rows
    [H, n, 2*order+1] with each coefficient's row weights in its azimuth
    column (benchmarks/bench_sh.py compares methods with it)."""
    azimuth, groups = _projection_factors(height, width, order)
    rows = np.zeros((height, (order + 1) ** 2, azimuth.shape[1]))
    for a, (k, w) in enumerate(groups):
        rows[:, k, a] = w
    rows.flags.writeable = False
    return azimuth, rows


@functools.lru_cache(maxsize=8)
def _interleaved_azimuth(height: int, width: int, order: int, channels: int, dtype: str):
    """Azimuth table for pixels stored interleaved ([H, W*C] rows): entry
    [w*C + c, c*A + a] = azimuth[w, a] for c < 3; alpha (c = 3) gets weight 0.
    One plain 2D GEMM then sums over columns for all channels, no transpose."""
    azimuth, _ = _projection_factors(height, width, order)
    n_az = azimuth.shape[1]
    table = np.zeros((width, channels, 3, n_az), dtype=dtype)
    for c in range(3):
        table[:, c, c, :] = azimuth
    table = table.reshape(width * channels, 3 * n_az)
    table.flags.writeable = False
    return table


def project_equirect(img, order: int, *, precision: str = "float32") -> np.ndarray:
    """SH coefficients [n, 3] of an equirect radiance map [H, W, 3] (RGB; alpha ignored).

    L_lm = sum over texels of L * Y_lm(texel centre) * texel solid angle.
    Validates: rank 3, 3 or 4 channels, finite RGB; negative texels are
    clamped to zero. `precision` "float32" sums over columns in float32
    (relative error ~1e-7, docs/benchmarks/sh.md), "float64" throughout. In
    float32, texels beyond its range are refused, and row sums that overflow
    it (texels near 3.4e38) are redone in float64: the result is finite.
    """
    order = _check_order(order)
    if precision not in ("float32", "float64"):
        raise ValueError(f"precision must be 'float32' or 'float64', got {precision!r}")
    a = np.asarray(img)
    if a.ndim != 3:
        raise ValueError(f"equirect map must have shape [H, W, 3|4], got rank {a.ndim}")
    if a.shape[2] not in (3, 4):
        raise ValueError(f"equirect map must have 3 or 4 channels, got {a.shape[2]}")
    if a.shape[0] < 1 or a.shape[1] < 1:
        raise ValueError(f"equirect map is empty: shape {a.shape}")
    if not np.issubdtype(a.dtype, np.number) or np.issubdtype(a.dtype, np.complexfloating):
        raise ValueError(f"equirect map must be real numbers, got dtype {a.dtype}")
    height, width, channels = a.shape
    dtype = np.float32 if precision == "float32" else np.float64
    with np.errstate(over="ignore"):  # overflow to Inf is reported below
        flat = np.ascontiguousarray(a, dtype=dtype).reshape(height, width * channels)
    # two fast reductions instead of elementwise masks: NaN propagates to
    # min/max and +-Inf shows up in one of them
    low, high = flat.min(), flat.max()
    if not (np.isfinite(low) and np.isfinite(high)):
        if not np.all(np.isfinite(a[..., :3])):
            raise ValueError("equirect map contains NaN or Inf texels")
        if not np.all(np.isfinite(flat.reshape(a.shape)[..., :3])):
            raise ValueError("equirect map has values beyond float32 range; use precision='float64'")
        flat = np.where(np.isfinite(flat), flat, 0)  # only alpha was non-finite
        low = flat.min()
    if low < 0:
        flat = np.maximum(flat, 0)
    table = _interleaved_azimuth(height, width, order, channels, np.dtype(dtype).name)
    with np.errstate(over="ignore", invalid="ignore"):  # overflow is caught just below
        per_row = (flat @ table).reshape(height, 3, -1)  # [H, 3, n_az]: sums over columns
    if not np.all(np.isfinite(per_row)):
        if dtype is np.float32:
            return project_equirect(a, order, precision="float64")  # row sums beyond float32 range
        raise ValueError("equirect map values are too large: their sums overflow float64")
    _, groups = _projection_factors(height, width, order)
    # then the latitude quadrature per coefficient, in float64: [n, 3]
    per_row = per_row.astype(np.float64)
    coeffs = np.empty((num_coeffs(order), 3))
    with np.errstate(over="ignore", invalid="ignore"):
        for a, (k, w) in enumerate(groups):
            coeffs[k] = w.T @ per_row[:, :, a]
    if not np.all(np.isfinite(coeffs)):
        raise ValueError("equirect map values are too large: their sums overflow float64")
    return coeffs


# ---------------------------------------------------------------- rotation


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
    order = _check_order(order)
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


# ---------------------------------------------------------------- convolution


def clamped_cosine_coeffs(order: int) -> np.ndarray:
    """A_l for l <= order: the irradiance filter, E_lm = A_l L_lm.

    A_l = sqrt(4 pi / (2l+1)) * (zonal coefficient of max(0, cos theta)):
    pi, 2pi/3, pi/4, 0, -pi/24, 0, pi/64, ...
    """
    order = _check_order(order)
    A = np.zeros(order + 1)
    A[0] = math.pi
    if order >= 1:
        A[1] = 2.0 * math.pi / 3.0
    for l in range(2, order + 1, 2):
        sign = -1.0 if (l // 2) % 2 == 0 else 1.0  # (-1)^(l/2 - 1)
        # l! / (2^l ((l/2)!)^2) evaluated as a product to avoid big factorials
        ratio = 1.0
        for j in range(1, l // 2 + 1):
            ratio *= (l // 2 + j) / (4.0 * j)
        A[l] = 2.0 * math.pi * sign / ((l + 2) * (l - 1)) * ratio
    return A


def window(order: int, kind: str = "hanning") -> np.ndarray:
    """Ringing-reduction window sigma_l, l <= order (sigma_0 = 1).

    hanning: (1 + cos(pi l / (order+1))) / 2;
    lanczos: sinc(l / (order+1)) = sin(pi x) / (pi x).
    """
    order = _check_order(order)
    l = np.arange(order + 1, dtype=np.float64)
    x = l / (order + 1)
    if kind == "hanning":
        return 0.5 * (1.0 + np.cos(math.pi * x))
    if kind == "lanczos":
        return np.sinc(x)  # numpy's sinc is sin(pi x) / (pi x)
    raise ValueError(f"window kind must be 'hanning' or 'lanczos', got {kind!r}")


def apply_window(coeffs, kind: str = "hanning") -> np.ndarray:
    """Multiply every band l of coeffs [n, 3] by window(order, kind)[l]."""
    c = validate_coeffs(coeffs)
    order = order_from_num_coeffs(c.shape[0])
    sigma = window(order, kind)
    per_coeff = np.repeat(sigma, 2 * np.arange(order + 1) + 1)
    return c * per_coeff[:, None]


# ---------------------------------------------------------------- exposure


def mean_luminance(coeffs) -> float:
    """Solid-angle-weighted mean luminance (Rec.709 Y) of the light.

    The mean of L over the sphere is L_00 * Y_00 = L_00 / (2 sqrt(pi)).
    """
    c = validate_coeffs(coeffs)
    mean_rgb = c[0] / (2.0 * math.sqrt(math.pi))
    return float(np.dot(LUMINANCE_WEIGHTS, mean_rgb))


def normalize_reference(coeffs, target: float = 0.8):
    """Scale coeffs so mean_luminance == target; returns (scaled coeffs, scale)."""
    c = validate_coeffs(coeffs)
    try:
        target = float(target)
    except (TypeError, ValueError):
        raise ValueError(f"target luminance must be a number, got {target!r}") from None
    if not (math.isfinite(target) and target > 0):
        raise ValueError(f"target luminance must be finite and > 0, got {target}")
    current = mean_luminance(c)
    if not current > 0:
        raise ValueError(f"light has mean luminance {current:g} <= 0; cannot normalize it")
    scale = target / current
    return c * scale, scale


# ---------------------------------------------------------------- adaptive order


def band_irradiance_energy(coeffs) -> np.ndarray:
    """Energy per band l of the clamped-cosine-convolved light: A_l^2 sum_m,rgb L_lm^2."""
    c = validate_coeffs(coeffs)
    order = order_from_num_coeffs(c.shape[0])
    A = clamped_cosine_coeffs(order)
    band = np.repeat(np.arange(order + 1), 2 * np.arange(order + 1) + 1)
    per_coeff = (c.astype(np.float64) ** 2).sum(axis=1)
    return A**2 * np.bincount(band, weights=per_coeff, minlength=order + 1)


def required_order(coeffs, fraction: float = 0.99) -> int:
    """Smallest order whose convolved energy holds `fraction` of the total of `coeffs`.

    A diffuse surface sees the light through the clamped cosine, whose A_l falls
    as l^-2.5 (and is 0 for odd l > 1): bands beyond this order change a
    Lambertian image by at most sqrt(1 - fraction) of its energy. Pass order-8
    coefficients to compare against the order-8 total.
    """
    if not (isinstance(fraction, (int, float)) and 0.0 < fraction <= 1.0):
        raise ValueError(f"fraction must be in (0, 1], got {fraction!r}")
    energy = band_irradiance_energy(coeffs)
    total = energy.sum()
    if not total > 0:
        return 0  # a black light needs nothing
    captured = np.cumsum(energy) / total
    # Tolerance: cumsum rounding may leave the full sum a few ulps below 1.
    return int(np.argmax(captured >= fraction - 1e-12))


def directional_light(azimuth_deg: float, order: int, elevation_deg: float = 30.0,
                      ambient: float = 0.2, target: float = 0.8) -> np.ndarray:
    """A white directional light plus a constant ambient term, as SH [n, 3] at mean luminance `target`.

    Azimuth 0 lights the person from the camera's side (the light sits toward -Y
    from the person, docs/conventions.md); positive azimuth turns it about world Z
    like z_rotation. `ambient` is the constant part's share of the irradiance a
    surface facing the light gets, so the far side is not pure black. A direct
    light's SH is its delta, Y_lm(d), truncated at `order`; the ambient term
    lives in Y_00 only.
    """
    if not (math.isfinite(azimuth_deg) and math.isfinite(elevation_deg) and 0.0 <= ambient < 1.0):
        raise ValueError("directional_light: azimuth and elevation must be finite, ambient in [0, 1)")
    e = math.radians(elevation_deg)
    direction = z_rotation(azimuth_deg) @ np.array([0.0, -math.cos(e), math.sin(e)])
    delta = sh_basis(direction, order)  # SH of a delta of integral 1 at `direction`
    # a delta of integral 1 gives a facing surface irradiance 1; a constant radiance c
    # gives irradiance pi * c: choose c so the ambient share of a facing surface is `ambient`
    c = ambient / (1.0 - ambient) / math.pi
    coeffs = np.zeros((num_coeffs(order), 3))
    coeffs += delta[:, None]
    coeffs[0] += 2.0 * math.sqrt(math.pi) * c
    return normalize_reference(coeffs, target)[0]
