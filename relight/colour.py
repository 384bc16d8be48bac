"""Colour: linear Rec.709 <-> sRGB transfer (IEC 61966-2-1) and luminance."""

from __future__ import annotations

import numpy as np

# Rec.709 / sRGB primaries, D65: Y = 0.2126 R + 0.7152 G + 0.0722 B
LUMINANCE_WEIGHTS = np.array([0.2126, 0.7152, 0.0722])
LUMINANCE_WEIGHTS.flags.writeable = False

# The piecewise sRGB curve, the one definition (model/ has its torch twins): a linear
# segment of slope SRGB_SLOPE below the knees, encoded = SRGB_SCALE * linear^(1/SRGB_GAMMA)
# - SRGB_OFFSET above.
SRGB_LINEAR_KNEE = 0.0031308
SRGB_ENCODED_KNEE = 0.04045
SRGB_SLOPE = 12.92
SRGB_GAMMA = 2.4
SRGB_OFFSET = 0.055
SRGB_SCALE = 1.0 + SRGB_OFFSET


def _as_float(x, name: str) -> np.ndarray:
    a = np.asarray(x)
    if not (np.issubdtype(a.dtype, np.floating) or np.issubdtype(a.dtype, np.integer)):
        raise ValueError(f"{name} must be numeric, got dtype {a.dtype}")
    if not np.issubdtype(a.dtype, np.floating):
        a = a.astype(np.float64)
    return a


def srgb_encode(linear) -> np.ndarray:
    """Linear [0, 1] -> sRGB-encoded [0, 1]; values are clipped to [0, 1] first."""
    a = _as_float(linear, "linear image")
    x = np.clip(a, 0.0, 1.0).astype(a.dtype, copy=False)
    low = x * SRGB_SLOPE
    high = SRGB_SCALE * np.power(np.maximum(x, SRGB_LINEAR_KNEE), 1.0 / SRGB_GAMMA) - SRGB_OFFSET
    return np.where(x <= SRGB_LINEAR_KNEE, low, high).astype(x.dtype, copy=False)


def srgb_decode(encoded) -> np.ndarray:
    """sRGB-encoded [0, 1] -> linear [0, 1]; values are clipped to [0, 1] first."""
    a = _as_float(encoded, "sRGB image")
    x = np.clip(a, 0.0, 1.0).astype(a.dtype, copy=False)
    low = x / SRGB_SLOPE
    high = np.power((np.maximum(x, SRGB_ENCODED_KNEE) + SRGB_OFFSET) / SRGB_SCALE, SRGB_GAMMA)
    return np.where(x <= SRGB_ENCODED_KNEE, low, high).astype(x.dtype, copy=False)


def luminance(rgb) -> np.ndarray:
    """Rec.709 luminance Y of linear RGB [..., 3] -> [...]."""
    a = _as_float(rgb, "RGB image")
    if a.ndim < 1 or a.shape[-1] != 3:
        raise ValueError(f"RGB input must have shape [..., 3], got {a.shape}")
    return a @ LUMINANCE_WEIGHTS.astype(a.dtype)
