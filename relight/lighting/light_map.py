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
("The light as a World map"), measured by benchmarks/bench_light_map.py (at commit 619862d).

Clamped per channel, each channel rings on its own and the map gets fringes of
colours the light does not have; so a fitted map is P(sum c Y) instead, P the
nearest colour no more saturated than the light's own (relight.lighting.light_colour),
and c minimises the objective above with 1/2 |P(.)|^2 for max(0, .)^2: the same
stationarity, the three channels solved together. numpy only.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from relight.lighting import sh, sh_projection
from relight.lighting.light_colour import ENVELOPE_HEIGHT, colour_envelope, project_colours

__all__ = ["LightMap", "light_map", "irradiance_error", "check_width", "DEFAULT_WIDTH", "MAX_WIDTH",
           "REGULARISATION"]

DEFAULT_WIDTH = 512
MIN_WIDTH, MAX_WIDTH = 8, 4096
# lambda above: 1e-5 .. 1e-3 give the same irradiance error (within 0.001 on the
# held-out estimates, 0.003 on the presets); larger lambda smooths the hot spot of a
# sharp light (peak / mean 123 at 1e-4, 569 at 1e-6) and then costs accuracy
# (benchmarks/bench_light_map.py --lambdas, at commit 619862d)
REGULARISATION = 1e-4
# the Newton solve runs on a 128 x 64 grid (or the map's, when smaller); two more steps on a
# 512 x 256 map's own grid change the irradiance error by < 0.0001 and cost 3x the time
# (benchmarks/bench_light_map.py, at commit 619862d)
FIT_HEIGHT = 64
# the three channels' fit (_fit_colours) on 64 x 32: 5x faster than on 128 x 64, the irradiance error the same
# to 0.01 points on the presets (0.05 on the bundled photos' estimates)
COLOUR_FIT_HEIGHT = 32
MAX_STEPS = 60            # Newton steps (the presets and the held-out estimates take 2-13)
TABLE_HEIGHT = 256        # maps up to 512 x 256 are evaluated with a cached basis table
STRIP_ROWS = 64           # map rows evaluated at a time (bounds the basis table)
IRRADIANCE_ORDER = 16     # the map's irradiance is compared up to this band (A_16 / A_0 < 0.002)


@dataclass(frozen=True)
class LightMap:
    """The map of one SH light: `pixels` linear RGB float32 [H, W, 3] (>= 0, finite),
    `coeffs` the light as given [n, 3], `map_coeffs` the c with pixels = P(sum c Y), P the nearest
    colour of HSV saturation <= `saturation_bound` (relight.lighting.light_colour; equal to `coeffs`
    and a bound of 1, P = max(0, .), when `fitted` is False: the light's SH was >= 0 on every texel)."""

    pixels: np.ndarray
    coeffs: np.ndarray
    map_coeffs: np.ndarray
    fitted: bool
    saturation_bound: float = 1.0

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


def _newton_colours(basis, omega, target, reg, c, bound: float, steps: int) -> np.ndarray:
    """Minimise 1/2 sum omega |P(basis c)|^2 - <c, target> + 1/2 <c, reg c> over c [n, 3] (damped
    Newton), P the projection onto the colours of saturation <= bound (light_colour.project_colours):
    _newton with the three channels together and max(0, .) replaced by P. 1/2 |P(v)|^2 is convex
    with gradient P(v), so the optimum's map P(basis c) has the irradiance of `target` up to reg."""
    n = basis.shape[1]
    tol = 1e-9 * max(float(np.linalg.norm(target)), 1e-300)

    def at(c):
        x, derivative = project_colours(basis @ c, bound, jacobian=True)
        value = 0.5 * float(omega @ np.sum(x * x, axis=1)) - float(np.sum(c * target)) + 0.5 * float(np.sum(reg[:, None] * c * c))
        return x, derivative, value

    x, derivative, value = at(c)
    for _ in range(steps):
        grad = basis.T @ (omega[:, None] * x) - target + reg[:, None] * c
        if not np.linalg.norm(grad) > tol:
            break
        hessian = np.zeros((n, 3, n, 3))
        for a in range(3):
            for b in range(a, 3):  # the projection's derivative is symmetric
                w = omega * derivative[:, a, b]
                if np.any(w):
                    hessian[:, a, :, b] = hessian[:, b, :, a] = (basis * w[:, None]).T @ basis
        hessian = hessian.reshape(3 * n, 3 * n)
        hessian[np.diag_indices_from(hessian)] += np.repeat(reg, 3)
        step = np.linalg.solve(hessian, grad.reshape(-1)).reshape(n, 3)
        slope, t = float(np.sum(grad * step)), 1.0
        while True:
            trial = c - t * step
            trial_x, trial_derivative, trial_value = at(trial)
            if trial_value <= value - 1e-4 * t * slope or t < 1e-6:
                break
            t *= 0.5
        c, x, derivative, value = trial, trial_x, trial_derivative, trial_value
    return c


def _fit_colours(coeffs: np.ndarray, height: int, bound: float) -> np.ndarray:
    """_fit's coefficients [n, 3] for the map P(sum c Y) of colours of saturation <= bound, solved on a
    grid of min(height, COLOUR_FIT_HEIGHT) rows."""
    order = sh.order_from_num_coeffs(coeffs.shape[0])
    keep, inverse_a2 = _fitted_bands(order)
    basis, omega = _grid(min(height, COLOUR_FIT_HEIGHT), order)
    out = np.zeros_like(coeffs)
    out[keep] = _newton_colours(basis[:, keep], omega, coeffs[keep], REGULARISATION * inverse_a2,
                                coeffs[keep].copy(), bound, MAX_STEPS)
    return out


def _colour_map(c: np.ndarray, height: int, bound: float) -> np.ndarray:
    """P(sum c Y) at the texel centres of a 2H x H map, [H, 2H, 3]."""
    values = _evaluate(c, height)
    return project_colours(values.reshape(-1, 3), bound).reshape(values.shape)


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
    bound = 1.0
    if fitted:  # clamped per channel where each rings on its own, the map had fringes of colours no light has
        _, bound = colour_envelope(L, ENVELOPE_HEIGHT)
        c = _fit_colours(L, height, bound)
        values = _colour_map(c, height, bound)
    with np.errstate(over="ignore"):
        pixels = values.astype(np.float32)
    if not np.all(np.isfinite(pixels)):
        raise ValueError("the light is too bright for a float32 map (texels beyond 3.4e38)")
    pixels.flags.writeable = False
    return LightMap(pixels=pixels, coeffs=L, map_coeffs=c, fitted=fitted, saturation_bound=bound)


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
