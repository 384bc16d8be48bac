"""Colour: linear Rec.709 <-> sRGB transfer (IEC 61966-2-1), luminance, and the one decoder of
8- and 16-bit sRGB code values (photo files in the CLI, Blender's byte images in the add-on)."""

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


# code value -> linear, one table per bit depth, computed in float64 and stored as float32: the
# one decoder of stored sRGB codes, so `relight image` and the add-on read a PNG to the same floats
_DECODE_TABLES: dict[int, np.ndarray] = {}
DECODE_STRIP_ROWS = 256  # rows looked up at a time: bounds the gather's temporaries on huge photos


def _decode_table(dtype) -> np.ndarray:
    levels = {np.dtype(np.uint8): 256, np.dtype(np.uint16): 65536}.get(np.dtype(dtype))
    if levels is None:
        raise ValueError(f"sRGB code values must be uint8 or uint16, got dtype {np.dtype(dtype)}")
    table = _DECODE_TABLES.get(levels)
    if table is None:  # a benign race: two threads may both build the same table
        table = srgb_decode(np.arange(levels, dtype=np.float64) / (levels - 1)).astype(np.float32)
        table.flags.writeable = False
        _DECODE_TABLES[levels] = table
    return table


def decode_srgb_codes(codes: np.ndarray) -> np.ndarray:
    """Linear float32 values of stored sRGB code values (uint8 or uint16, any shape)."""
    codes = np.asarray(codes)
    table = _decode_table(codes.dtype)
    if codes.ndim < 2:
        return table[codes]
    out = np.empty(codes.shape, np.float32)
    for r0 in range(0, codes.shape[0], DECODE_STRIP_ROWS):
        out[r0:r0 + DECODE_STRIP_ROWS] = table[codes[r0:r0 + DECODE_STRIP_ROWS]]
    return out


def decode_alpha_codes(codes: np.ndarray) -> np.ndarray:
    """Coverage in [0, 1], float32, of stored alpha code values (uint8 or uint16; alpha is linear)."""
    codes = np.asarray(codes)
    _decode_table(codes.dtype)  # the same dtypes as colour
    return codes.astype(np.float32) / np.float32(np.iinfo(codes.dtype).max)
