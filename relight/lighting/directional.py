"""The directional part of a light: the lamp whose cast shadows a relight draws, or None.

A light's key (relight.lighting.key_light.fit_key: a cone of light, its direction, colour, strength and
width) casts a shadow worth drawing when it is narrow enough for the shadow to have an edge and bright
enough to matter: it gives a surface facing it at least MIN_KEY_SHARE of that surface's SH
irradiance, and its cone is at most MAX_HALF_ANGLE_DEG wide. A sky, a studio softbox or an overcast
map has none: no shadow pass runs for them (model only what the light requires). numpy only.
"""

from __future__ import annotations

import math

import numpy as np

from relight.imaging.colour import LUMINANCE_WEIGHTS
from relight.lighting import sh
from relight.lighting.key_light import KeyLight, cone_profile, fit_key

__all__ = ["MAX_HALF_ANGLE_DEG", "MIN_KEY_SHARE", "directional_part", "key_share"]

MIN_KEY_SHARE = 0.25       # of the facing surface's irradiance: below it the key's shadow is a faint tint
MAX_HALF_ANGLE_DEG = 30.0  # a wider key's penumbra spans most of the person: no edge left to draw


def key_share(key: KeyLight, coeffs: np.ndarray) -> float:
    """The share of a surface facing the key whose (luminance) SH irradiance comes from the key."""
    order = sh.order_from_num_coeffs(coeffs.shape[0])
    a = sh.clamped_cosine_coeffs(order)
    basis = sh.sh_basis(np.asarray(key.direction, np.float64), order)
    per_band = np.repeat(a, [2 * l + 1 for l in range(order + 1)])
    total = float((per_band * basis) @ coeffs @ LUMINANCE_WEIGHTS)
    facing = float(key.rgb @ LUMINANCE_WEIGHTS) * float(cone_profile(key.half_angle, 1)[1])
    return facing / total if total > 0 else 0.0


def directional_part(coeffs) -> KeyLight | None:
    """The key of the SH light `coeffs` [n, 3] (order >= 1) when it casts a shadow worth drawing
    (the module docstring's rule), else None."""
    L = sh.validate_coeffs(coeffs, "light")
    if L.shape[0] < 4:
        return None
    key = fit_key(L)
    if key.strength <= 0 or key.half_angle > math.radians(MAX_HALF_ANGLE_DEG):
        return None
    return key if key_share(key, L) >= MIN_KEY_SHARE else None
