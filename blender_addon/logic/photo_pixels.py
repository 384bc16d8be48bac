"""A photo's pixels as the add-on reads them: a file through the core's reader
(relight.files.photo.read_photo_with_header, as `relight image` reads it: its header read once, EXIF
orientation, 8 and 16 bits, EXR, its size limits; their refusals worded here), Blender's image buffers decoded to linear float32 by the core's one sRGB decoder
(relight.imaging.colour.decode_srgb_codes), both upright, with the file's EXIF orientation to turn results
back to the pixels Blender shows, and a digest of the upright linear values. Plain Python."""

from __future__ import annotations

import hashlib
import os
from dataclasses import dataclass

import numpy as np

from . import pixel_buffers
from .messages import first_line


@dataclass
class PhotoPixels:
    """A photo as the add-on works on it."""

    rgb: np.ndarray             # linear RGB [H, W, 3] float32, upright, top row first
    alpha: np.ndarray | None    # [H, W] in [0, 1] (upright), or None when the image has no alpha
    digest: str                 # hash of the upright linear values: the key of a saved decomposition
    orientation: int = 1        # the file's EXIF orientation: Blender shows pixel_buffers.as_stored(rgb, it)


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        h.update(repr(a.shape).encode())
        h.update(np.ascontiguousarray(a).data)  # hashlib releases the GIL on large buffers
    return h.hexdigest()


def _pixels(rgb: np.ndarray, alpha: np.ndarray | None, orientation: int,
            reuse: PhotoPixels | None) -> PhotoPixels:
    # the digest covers the colour only, so it does not depend on how the alpha was read
    # (Blender gives every byte image four channels); the same pixels as the photo's last
    # decoding (Relight again) share its linear copy, not hold two (288 MB at 24 MP)
    digest = _digest(rgb)
    if reuse is not None and reuse.digest == digest and reuse.rgb.shape == rgb.shape:
        rgb = reuse.rgb
    return PhotoPixels(rgb, alpha, digest, orientation)


def read_file(path: str, shape: tuple[int, int] | None, with_alpha: bool, name: str,
              reuse: PhotoPixels | None = None, max_megapixels: int | None = None) -> PhotoPixels:
    """Read a photo file upright through the core's reader (worker thread), as `relight image` does,
    its header read once (relight.files.photo_header: size, orientation) and its refusals worded here.

    `shape` is (H, W) as Blender loaded it (stored, not turned), or None when Blender has not
    loaded the image. `with_alpha`: keep the file's alpha. `reuse`: the photo as decoded before,
    shared when its pixels are the same. `max_megapixels`: the panel's Max Photo Size, weighed
    against the file's header first."""
    from relight.files.image_limits import ImageSizeError
    from relight.files.photo import read_photo_with_header
    from relight.files.photo_header import ImageNotFound, NotAnImage

    from .photo_checks import DEFAULT_MEGAPIXELS, size_limits, size_refused

    megapixels = DEFAULT_MEGAPIXELS if max_megapixels is None else max_megapixels
    try:
        rgb, alpha, header = read_photo_with_header(path, **size_limits(megapixels))
    except ImageSizeError as exc:
        raise size_refused(exc, name, megapixels) from None
    except ImageNotFound:
        raise ValueError(f"The photo file of '{name}' is missing.") from None
    except NotAnImage:
        raise ValueError(f"'{name}' is not an image Blender can read ({os.path.basename(path)}).") from None
    except (ValueError, OSError) as exc:
        raise ValueError(f"The photo file of '{name}' cannot be read ({first_line(exc)}).") from None
    if shape is not None and pixel_buffers.stored_size(rgb.shape[:2], header.orientation) != tuple(shape):
        raise ValueError(f"The photo file of '{name}' changed on disk since Blender loaded it: "
                         "reload the image (Image > Reload) and relight.")
    return _pixels(rgb, alpha if with_alpha else None, header.orientation, reuse)


def photo_from_blender(flat: np.ndarray, shape: tuple[int, int, int], *, srgb: bool, with_alpha: bool,
                       name: str, reuse: PhotoPixels | None = None, orientation: int = 1) -> PhotoPixels:
    """Pixels copied out of Blender (flat, bottom row first, `shape` = (H, W, C)) as a PhotoPixels,
    turned upright by `orientation` (the EXIF orientation of the image's file; 1 for none).

    8-bit sRGB images hold code / 255: the codes are recovered exactly and
    decoded by table; float images are taken as scene-linear.
    """
    from relight.imaging.colour import decode_alpha_codes, decode_srgb_codes  # the CLI's decoder: the same floats

    h, w, c = shape
    px = pixel_buffers.upright(flat.reshape(h, w, c)[::-1], orientation)
    rgb = px[..., :3] if c >= 3 else np.repeat(px[..., :1], 3, axis=2)
    alpha = px[..., 3] if c == 4 and with_alpha else None
    if srgb:
        codes = np.rint(np.clip(rgb, 0.0, 1.0) * np.float32(255.0)).astype(np.uint8)
        alpha_codes = None if alpha is None else np.rint(np.clip(alpha, 0.0, 1.0) * 255.0).astype(np.uint8)
        return _pixels(decode_srgb_codes(codes), None if alpha_codes is None else decode_alpha_codes(alpha_codes),
                       orientation, reuse)
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if not np.all(np.isfinite(rgb)):
        raise ValueError(f"The image '{name}' contains NaN or infinite pixels.")
    alpha = None if alpha is None else np.ascontiguousarray(alpha)
    return _pixels(rgb, alpha, orientation, reuse)
