"""The colours a World map of an SH light may hold: no texel more saturated than the light's own.

Truncated SH of a light whose colour varies (a warm sun over a blue sky) ring differently per
channel; clamped at 0 per channel they make coloured fringes: texels where one channel is 0
and the others lit (saturation 1), colours the light does not have. The light's own colours
are bounded by a positive average of it (`colour_envelope`): the SH light smoothed by the
kernel ((1 + cos) / 2)^p, which is >= 0 and a polynomial of degree p in the cosine, so exact
on the SH (p <= the light's order). Each texel of that field is a positive mix of the light's
colours, and the colours of HSV saturation <= s form a convex cone

    K_s = {x : x_i >= (1 - s) x_j for every pair of channels i, j},

so the field's highest saturation where it is lit, `bound`, is no more than the light's most
saturated colour. relight.lighting.light_map projects its map onto K_bound (`project_colours`: the nearest
colour in the cone, Euclidean) and fits the coefficients under that projection; the key light's
smooth World moves its texels above the bound toward the field's colour (`bound_saturation`).
HSV saturation is (max - min) / max. numpy only.
"""

from __future__ import annotations

import math

import numpy as np

from relight.imaging.colour import LUMINANCE_WEIGHTS
from relight.lighting import sh, sh_projection

__all__ = ["saturation", "colour_envelope", "project_colours", "bound_saturation", "chroma_spread"]

PAIRS = tuple((i, j) for i in range(3) for j in range(3) if i != j)
# the bound is the envelope's most saturated *lit* colour: directions at least this share of its brightest
# (any subset keeps the bound within the light's colours; 0 and 0.05 left bounds up to 0.94 on the bundled
# photos' estimates, from dim directions; 0.2: at most 0.76, the presets' irradiance error 0.72 -> 0.89 %)
LIT_FRACTION = 0.2
ENVELOPE_HEIGHT = 64  # rows of the map on which the envelope's power and bound are found
CANDIDATE_ROWS = 16384  # colours projected at a time (bounds the [N, 16, 3] candidates)


def saturation(rgb) -> np.ndarray:
    """HSV saturation (max - min) / max of colours [..., 3] >= 0; 0 for black."""
    rgb = np.asarray(rgb, np.float64)
    top = rgb.max(axis=-1)
    return np.where(top > 0, (top - rgb.min(axis=-1)) / np.where(top > 0, top, 1.0), 0.0)


