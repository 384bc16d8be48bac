"""Real spherical harmonics: sizes and checks, the basis, per-band filters, a light's level.

Conventions (docs/conventions.md): real, orthonormal SH without the
Condon-Shortley phase, index k = l*l + l + m, Y_{1,-1} ~ y, Y_{1,0} ~ z,
Y_{1,1} ~ x. Equirect maps to SH: relight/lighting/sh_projection.py; rotations:
relight/lighting/sh_rotation.py.
numpy only.
"""

from __future__ import annotations

import functools
import math

import numpy as np

from relight.files.sh_sizes import MAX_ORDER, check_order, num_coeffs, order_from_num_coeffs
from relight.imaging.colour import LUMINANCE_WEIGHTS

REFERENCE_LUMINANCE = 0.8  # the mean luminance a map is scaled to (docs/conventions.md, exposure): the one definition

__all__ = [
    "MAX_ORDER",
    "check_order",
    "num_coeffs",
    "order_from_num_coeffs",
    "validate_coeffs",
    "sh_basis",
    "legendre_table",
    "clamped_cosine_coeffs",
    "window",
    "apply_window",
    "REFERENCE_LUMINANCE",
    "mean_luminance",
    "reference_scale",
    "normalize_reference",
]


# ---------------------------------------------------------------- sizes (relight/files/sh_sizes.py)


def validate_coeffs(coeffs, name: str = "coeffs") -> np.ndarray:
    """Return coeffs as float64 [n, 3]; ValueError on wrong shape or non-finite."""
    c = np.asarray(coeffs, dtype=np.float64)
    if c.ndim != 2 or c.shape[1] != 3:
        raise ValueError(f"{name} must have shape [(order+1)^2, 3], got {c.shape}")
    order_from_num_coeffs(c.shape[0])
    if not np.all(np.isfinite(c)):
        raise ValueError(f"{name} contains NaN or Inf")
    return c


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


def legendre_table(z: np.ndarray, order: int) -> list[list[np.ndarray]]:
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
    order = check_order(order)
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
    q = legendre_table(z, order)
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


# ---------------------------------------------------------------- convolution


def clamped_cosine_coeffs(order: int) -> np.ndarray:
    """A_l for l <= order: the irradiance filter, E_lm = A_l L_lm.

    A_l = sqrt(4 pi / (2l+1)) * (zonal coefficient of max(0, cos theta)):
    pi, 2pi/3, pi/4, 0, -pi/24, 0, pi/64, ...
    """
    order = check_order(order)
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
    order = check_order(order)
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
    return _mean_luminance(validate_coeffs(coeffs))


def _mean_luminance(c: np.ndarray) -> float:
    """mean_luminance of coefficients validate_coeffs returned (the one formula)."""
    return float(np.dot(LUMINANCE_WEIGHTS, c[0] / (2.0 * math.sqrt(math.pi))))


def reference_scale(c: np.ndarray, target: float = REFERENCE_LUMINANCE) -> float:
    """The factor that scales the light `c` (coefficients as validate_coeffs returns them: not
    checked again) to mean luminance `target`; ValueError for a target that is not finite and
    > 0, a light that is not bright (mean luminance <= 0), or one that the factor would
    overflow. A rotation about any axis keeps band 0, and with it this factor."""
    try:
        target = float(target)
    except (TypeError, ValueError):
        raise ValueError(f"target luminance must be a number, got {target!r}") from None
    if not (math.isfinite(target) and target > 0):
        raise ValueError(f"target luminance must be finite and > 0, got {target}")
    current = _mean_luminance(c)
    if not current > 0:
        raise ValueError(f"light has mean luminance {current:g} <= 0; cannot normalize it")
    scale = target / current
    if not (math.isfinite(scale) and np.all(np.isfinite(c * scale))):
        raise ValueError(f"light has mean luminance {current:g}, too dim beside its other coefficients to be "
                         f"scaled to {target:g} in float64")
    return scale


def normalize_reference(coeffs, target: float = REFERENCE_LUMINANCE):
    """Scale coeffs so mean_luminance == target; returns (scaled coeffs, scale)."""
    c = validate_coeffs(coeffs)
    scale = reference_scale(c, target)
    return c * scale, scale
