"""An SH light split into a key light (a sun: direction, colour, strength, angle) and a smooth World.

The model is a uniform cone of light (Blender's Sun: a disk of angular diameter
`angle`) plus whatever is left. A cone of half-angle a about the unit vector d,
of integral S (its radiance integrated over the sphere), has SH coefficients

    K_lm = S g_l(a) Y_lm(d),   g_l = (P_{l-1}(c) - P_{l+1}(c)) / ((2l + 1)(1 - c)),  c = cos a

(Funk-Hecke; g_0 = 1, g_1 = (1 + c) / 2, g_2 = c (1 + c) / 2, all 1 for a delta). So
from bands 1 and 2 of a light, projected on the key's direction d,

    s_l = (4 pi / (2l + 1)) sum_m L_lm Y_lm(d) = S g_l,     s_2 / s_1 = cos a,   S = 2 s_1 / (1 + c):

the closed forms `fit_key` uses (on the luminance for the angle, per channel for the
colour). When the light has band 4 and g_4(a) / g_2(a) = s_4 / s_2 has a root (a <= 49
degrees), the angle comes from bands 2 and 4 instead and S = min(s_2 / g_2, s_1 / g_1): a
broad sky adds to band 1 about d and would widen the s_2 / s_1 cone (a 2-degree sun under
a sky: 30 degrees). d is where the light's luminance SH up to band DIRECTION_BANDS, Hanning
windowed, peaks (for band 1 alone that is the band-1 vector; a delta's truncated SH peaks at the
delta).
The key is then shrunk, if needed, until what is left is a light (mean >= 0 per channel,
order-2 irradiance >= 0 or no lower than the light's own).

The rest (`smooth_world`) is capped at band WORLD_ORDER = 2: band 3 is invisible to a
diffuse surface (A_3 = 0) and band 4 nearly so (A_4 / A_0 = 1/24), and those are the bands
whose per-channel ringing made today's map show coloured stripes. Its luminance is the
non-negative fit of relight.lighting.light_map (irradiance-preserving up to lambda) and its
colour one slowly varying chromaticity: that of the residual's own band-0 + band-1
irradiance, a positively weighted average of the light, so for a light >= 0 it holds no
colour the light does not. A last per-channel scale makes its mean (band 0) exact.

Units: coefficients are radiance as the runtime's light (a World of strength 1 shows
them as they are). A key's `strength` S is the integral of its radiance over the sphere,
which for a small sun is the irradiance (W/m^2) of a surface facing it, Blender's Sun
Strength; `blender_strength` is what a Blender Sun of the key's angle needs
(docs/conventions.md, "The light as a key lamp and a World"). numpy only.
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

from relight.lighting import sh, sh_projection
from relight.lighting.light_colour import bound_saturation, chroma_spread
from relight.imaging.colour import LUMINANCE_WEIGHTS

__all__ = ["KeyLight", "LightSplit", "cone_profile", "lobe_coeffs", "key_direction", "fit_key", "key_coeffs",
           "smooth_world", "split_light", "split_irradiance_error", "chroma_spread", "direction_from_angles",
           "angles_from_direction", "DIRECTION_BANDS", "WORLD_ORDER", "WIDE_ANGLE_DEG"]

DIRECTION_BANDS = 4      # bands whose windowed luminance peak is the key's direction (benchmarks/bench_key_direction.py at 619862d)
DIRECTION_WINDOW = "hanning"  # relight.lighting.sh.window over those bands: 3 and 4 sharpen, damped
WORLD_ORDER = 2          # the smooth World's highest band
CHROMA_ORDER = 1         # the World's chromaticity: SH up to this band (1: linear in the direction)
WIDTH_FROM_BAND4 = True  # the key's width from bands 2 and 4 when they agree (benchmarks/bench_key_light.py at 619862d)
WIDTH_STEPS = 50         # bisection steps of that width
WIDE_ANGLE_DEG = 90.0    # a key wider than this (full angle) becomes an area light in Blender
SEARCH_POINTS = 2048     # Fibonacci directions of the coarse peak search (about 4.5 degrees apart)
REFINE_STEPS = 24        # halvings of the local search: 4.5 / 2^24 degrees
RADIANCE_RING = 0.20     # a delta's order-2 radiance dips to -0.20 of its peak ((1 - 3/5 - 5 * 0.44) / 9)
IRRADIANCE_RING = 0.035  # and its order-2 irradiance to -0.0375 / 1.0625 of a facing surface's
SHRINK_STEPS = 40        # bisection steps on the key's share when the rest would have negative irradiance
CHROMA_PENALTY = 1e4     # weight of a negative chromaticity against the irradiance fit (per unit of |M|^2)
CHROMA_STEPS = 30        # active-set steps of the chromaticity fit


@functools.lru_cache(maxsize=8)
def _gauss_legendre(n: int):
    return np.polynomial.legendre.leggauss(n)


def cone_profile(half_angle: float, order: int) -> np.ndarray:
    """g_l, l <= order, of a uniform cone of half-angle `half_angle` (radians, in [0, pi])
    and integral 1: its SH are g_l Y_lm(axis), g_l the mean of the Legendre polynomial P_l over the
    cap. 1 for every l at half-angle 0 (a delta)."""
    order = sh.check_order(order)
    a = float(half_angle)
    if not (math.isfinite(a) and 0.0 <= a <= math.pi):
        raise ValueError(f"cone half-angle must be in [0, pi] radians, got {half_angle!r}")
    if a == 0.0:
        return np.ones(order + 1)
    # the mean of P_l over the cap mu in [cos a, 1], by Gauss-Legendre quadrature exact for degree
    # <= order (no cancellation, unlike the closed form's (P_{l-1} - P_{l+1}) / (1 - c) near a delta)
    x, w = _gauss_legendre(order // 2 + 1)
    one_minus_c = 2.0 * math.sin(a / 2.0) ** 2
    mu = 1.0 - one_minus_c * (1.0 - x) / 2.0
    p_prev, p = np.ones_like(mu), mu
    g = np.empty(order + 1)
    g[0] = 1.0
    for l in range(1, order + 1):
        g[l] = float(w @ p) / 2.0
        p_prev, p = p, ((2 * l + 1) * mu * p - l * p_prev) / (l + 1)
    return g


def lobe_coeffs(direction, half_angle: float, order: int) -> np.ndarray:
    """SH [n] of a uniform cone of integral 1 about `direction` (any non-zero vector)."""
    g = cone_profile(half_angle, order)
    band = np.repeat(np.arange(order + 1), 2 * np.arange(order + 1) + 1)
    return g[band] * sh.sh_basis(np.asarray(direction, dtype=np.float64), order)


@functools.lru_cache(maxsize=1)
def _fibonacci(n: int) -> np.ndarray:
    i = np.arange(n) + 0.5
    z = 1.0 - 2.0 * i / n
    phi = math.pi * (1.0 + math.sqrt(5.0)) * i
    r = np.sqrt(1.0 - z * z)
    out = np.stack([r * np.cos(phi), r * np.sin(phi), z], axis=-1)
    out.flags.writeable = False
    return out


@functools.lru_cache(maxsize=4)
def _search_basis(bands: int) -> np.ndarray:
    out = sh.sh_basis(_fibonacci(SEARCH_POINTS), bands)
    out.flags.writeable = False
    return out


def _band_slice(lo: int, hi: int) -> slice:
    return slice(lo * lo, (hi + 1) * (hi + 1))


def key_direction(coeffs, bands: int = DIRECTION_BANDS, window: str | None = DIRECTION_WINDOW) -> np.ndarray:
    """Unit vector toward the peak of the light's luminance SH over bands 1..`bands` (at most the
    light's order), band l weighted by relight.lighting.sh.window(bands, `window`) (None: not
    weighted; band 0 is a constant and does not move the peak). Band 1 alone: the band-1 vector,
    in closed form. Otherwise a search over SEARCH_POINTS directions refined locally. On
    estimated lights bands 1-4 Hanning-windowed point the key nearer the true light than bands
    1-2 unwindowed (benchmarks/bench_key_direction.py at 619862d; docs/EVALUATION.md)."""
    L = sh.validate_coeffs(coeffs, "light")
    order = sh.order_from_num_coeffs(L.shape[0])
    bands = max(1, min(int(bands), order))
    sigma = np.ones(bands + 1) if window is None else sh.window(bands, window)
    y = (L[:(bands + 1) ** 2] @ LUMINANCE_WEIGHTS) * np.repeat(sigma, 2 * np.arange(bands + 1) + 1)
    if bands == 1 or not np.any(y[_band_slice(2, bands)]):
        v = np.array([y[3], y[1], y[2]])  # (Y_11, Y_1-1, Y_10) are x, y, z up to one factor
        n = float(np.linalg.norm(v))
        return v / n if n > 0 else np.array([0.0, 0.0, 1.0])
    w = y[:(bands + 1) ** 2].copy()
    w[0] = 0.0

    def score(dirs):
        return sh.sh_basis(dirs, bands) @ w

    grid = _fibonacci(SEARCH_POINTS)
    best = grid[int(np.argmax(_search_basis(bands) @ w))]
    step = math.radians(4.5)
    offsets = np.array([(i, j) for i in (-1, 0, 1) for j in (-1, 0, 1)], dtype=np.float64)
    for _ in range(REFINE_STEPS):
        t1 = np.cross(best, [0.0, 0.0, 1.0] if abs(best[2]) < 0.9 else [1.0, 0.0, 0.0])
        t1 /= np.linalg.norm(t1)
        t2 = np.cross(best, t1)
        trial = best + step * (offsets[:, :1] * t1 + offsets[:, 1:] * t2)
        trial /= np.linalg.norm(trial, axis=1, keepdims=True)
        best = trial[int(np.argmax(score(trial)))]
        step *= 0.5
    return best / np.linalg.norm(best)


def angles_from_direction(direction) -> tuple[float, float]:
    """(azimuth, elevation) in degrees of a direction toward a light, in
    relight.lighting.light.directional_light's convention: azimuth 0 is toward -Y (the camera's
    side of the person), positive azimuth turns it about +Z from -Y toward +X."""
    d = np.asarray(direction, dtype=np.float64)
    d = d / np.linalg.norm(d)
    elevation = math.degrees(math.asin(max(-1.0, min(1.0, float(d[2])))))
    azimuth = math.degrees(math.atan2(float(d[0]), float(-d[1])))
    return azimuth, elevation


def direction_from_angles(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """The unit vector toward a light at (azimuth, elevation) degrees (angles_from_direction's inverse)."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.sin(a) * math.cos(e), -math.cos(a) * math.cos(e), math.sin(e)])


@dataclass(frozen=True)
class KeyLight:
    """A cone of light: `direction` unit vector toward it (Blender world axes), `rgb` its
    radiance integrated over the sphere per channel [3] (W/m^2: a facing surface's irradiance
    for a small cone), `half_angle` radians."""

    direction: np.ndarray
    rgb: np.ndarray
    half_angle: float

    @property
    def strength(self) -> float:
        """The largest channel of rgb: the key is colour * strength, colour's largest channel 1."""
        return float(np.max(self.rgb, initial=0.0))

    @property
    def colour(self) -> np.ndarray:
        s = self.strength
        return self.rgb / s if s > 0 else np.ones(3)

    @property
    def angle_deg(self) -> float:
        """Full angular diameter in degrees (Blender's Sun Angle)."""
        return math.degrees(2.0 * self.half_angle)

    @property
    def blender_strength(self) -> float:
        """A Blender Sun's Strength for this key: Cycles gives a surface facing a Sun of any
        angle the irradiance Strength, while the cone's is strength * g_1 (docs/conventions.md)."""
        return self.strength * float(cone_profile(self.half_angle, 1)[1])

    @property
    def wide(self) -> bool:
        return self.angle_deg > WIDE_ANGLE_DEG

    def as_json(self) -> dict:
        azimuth, elevation = angles_from_direction(self.direction)
        return {"direction": [round(float(v), 6) for v in self.direction],
                "azimuth_deg": round(azimuth, 3), "elevation_deg": round(elevation, 3),
                "colour": [round(float(v), 6) for v in self.colour],
                "strength": round(self.blender_strength, 6), "integral": round(self.strength, 6),
                "angle_deg": round(self.angle_deg, 3), "lamp": "AREA" if self.wide else "SUN"}


def key_coeffs(key: KeyLight, order: int) -> np.ndarray:
    """SH [n, 3] of the key light."""
    return lobe_coeffs(key.direction, key.half_angle, order)[:, None] * np.asarray(key.rgb)[None, :]


def _order2_min(coeffs9: np.ndarray) -> np.ndarray:
    """[luminance radiance, irradiance per channel]: minima over SEARCH_POINTS directions of
    the order-2 luminance of coeffs [9, 3] and of each channel's order-2 irradiance; [4]."""
    A = np.repeat(sh.clamped_cosine_coeffs(2), [1, 3, 5])
    basis = _basis2()
    radiance = (basis @ (coeffs9 @ LUMINANCE_WEIGHTS)).min()
    return np.concatenate([[radiance], (basis @ (A[:, None] * coeffs9)).min(axis=0)])


@functools.lru_cache(maxsize=1)
def _basis2() -> np.ndarray:
    out = sh.sh_basis(_fibonacci(SEARCH_POINTS), 2)
    out.flags.writeable = False
    return out


def _order2(coeffs: np.ndarray) -> np.ndarray:
    out = np.zeros((9, coeffs.shape[1]))
    n = min(9, coeffs.shape[0])
    out[:n] = coeffs[:n]
    return out


def _width_from_band4(L: np.ndarray, d: np.ndarray, s2y: float) -> float | None:
    """The half-angle a of the cone about d with g_4(a) / g_2(a) = s_4 / s_2 (luminance; bisection:
    the ratio falls from 1 at a delta to 0 as the cone widens), or None when the light has no band
    4 or the ratio is <= 0 (a cone wider than 49 degrees, where band 4 says little); 0 (a delta) for
    a ratio >= 1."""
    if not WIDTH_FROM_BAND4 or L.shape[0] < 25 or not s2y > 0:
        return None
    s4y = float((4.0 * math.pi / 9.0) * (sh.sh_basis(d, 4)[16:25] @ L[16:25]) @ LUMINANCE_WEIGHTS)
    ratio = s4y / s2y
    if ratio >= 1.0:
        return 0.0  # as sharp as a delta or sharper (a broad part adds to band 4 about d): a delta
    if not ratio > 0.0:
        return None
    lo, hi = 0.0, math.acos(math.sqrt(3.0 / 7.0))  # g_4 / g_2 reaches 0 where P_3-P_5 balance: ~49 deg
    for _ in range(WIDTH_STEPS):
        mid = 0.5 * (lo + hi)
        g = cone_profile(mid, 4)
        if g[4] / g[2] > ratio:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


def fit_key(coeffs, bands: int = DIRECTION_BANDS) -> KeyLight:
    """The key light of the SH light `coeffs` [n, 3] (order >= 1) by the module docstring's
    closed forms (the width from bands 1 and 2, or 2 and 4); shrunk, if needed, until what is
    left is a light. A light without a positive lobe gives a key of strength 0."""
    L = sh.validate_coeffs(coeffs, "light")
    if L.shape[0] < 4:
        raise ValueError("a key light needs a light of SH order >= 1")
    d = key_direction(L, bands)
    basis = sh.sh_basis(d, 2)
    s1 = (4.0 * math.pi / 3.0) * (basis[1:4] @ L[1:4])         # [3]
    s1y = float(s1 @ LUMINANCE_WEIGHTS)
    if not s1y > 0:
        return KeyLight(d, np.zeros(3), 0.0)
    c, s2y = 1.0, s1y
    if L.shape[0] >= 9:
        s2y = float((4.0 * math.pi / 5.0) * (basis[4:9] @ L[4:9]) @ LUMINANCE_WEIGHTS)
        c = min(1.0, max(0.0, s2y / s1y))                      # hemisphere at most (g_2 = 0)
    rgb = np.maximum(s1, 0.0) * 2.0 / (1.0 + c)
    half = _width_from_band4(L, d, s2y)
    if half is not None:  # bands 2 and 4 agree on a cone: its width from them, its strength from band 2
        g = cone_profile(half, 2)
        c = math.cos(half)
        rgb = np.maximum(s1, 0.0) / s1y * min(s2y / g[2], s1y / g[1])
    key = KeyLight(d, rgb, math.acos(c))
    rest = _order2(L)
    # what is left must be a light: its mean >= 0 per channel, its order-2 luminance radiance and
    # every channel's order-2 irradiance >= 0, or no lower than the light's own, less `ring`
    floor = np.minimum(_order2_min(rest), 0.0) - 1e-12 * max(1.0, float(np.abs(L[0]).max()))

    key2 = _order2(key_coeffs(key, 2))
    tiny = 1e-12 * max(1.0, float(np.abs(L[0]).max()))
    # what the key's own order-2 ringing may explain (a delta's order-2 radiance rings to 0.20 of its
    # peak, its irradiance to 3.5 % of a facing surface's): the rest's minima may fall that far below
    # the light's own (a light whose own order-2 irradiance is negative, as estimates' can be, would
    # otherwise refuse any key: the minimum falls linearly in t)
    g = cone_profile(key.half_angle, 2)
    ring = np.concatenate([[RADIANCE_RING * float(key.rgb @ LUMINANCE_WEIGHTS) * float(g @ [1, 3, 5]) / (4 * math.pi)],
                           IRRADIANCE_RING * key.rgb * g[1]])

    def fits(t: float) -> bool:  # and never more light than there is: the rest's mean >= 0 per channel
        return bool(np.all(_order2_min(rest - t * key2) >= floor - ring)
                    and np.all(rest[0] - t * key2[0] >= -tiny))

    if fits(1.0):
        return key
    lo, hi = 0.0, 1.0
    for _ in range(SHRINK_STEPS):
        mid = 0.5 * (lo + hi)
        if fits(mid):
            lo = mid
        else:
            hi = mid
    return KeyLight(d, rgb * lo, key.half_angle)


def _luminance_coeffs(lum: np.ndarray) -> np.ndarray:
    """The order-2 luminance [9] itself when it is >= 0 on relight.lighting.light_map's fit grid, else
    relight.lighting.light_map's irradiance-preserving non-negative fit of it (to be clamped at 0); [9, 1]."""
    from relight.lighting import light_map

    values = light_map._evaluate(lum[:, None], light_map.FIT_HEIGHT)
    return lum[:, None] if values.min() >= 0 else light_map._fit(lum[:, None], light_map.FIT_HEIGHT)


def _chroma_fit(M: np.ndarray, r: np.ndarray, phi: np.ndarray, weight: np.ndarray) -> np.ndarray:
    """q [4] minimising |M q - r|^2 subject to phi q >= 0 (phi [N, 4], the texels where the World
    is lit), by a penalty CHROMA_PENALTY * |M|^2 * sum weight min(0, phi q)^2 solved exactly per
    active set (convex, piecewise quadratic; the active set settles in a few steps)."""
    gram, rhs = M.T @ M, M.T @ r
    mu = CHROMA_PENALTY * max(float(np.trace(gram)), 1e-300)
    q = np.linalg.lstsq(M, r, rcond=None)[0]
    active = None
    for _ in range(CHROMA_STEPS):
        now = phi @ q < 0
        if active is not None and np.array_equal(now, active):
            break
        active = now
        on = phi[active]
        q = np.linalg.solve(gram + mu * (on * weight[active, None]).T @ on + 1e-12 * np.eye(len(q)) * mu, rhs)
    return q


def smooth_world(residual, width: int = 512) -> np.ndarray:
    """The non-negative, smooth equirect map [width/2, width, 3] float32 (Blender's World
    mapping) of the SH light `residual` [n, 3]: f(w) (a_c + b_c . w) per channel c, f the
    non-negative fit of the residual's order-2 luminance and a_c + b_c . w (|b_c| <= a_c, so
    >= 0) the chromaticity, linear in the direction, whose product with f has the
    irradiance of channel c in bands 0-2 nearest the residual's (least squares, A_l^2-weighted)."""
    from relight.lighting import light_map

    R = _order2(sh.validate_coeffs(residual, "light"))
    height = light_map.check_width(width) // 2
    lum = R @ LUMINANCE_WEIGHTS
    fit_height = min(height, light_map.FIT_HEIGHT)
    c_lum = _luminance_coeffs(lum)
    f = np.maximum(light_map._evaluate(c_lum, fit_height)[..., 0], 0.0).reshape(-1)
    basis, omega = light_map._grid(fit_height, 2)
    dirs = sh_projection.equirect_directions(fit_height, 2 * fit_height)[0].reshape(-1, 3)
    phi = sh.sh_basis(dirs, CHROMA_ORDER)                                              # [N, m]
    P = basis.T @ (omega[:, None] * f[:, None] * phi)                                    # [9, m]
    A = np.repeat(sh.clamped_cosine_coeffs(2), [1, 3, 5])[:, None]
    support = f > 0
    weight = omega[support] * f[support]
    q = np.zeros((phi.shape[1], 3))
    if np.any(support):
        for c in range(3):
            q[:, c] = _chroma_fit(A * P, A[:, 0] * R[:, c], phi[support], weight / weight.sum())
    values = f.reshape(fit_height, 2 * fit_height) if fit_height == height else \
        np.maximum(light_map._evaluate(c_lum, height)[..., 0], 0.0)
    with np.errstate(over="ignore"):
        out = (values[..., None] * np.maximum(light_map._evaluate(q, height), 0.0)).astype(np.float32)
    if not np.all(np.isfinite(out)):
        raise ValueError("the light is too bright for a float32 map (texels beyond 3.4e38)")
    return np.maximum(out, 0.0)


@dataclass(frozen=True)
class LightSplit:
    """A light split into `key` and the smooth World `pixels` [H, W, 3] float32 (>= 0);
    `coeffs` the light as given [n, 3]."""

    key: KeyLight
    pixels: np.ndarray
    coeffs: np.ndarray


def split_light(coeffs, width: int = 512, bands: int = DIRECTION_BANDS) -> LightSplit:
    """The key light of `coeffs` [n, 3] and the smooth World of what is left."""
    L = sh.validate_coeffs(coeffs, "light")
    key = fit_key(L, bands)
    order = sh.order_from_num_coeffs(L.shape[0])
    # its colour capped at the rest's own most saturated (relight.lighting.light_colour.colour_envelope): the
    # chromaticity fit may overshoot it (green on one side, magenta on the other); the whole light's lit
    # colours would be the key's, and cap a sky dimmer than the sun at the sun's saturation
    rest = L - key_coeffs(key, order)
    pixels = bound_saturation(smooth_world(rest, width), rest)
    pixels.flags.writeable = False
    return LightSplit(key=key, pixels=pixels, coeffs=L)


def split_irradiance_error(split: LightSplit, key_order: int | None = None) -> float:
    """Relative RMS difference over all normals and channels between the irradiance of key +
    World and the SH irradiance of the light (relight.lighting.light_map.irradiance_error's measure, up to
    its IRRADIANCE_ORDER): sqrt(sum A_l^2 (f_lm - L_lm)^2 / sum A_l^2 L_lm^2), f the World's SH
    plus the key's exact SH up to `key_order` (default: all the compared bands, the key as Cycles
    renders it; the light's own order: the key as far as the light's SH knows it)."""
    from relight.lighting.light_map import IRRADIANCE_ORDER

    L = split.coeffs
    order = max(IRRADIANCE_ORDER, sh.order_from_num_coeffs(L.shape[0]))
    f = sh_projection.project_equirect(split.pixels, order, precision="float64")
    k = min(order, order if key_order is None else sh.check_order(key_order))
    f[:sh.num_coeffs(k)] += key_coeffs(split.key, k)
    padded = np.zeros_like(f)
    padded[:L.shape[0]] = L
    weight = np.repeat(sh.clamped_cosine_coeffs(order), 2 * np.arange(order + 1) + 1)[:, None] ** 2
    reference = float(np.sum(weight * padded ** 2))
    difference = float(np.sum(weight * (f - padded) ** 2))
    if reference == 0.0:
        return 0.0 if difference == 0.0 else math.inf
    return math.sqrt(difference / reference)
