"""Equirect maps and SH in Blender's mapping: texel directions and solid angles, the projection.

Blender's Environment Texture default mapping (docs/conventions.md): u = 0.5 -
atan2(y, x) / (2 pi), v = 0.5 + elevation / pi, row 0 at the top. The
projection is separable on that grid (a GEMM over columns, then a latitude
quadrature per coefficient); docs/benchmarks/sh.md has its speed. numpy only.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from relight.lighting.sh import check_order, legendre_table

__all__ = ["equirect_directions", "project_equirect"]


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
    q = legendre_table(np.sin(elevation), order)
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
    order = check_order(order)
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
    coeffs = np.empty(((order + 1) ** 2, 3))  # (the order checked above)
    with np.errstate(over="ignore", invalid="ignore"):
        for a, (k, w) in enumerate(groups):
            coeffs[k] = w.T @ per_row[:, :, a]
    if not np.all(np.isfinite(coeffs)):
        raise ValueError("equirect map values are too large: their sums overflow float64")
    return coeffs
