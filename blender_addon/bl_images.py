"""bpy image datablocks <-> numpy arrays (top row first), looked up by name.

Blender stores pixels bottom row first, RGBA float. Byte images hold their
encoded values (/255); float images hold scene-linear values.
"""

from __future__ import annotations

import bpy
import numpy as np

from relight.colour import srgb_decode

LINEAR = "Linear Rec.709"
NON_COLOR = "Non-Color"
_SRGB_NAMES = {"sRGB", "sRGB 2.2"}  # Blender names for the sRGB transfer


def rgba_pixels(image: bpy.types.Image) -> np.ndarray:
    """The image's pixels as float32 [H, W, C] (C = image.channels), top row first."""
    if not image.has_data:
        _load(image)
    width, height = image.size
    if width == 0 or height == 0 or not image.has_data:
        raise ValueError(f"The image '{image.name}' has no pixels: is its file missing?")
    channels = image.channels
    flat = np.empty(width * height * channels, dtype=np.float32)
    image.pixels.foreach_get(flat)
    return flat.reshape(height, width, channels)[::-1].copy()


def _load(image: bpy.types.Image) -> None:
    """Ask Blender to read the file behind `image` (a failure shows as no pixels)."""
    try:
        if image.source == "FILE":
            image.reload()
        image.pixels[0:1]  # touching the pixels loads the buffer
    except (RuntimeError, IndexError):
        pass


def linear_rgb_and_alpha(image: bpy.types.Image) -> tuple[np.ndarray, np.ndarray | None]:
    """(linear RGB [H, W, 3] float32, alpha [H, W] or None when the image has no alpha)."""
    px = rgba_pixels(image)
    if px.shape[2] == 1:
        rgb = np.repeat(px, 3, axis=2)
    else:
        rgb = px[..., :3]
    if not image.is_float and image.colorspace_settings.name in _SRGB_NAMES:
        rgb = srgb_decode(rgb).astype(np.float32)
    alpha = px[..., 3] if px.shape[2] == 4 and image.alpha_mode != "NONE" else None
    if not np.all(np.isfinite(rgb)):
        raise ValueError(f"The image '{image.name}' contains NaN or infinite pixels.")
    return np.ascontiguousarray(rgb), alpha


def write_image(name: str, pixels: np.ndarray, *, colorspace: str = LINEAR) -> bpy.types.Image:
    """Create or overwrite float image `name` with pixels [H, W] or [H, W, 1|3|4] (top row first)."""
    px = np.asarray(pixels, dtype=np.float32)
    if px.ndim == 2:
        px = px[..., None]
    height, width, channels = px.shape
    # one strided copy into Blender's layout: RGBA, bottom row first
    rgba = np.ones((height, width, 4), dtype=np.float32)
    rgba[..., :3] = px[::-1, :, :3] if channels >= 3 else px[::-1, :, :1]
    if channels == 4:
        rgba[..., 3] = px[::-1, :, 3]
    image = bpy.data.images.get(name)
    if image is not None and (tuple(image.size) != (width, height) or not image.is_float):
        bpy.data.images.remove(image)
        image = None
    if image is None:
        image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
    image.colorspace_settings.name = colorspace
    image.pixels.foreach_set(rgba.ravel())
    image.update()
    return image
