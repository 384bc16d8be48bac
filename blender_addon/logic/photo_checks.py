"""Is there a person to relight? A photo too small, too large, black, blown out or one flat
colour is refused, in the artist's words, before the network runs (a size before anything
decodes the pixels). Plain Python."""

from __future__ import annotations

import math
import os
import re

import numpy as np

from relight.files import image_limits
from relight.imaging.colour import LUMINANCE_WEIGHTS

MIN_PHOTO_SIDE = 32      # pixels: below this on either side a photo cannot show a person
BLACK_LEVEL = 3e-3       # linear luminance (sRGB code ~11/255): a photo whose brightest pixel is below is black
WHITE_LEVEL = 0.98       # a photo whose darkest channel value everywhere is above this is blown out
FLAT_SPREAD = 0.02       # luminance spread (1st to 99th percentile) below this fraction of its level: one colour
CHECK_SAMPLES = 1 << 18  # pixels looked at by check_photo_content (a regular subsample)


def check_photo_size(width: int, height: int) -> None:
    """ValueError in the artist's words when the photo is too small to show a person."""
    if min(width, height) < MIN_PHOTO_SIDE:
        raise ValueError(f"The photo is only {width} x {height} pixels, too small to show a person: "
                         f"use a photo at least {MIN_PHOTO_SIDE} pixels on each side.")


EXR_MAGIC = b"\x76\x2f\x31\x01"  # relight.files.photo's: an OpenEXR file's first four bytes
DEFAULT_MEGAPIXELS = image_limits.DEFAULT_MAX_PIXELS // 1_000_000  # the panel's Max Photo Size
MOST_MEGAPIXELS = image_limits.MAX_PIXELS // 1_000_000
GB_PER_MEGAPIXEL = 0.16  # Relight + Save Layers of a 24 MP photo: 3.4 GB, the whole UI flow more (docs/benchmarks/addon.md)


def check_photo_pixels(width: int, height: int, name: str, max_megapixels: int = DEFAULT_MEGAPIXELS,
                       file_bytes: int | None = None, fmt: str | None = None) -> None:
    """ValueError in the artist's words when a photo of this size (as its header declares it)
    must not be decoded: the core's limits (relight.files.image_limits), with what allows it.
    `max_megapixels` is the panel's Max Photo Size; set above its default it also lets a header
    that claims more pixels than its file can hold (as `--max-pixels` does for `relight image`)."""
    pixels = width * height
    mp = pixels / 1e6
    said = f"'{name}' is {width} x {height} pixels ({mp:.3g} MP)"
    if width > image_limits.MAX_SIDE or height > image_limits.MAX_SIDE or pixels > image_limits.MAX_PIXELS:
        raise _too_large(said)
    if pixels > max_megapixels * 1_000_000:
        need = math.ceil(mp)
        raise ValueError(f"{said}, over Max Photo Size ({max_megapixels} MP): to relight it, raise Max Photo "
                         f"Size in the panel to {need} MP (it will need about {need * GB_PER_MEGAPIXEL:.0f} GB "
                         "of memory), or scale the photo down.")
    explicit = max_megapixels > DEFAULT_MEGAPIXELS
    if not explicit and file_bytes is not None and pixels > image_limits.PLAUSIBLE_FROM:
        per_byte = image_limits.MAX_PIXELS_PER_BYTE.get(fmt or "", image_limits.MAX_PIXELS_PER_BYTE_OTHER)
        if pixels > file_bytes * per_byte:
            raise ValueError(f"'{name}' claims {width} x {height} pixels ({mp:.3g} MP) in a file of "
                             f"{file_bytes:,} bytes, more than such a file can hold: it is damaged or forged. "
                             f"Open another photo (or, if it is whole, set Max Photo Size above "
                             f"{DEFAULT_MEGAPIXELS} MP to decode it anyway).")
    free = image_limits.memory_available()
    need = pixels * image_limits.BYTES_PER_PIXEL
    if free is not None and need > free:
        raise ValueError(f"{said} needs about {need / 2**30:.1f} GB of memory to read, and only "
                         f"{free / 2**30:.1f} GB is free: close other programs or scale the photo down.")


def _too_large(said: str) -> ValueError:
    return ValueError(f"{said}: too large to relight (at most {MOST_MEGAPIXELS} MP and "
                      f"{image_limits.MAX_SIDE:,} pixels a side). Scale it down in an image editor and open "
                      "the smaller copy.")


def check_photo_file(path: str, name: str, max_megapixels: int = DEFAULT_MEGAPIXELS) -> None:
    """check_photo_pixels on the size a photo file's header declares, before anything decodes
    it (Blender would decode a forged 20000 x 20000 JPEG into 1.6 GB, Pillow refuses it with an
    error of its own). A file Pillow cannot read is left to the decoder's own message."""
    import warnings

    from PIL import Image

    with open(path, "rb") as f:
        magic = f.read(4)
    if magic == EXR_MAGIC:  # Pillow does not read EXR: its header says the size as cheaply
        from relight.files.exr import exr_size

        try:
            width, height = exr_size(path)
        except ValueError:
            return  # a damaged EXR: Blender's loading says so
        check_photo_pixels(width, height, name, max_megapixels, os.path.getsize(path), "EXR")
        return
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # Pillow's DecompressionBombWarning: weighed here instead
            with Image.open(path) as im:
                (width, height), fmt = im.size, im.format
    except Image.DecompressionBombError as exc:  # over twice Pillow's own limit, so over ours too
        said = re.search(r"\((\d+) pixels\)", str(exc))  # Pillow names the pixel count, not the sides
        pixels = int(said.group(1)) if said else 2 * Image.MAX_IMAGE_PIXELS
        raise _too_large(f"'{name}' is {'' if said else 'over '}{pixels / 1e6:.3g} MP") from None
    except Exception as exc:  # not an image Pillow knows (or unreadable): the decoder will say
        if isinstance(exc, MemoryError):
            raise
        return
    check_photo_pixels(width, height, name, max_megapixels, os.path.getsize(path), fmt)


def check_photo_content(photo: np.ndarray) -> None:
    """ValueError when the photo cannot hold a visible person: black, blown-out white, or one flat colour.

    The network would still return layers for such a photo, relit from nothing,
    which would look like a result; these are caught first. A regular subsample
    of about CHECK_SAMPLES pixels is enough for levels and percentiles.
    """
    h, w = photo.shape[:2]
    check_photo_size(w, h)
    step = max(1, int(np.sqrt(h * w / CHECK_SAMPLES)))
    sample = np.asarray(photo[::step, ::step, :3], dtype=np.float32).reshape(-1, 3)
    luminance = sample @ LUMINANCE_WEIGHTS.astype(np.float32)
    if float(luminance.max()) < BLACK_LEVEL:
        raise ValueError("The photo is black: there is no person to see in it. "
                         "Check the photo's exposure, or open another photo.")
    if float(sample.min()) > WHITE_LEVEL:
        raise ValueError("The photo is white (blown out): there is no person to see in it. Open another photo.")
    low, high = np.percentile(luminance, [1.0, 99.0])
    if high - low < FLAT_SPREAD * max(float(high), BLACK_LEVEL):
        raise ValueError("The photo is one flat colour: there is no person to relight in it. Open another photo.")
