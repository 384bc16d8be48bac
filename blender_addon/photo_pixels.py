"""A photo's pixels as the add-on reads them: 8-bit files and Blender's image buffers decoded
to linear float32 by the core's one sRGB decoder (relight.colour.decode_srgb_codes, so the add-on
and `relight image` read a PNG to the same floats), with a digest of the stored values. Plain Python."""

from __future__ import annotations

import hashlib
import os
import warnings
from dataclasses import dataclass

import numpy as np

from .jobs import first_line


@dataclass
class PhotoPixels:
    """A photo as the add-on works on it."""

    rgb: np.ndarray             # linear RGB [H, W, 3] float32, top row first
    alpha: np.ndarray | None    # [H, W] in [0, 1], or None when the image has no alpha
    digest: str                 # hash of the stored pixel values: the key of a saved decomposition


def _digest(*arrays: np.ndarray) -> str:
    h = hashlib.blake2b(digest_size=16)
    for a in arrays:
        h.update(repr(a.shape).encode())
        h.update(np.ascontiguousarray(a).data)  # hashlib releases the GIL on large buffers
    return h.hexdigest()


def _from_codes(codes: np.ndarray, alpha_codes: np.ndarray | None,
                reuse: PhotoPixels | None = None) -> PhotoPixels:
    # the digest covers the colour codes only, so it does not depend on how the
    # alpha was read (Blender gives every byte image four channels)
    from relight.colour import decode_alpha_codes, decode_srgb_codes  # the CLI's decoder: the same floats

    digest = _digest(codes)
    # the same pixels as the photo's last decoding (Relight again): its linear copy is shared,
    # not made twice (288 MB at 24 MP)
    rgb = reuse.rgb if reuse is not None and reuse.digest == digest else decode_srgb_codes(codes)
    alpha = None if alpha_codes is None else decode_alpha_codes(alpha_codes)
    return PhotoPixels(rgb, alpha, digest)


_8BIT_MODES = {"1", "L", "LA", "P", "PA", "RGB", "RGBA", "RGBX", "CMYK", "YCbCr"}
_ALPHA_MODES = {"LA", "PA", "RGBA"}


def read_8bit_file(path: str, shape: tuple[int, int] | None, with_alpha: bool, name: str,
                   reuse: PhotoPixels | None = None, max_megapixels: int | None = None) -> PhotoPixels:
    """Decode an 8-bit sRGB photo file (worker thread).

    `shape` is (H, W) as Blender loaded it, or None when Blender has not
    loaded the image (then the file's own mode says whether it is 8-bit and
    has alpha). `reuse`: the photo as decoded before, shared when its pixels are the same.
    `max_megapixels`: the panel's Max Photo Size, weighed against the file's header first."""
    from PIL import Image, UnidentifiedImageError

    from .photo_checks import DEFAULT_MEGAPIXELS, check_photo_file

    check_photo_file(path, name, DEFAULT_MEGAPIXELS if max_megapixels is None else max_megapixels)
    try:
        with warnings.catch_warnings(), Image.open(path) as im:
            warnings.simplefilter("ignore")  # Pillow's bomb warning: the size was weighed just above
            if shape is None:
                if im.mode not in _8BIT_MODES:
                    raise ValueError(f"'{name}' has more than 8 bits per channel: show it in the Image Editor, "
                                     "then press Relight.")
                with_alpha = with_alpha and (im.mode in _ALPHA_MODES or "transparency" in im.info)
            im = im.convert("RGBA" if with_alpha else "RGB")
            codes = np.asarray(im)
    except UnidentifiedImageError:
        raise ValueError(f"'{name}' is not an image Blender can read ({os.path.basename(path)}).") from None
    except OSError as exc:
        raise ValueError(f"The photo file of '{name}' cannot be read ({first_line(exc)}).") from None
    if shape is not None and codes.shape[:2] != tuple(shape):
        raise ValueError(f"The photo file of '{name}' changed on disk since Blender loaded it: "
                         "reload the image (Image > Reload) and relight.")
    if with_alpha:
        return _from_codes(np.ascontiguousarray(codes[..., :3]), np.ascontiguousarray(codes[..., 3]), reuse)
    return _from_codes(codes, None, reuse)


def photo_from_blender(flat: np.ndarray, shape: tuple[int, int, int], *, srgb: bool, with_alpha: bool,
                       name: str, reuse: PhotoPixels | None = None) -> PhotoPixels:
    """Pixels copied out of Blender (flat, bottom row first, `shape` = (H, W, C)) as a PhotoPixels.

    8-bit sRGB images hold code / 255: the codes are recovered exactly and
    decoded by table; float images are taken as scene-linear.
    """
    h, w, c = shape
    px = flat.reshape(h, w, c)[::-1]
    rgb = px[..., :3] if c >= 3 else np.repeat(px[..., :1], 3, axis=2)
    alpha = px[..., 3] if c == 4 and with_alpha else None
    if srgb:
        codes = np.rint(np.clip(rgb, 0.0, 1.0) * np.float32(255.0)).astype(np.uint8)
        alpha_codes = None if alpha is None else np.rint(np.clip(alpha, 0.0, 1.0) * 255.0).astype(np.uint8)
        return _from_codes(codes, alpha_codes, reuse)
    rgb = np.ascontiguousarray(rgb, dtype=np.float32)
    if not np.all(np.isfinite(rgb)):
        raise ValueError(f"The image '{name}' contains NaN or infinite pixels.")
    alpha = None if alpha is None else np.ascontiguousarray(alpha)
    return PhotoPixels(rgb, alpha, _digest(rgb))
