"""An SH light as a non-negative equirectangular radiance map in Blender's World mapping.

The photo's estimated light (`Decomposition.light`) evaluated on the sphere
rings and goes negative; a World texel cannot. The map is

    f(w) = max(0, sum_lm c_lm Y_lm(w))

at the texel centres of Blender's mapping (relight.lighting.sh_projection.equirect_directions):
the light's own SH (c = L) when that is >= 0 at every texel; otherwise the
clamp of the coefficients c that minimise the convex

    1/2 integral f(w)^2 dw  -  sum_lm c_lm L_lm  +  lambda/2 sum_lm c_lm^2 / A_l^2

over the bands a diffuse surface sees (A_l != 0: l = 0, 1, 2, 4, 6, ...).
Its stationarity, A_l^2 (L_lm - f_lm) = lambda c_lm, says the map's irradiance
coefficients A_l f_lm equal the light's up to lambda: the map lights a
Lambertian surface as the runtime's SH does, up to what the clamp adds in
bands above the light's order (the irradiance error, `irradiance_error`).
Band 3 (A_3 = 0) is left free: no diffuse surface sees it, and fitting it
costs irradiance accuracy. Why not a per-band window: docs/conventions.md
("The light as a World map"), measured by benchmarks/bench_light_map.py.
numpy only.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from relight.lighting import sh, sh_projection

__all__ = ["LightMap", "light_map", "irradiance_error", "check_width", "DEFAULT_WIDTH", "MAX_WIDTH",
           "REGULARISATION"]

DEFAULT_WIDTH = 512
MIN_WIDTH, MAX_WIDTH = 8, 4096
# lambda above: 1e-5 .. 1e-3 give the same irradiance error (within 0.001 on the
# held-out estimates, 0.003 on the presets); larger lambda smooths the hot spot of a
# sharp light (peak / mean 123 at 1e-4, 569 at 1e-6) and then costs accuracy
# (benchmarks/bench_light_map.py --lambdas)
REGULARISATION = 1e-4
# the Newton solve runs on a 128 x 64 grid (or the map's, when smaller); two more steps on a
# 512 x 256 map's own grid change the irradiance error by < 0.0001 and cost 3x the time
# (benchmarks/bench_light_map.py)
FIT_HEIGHT = 64
MAX_STEPS = 60            # Newton steps (the presets and the held-out estimates take 2-13)
TABLE_HEIGHT = 256        # maps up to 512 x 256 are evaluated with a cached basis table
STRIP_ROWS = 64           # map rows evaluated at a time (bounds the basis table)
IRRADIANCE_ORDER = 16     # the map's irradiance is compared up to this band (A_16 / A_0 < 0.002)


@dataclass(frozen=True)
class LightMap:
    """The map of one SH light: `pixels` linear RGB float32 [H, W, 3] (>= 0, finite),
    `coeffs` the light as given [n, 3], `map_coeffs` the c with pixels = max(0, sum c Y)
    (equal to `coeffs` when `fitted` is False: the light's SH was >= 0 on every texel)."""

    pixels: np.ndarray
    coeffs: np.ndarray
    map_coeffs: np.ndarray
    fitted: bool

    @property
    def order(self) -> int:
        return sh.order_from_num_coeffs(self.coeffs.shape[0])


def check_width(width) -> int:
    """The map width as an int; ValueError unless an even integer in [MIN_WIDTH, MAX_WIDTH]."""
    if isinstance(width, bool) or not isinstance(width, (int, np.integer)):
        raise ValueError(f"map width must be an integer, got {width!r}")
    if not (MIN_WIDTH <= width <= MAX_WIDTH) or width % 2:
        raise ValueError(f"map width must be even and within {MIN_WIDTH}..{MAX_WIDTH}, got {width}")
    return int(width)


@functools.lru_cache(maxsize=6)
def _grid(height: int, order: int):
    """SH basis [H*2H, n] at the texel centres of a 2H x H map and each texel's solid angle [H*2H]."""
    dirs, solid_angle = sh_projection.equirect_directions(height, 2 * height)
    basis = sh.sh_basis(dirs, order).reshape(-1, sh.num_coeffs(order))
    omega = np.repeat(solid_angle, 2 * height)
    basis.flags.writeable = omega.flags.writeable = False
    return basis, omega


def _evaluate(coeffs: np.ndarray, height: int):
    """sum_k coeffs[k] Y_k at the texel centres of a 2H x H map, [H, 2H, C] float64, in row strips."""
    width = 2 * height
    order = sh.order_from_num_coeffs(coeffs.shape[0])
    if height <= TABLE_HEIGHT:
        return (_grid(height, order)[0] @ coeffs).reshape(height, width, coeffs.shape[1])
    dirs, _ = sh_projection.equirect_directions(height, width)
    out = np.empty((height, width, coeffs.shape[1]))
    for r0 in range(0, height, STRIP_ROWS):
        out[r0:r0 + STRIP_ROWS] = sh.sh_basis(dirs[r0:r0 + STRIP_ROWS], order) @ coeffs
    return out


def _fitted_bands(order: int) -> np.ndarray:
    """Coefficient indices of the bands a Lambertian surface sees (A_l != 0), and 1 / A_l^2 for each."""
    A = sh.clamped_cosine_coeffs(order)
    band = np.repeat(np.arange(order + 1), 2 * np.arange(order + 1) + 1)
    keep = np.flatnonzero(np.abs(A[band]) > 1e-12)
    return keep, 1.0 / A[band[keep]] ** 2


def _newton(basis, omega, target, reg, c, steps: int) -> np.ndarray:
    """Minimise 1/2 sum omega max(0, basis c)^2 - c.target + 1/2 c.reg.c from c (damped Newton).

    The objective is convex and piecewise quadratic; its Hessian, the active texels'
    Gram matrix plus diag(reg), is positive definite (reg > 0), so each step is a descent
    direction and a halving line search keeps the objective falling."""
    tol = 1e-9 * max(float(np.linalg.norm(target)), 1e-300)  # round-off leaves ~1e-10
    values = basis @ c

    def objective(c, values):
        positive = np.maximum(values, 0.0)
        return 0.5 * float(omega @ (positive * positive)) - float(c @ target) + 0.5 * float(c @ (reg * c))

    for _ in range(steps):
        positive = np.maximum(values, 0.0)
        grad = basis.T @ (omega * positive) - target + reg * c
        if not np.linalg.norm(grad) > tol:
            break
        active = values > 0
        on = basis[active]
        hessian = (on * omega[active, None]).T @ on
        hessian[np.diag_indices_from(hessian)] += reg
        step = np.linalg.solve(hessian, grad)
        start, slope, t = objective(c, values), float(grad @ step), 1.0
        while True:
            trial = c - t * step
            trial_values = basis @ trial
            if objective(trial, trial_values) <= start - 1e-4 * t * slope or t < 1e-6:
                break
            t *= 0.5
        c, values = trial, trial_values
    return c


def _fit(coeffs: np.ndarray, height: int) -> np.ndarray:
    """The coefficients c of the module docstring, per channel, [n, C] (0 on the bands not fitted),
    solved on a grid of min(height, FIT_HEIGHT) rows (any number of channels C: relight.lighting.key_light
    fits a luminance alone)."""
    order = sh.order_from_num_coeffs(coeffs.shape[0])
    keep, inverse_a2 = _fitted_bands(order)
    reg = REGULARISATION * inverse_a2
    basis, omega = _grid(min(height, FIT_HEIGHT), order)
    basis = basis[:, keep]
    out = np.zeros_like(coeffs)
    for channel in range(coeffs.shape[1]):
        target = coeffs[keep, channel]
        if np.any(target):  # a black channel stays black
            out[keep, channel] = _newton(basis, omega, target, reg, target.copy(), MAX_STEPS)
    return out


def light_map(coeffs, width: int = DEFAULT_WIDTH) -> LightMap:
    """The non-negative equirect map (width x width/2) of the SH light `coeffs` [n, 3].

    ValueError for coefficients that are not [(order+1)^2, 3] and finite, a bad width,
    or a light too bright for float32 texels.
    """
    L = sh.validate_coeffs(coeffs, "light")
    height = check_width(width) // 2
    values = _evaluate(L, height)
    fitted = bool(values.min() < 0)
    c = L
    if fitted:
        c = _fit(L, height)
        values = np.maximum(_evaluate(c, height), 0.0)
    with np.errstate(over="ignore"):
        pixels = values.astype(np.float32)
    if not np.all(np.isfinite(pixels)):
        raise ValueError("the light is too bright for a float32 map (texels beyond 3.4e38)")
    pixels.flags.writeable = False
    return LightMap(pixels=pixels, coeffs=L, map_coeffs=c, fitted=fitted)


def irradiance_error(coeffs, pixels) -> float:
    """Relative RMS difference, over all normals and channels, between the irradiance of
    the equirect map `pixels` and the SH irradiance of `coeffs` (what the runtime's
    Lambert transport gives): sqrt(sum A_l^2 (f_lm - L_lm)^2 / sum A_l^2 L_lm^2) by
    Parseval, f the map's SH up to IRRADIANCE_ORDER. 0 for a black light and black map."""
    L = sh.validate_coeffs(coeffs, "light")
    order = max(IRRADIANCE_ORDER, sh.order_from_num_coeffs(L.shape[0]))
    f = sh_projection.project_equirect(pixels, order, precision="float64")
    padded = np.zeros_like(f)
    padded[:L.shape[0]] = L
    A = sh.clamped_cosine_coeffs(order)
    weight = np.repeat(A, 2 * np.arange(order + 1) + 1)[:, None] ** 2
    reference = float(np.sum(weight * padded ** 2))
    difference = float(np.sum(weight * (f - padded) ** 2))
    if reference == 0.0:
        return 0.0 if difference == 0.0 else math.inf
    return math.sqrt(difference / reference)