def _positive_kernel(power: int, order: int) -> np.ndarray:
    """Funk-Hecke factors lambda_l / lambda_0, l <= order, of the kernel ((1 + cos) / 2)^power:
    >= 0 on the sphere and a polynomial of degree `power` in the cosine, so 0 above band `power`."""
    x, w = np.polynomial.legendre.leggauss((power + order) // 2 + 1)  # exact for degree power + order
    kernel = ((1.0 + x) / 2.0) ** power
    p_prev, p, out = np.ones_like(x), x, [float(w @ kernel)]
    for l in range(1, order + 1):
        out.append(float(w @ (kernel * p)))
        p_prev, p = p, ((2 * l + 1) * x * p - l * p_prev) / (l + 1)
    return np.asarray(out) / out[0]


def colour_envelope(coeffs, height: int):
    """The light's colours as a positive average: (field [height, 2 height, 3] >= 0, bound).

    `field` is the SH light `coeffs` [n, 3] smoothed by ((1 + cos) / 2)^p at the texel centres of a
    2H x H map, p the highest power <= the light's order for which it is >= 0 on every texel of an
    ENVELOPE_HEIGHT-row map (a light >= 0 passes at its own order; an estimate whose high bands no
    light has falls back to lower powers, at worst p = 0, its mean colour). `bound` is its highest
    saturation where it is lit (at least LIT_FRACTION of its brightest), on that same grid whatever
    `height` is asked for."""
    L = sh.validate_coeffs(coeffs, "light")
    order = sh.order_from_num_coeffs(L.shape[0])
    band = np.repeat(np.arange(order + 1), 2 * np.arange(order + 1) + 1)
    dirs, _ = sh_projection.equirect_directions(ENVELOPE_HEIGHT, 2 * ENVELOPE_HEIGHT)
    basis = sh.sh_basis(dirs, order)
    for power in range(order, -1, -1):
        smoothed = L * _positive_kernel(power, order)[band][:, None]
        field = basis @ smoothed
        if field.min() >= -1e-12 * max(float(np.abs(field).max()), 1e-300):
            break
    field = np.maximum(field, 0.0)
    luminance = field @ LUMINANCE_WEIGHTS
    lit = (field.max(axis=-1) > 0) & (luminance >= LIT_FRACTION * luminance.max())
    bound = float(saturation(field[lit]).max()) if np.any(lit) else 0.0
    if int(height) != ENVELOPE_HEIGHT:
        dirs, _ = sh_projection.equirect_directions(int(height), 2 * int(height))
        field = np.maximum(sh.sh_basis(dirs, order) @ smoothed, 0.0)
    return field, bound


def _cone(bound: float):
    """Facet normals [9, 3] and extreme rays [6, 3] of K_bound (x >= 0 too: at bound 0 the pairs
    alone would let the grey ray through the origin into negative colours)."""
    k = 1.0 - bound
    facets = np.zeros((9, 3))
    for row, (i, j) in enumerate(PAIRS):
        facets[row, i], facets[row, j] = 1.0, -k
    facets[6:] = np.eye(3)
    rays = np.concatenate([np.where(np.eye(3) > 0, 1.0, k), np.where(np.eye(3) > 0, k, 1.0)])
    return facets, rays


def project_colours(values, bound: float, jacobian: bool = False):
    """The nearest colour in K_bound (Euclidean) of each RGB row of `values` [N, 3] (any sign), and
    with `jacobian` the projection's derivative [N, 3, 3] (piecewise constant: onto the face the
    colour lands on). The nearest of the candidates: the colour itself, its projections onto each
    facet's plane and each extreme ray, and 0, among those inside the cone (a colour already in the
    cone is its own; one with no positive channel goes to 0)."""
    v = np.asarray(values, np.float64)
    facets, rays = _cone(bound)
    tol = 1e-12 * max(float(np.abs(v).max(initial=0.0)), 1e-300)
    out = v.copy()
    derivative = np.broadcast_to(np.eye(3), v.shape + (3,)).copy() if jacobian else None
    outside = np.any(v @ facets.T < -tol, axis=-1)
    # a colour with no positive channel is in the polar cone (K lies in the positive octant): it goes to 0
    dark = outside & (v.max(axis=-1) <= 0)
    out[dark] = 0.0
    if jacobian:
        derivative[dark] = 0.0
    outside = np.flatnonzero(outside & ~dark)
    # candidates [N, 15, 3]: onto each extreme ray (t >= 0, else 0), onto each facet's plane (kept if inside)
    faces = np.concatenate([np.einsum("ri,rj->rij", rays, rays) / np.sum(rays * rays, axis=1)[:, None, None],
                            np.eye(3) - np.einsum("fi,fj->fij", facets, facets)
                            / np.sum(facets * facets, axis=1)[:, None, None], np.zeros((1, 3, 3))])
    for start in range(0, len(outside), CANDIDATE_ROWS):
        rows = outside[start:start + CANDIDATE_ROWS]
        w = v[rows]
        along = w @ rays.T
        on_rays = np.maximum(along, 0.0)[..., None] * rays / np.sum(rays * rays, axis=1)[:, None]
        on_facets = np.einsum("fij,nj->nfi", faces[6:15], w)
        candidates = np.concatenate([on_rays, on_facets, np.zeros((len(rows), 1, 3))], axis=1)
        distance = np.sum((w[:, None, :] - candidates) ** 2, axis=-1)
        distance[:, :6][along <= 0] = np.inf  # that ray's candidate is 0, the last one's
        distance[:, 6:15][np.any(on_facets @ facets.T < -tol, axis=-1)] = np.inf
        pick = np.argmin(distance, axis=1)
        out[rows] = candidates[np.arange(len(rows)), pick]
        if jacobian:
            derivative[rows] = faces[pick]
    if jacobian:
        return out, derivative
    return out


def bound_saturation(pixels, coeffs) -> np.ndarray:
    """The equirect map `pixels` [H, W, 3] >= 0 with no texel more saturated than the light
    `coeffs`' colour envelope allows: a texel above the bound is moved, at its own R + G + B,
    toward the envelope's colour in its direction just far enough (that colour is in the convex
    K_bound); float32, the others unchanged."""
    pixels = np.asarray(pixels)
    field, bound = colour_envelope(coeffs, pixels.shape[0])
    rgb = pixels.astype(np.float64)
    # moved at its own channel sum (keeping its luminance instead would take a blue texel's blue away:
    # blue is 7 % of the luminance)
    total = rgb.sum(axis=-1)
    target_total = field.sum(axis=-1)
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(total[..., None] > 0, rgb / total[..., None], 1.0)
        t = np.where(target_total[..., None] > 0, field / target_total[..., None], 1.0)
    # the field at this map's texels may be a little more saturated than on the bound's grid
    t = project_colours(t.reshape(-1, 3), bound).reshape(t.shape)
    t /= np.maximum(t.sum(axis=-1, keepdims=True), 1e-300)
    # each pair (i, j): x_i - (1 - bound) x_j >= 0, linear along x + alpha (t - x)
    alpha = np.zeros(total.shape)
    for i, j in PAIRS:
        start, end = x[..., i] - (1 - bound) * x[..., j], t[..., i] - (1 - bound) * t[..., j]
        with np.errstate(divide="ignore", invalid="ignore"):
            need = np.where(start < 0, -start / np.maximum(end - start, 1e-300), 0.0)
        alpha = np.maximum(alpha, np.minimum(need, 1.0))
    out = np.where((alpha > 0)[..., None], np.maximum(total[..., None] * (x + alpha[..., None] * (t - x)), 0.0), rgb)
    return out.astype(np.float32)


def chroma_spread(pixels) -> float:
    """How much the colour of a map varies: the RMS distance of its texels' rg-chromaticity
    (r, g) / (r + g + b) from their mean, weighted by luminance x solid angle (dark texels count
    little). 0 for a map of one colour; saturated stripes of several colours give ~0.2-0.4."""
    from relight.lighting.envmap import validate_equirect

    rgb = validate_equirect(pixels).pixels[..., :3].astype(np.float64)
    rgb = np.maximum(rgb, 0.0)
    height, width = rgb.shape[:2]
    _, omega = sh_projection.equirect_directions(height, width)
    total = rgb.sum(axis=-1)
    weight = (rgb @ LUMINANCE_WEIGHTS) * omega[:, None]
    keep = total > 0
    if not np.any(keep) or float(weight[keep].sum()) <= 0:
        return 0.0
    rg = rgb[keep][:, :2] / total[keep][:, None]
    w = weight[keep] / float(weight[keep].sum())
    mean = w @ rg
    return float(math.sqrt(float(w @ np.sum((rg - mean) ** 2, axis=1))))
