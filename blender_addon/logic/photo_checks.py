"""Is there a person to relight? A photo too small, too large, black, blown out or one flat
colour is refused, in the artist's words, before the network runs (a size before anything
decodes the pixels). The size limits are the core's (relight.files.image_limits; the header
read by relight.files.photo_header): this module only words their refusals. Plain Python."""

from __future__ import annotations

import math

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


DEFAULT_MEGAPIXELS = image_limits.DEFAULT_MAX_PIXELS // 1_000_000  # the panel's Max Photo Size
MOST_MEGAPIXELS = image_limits.MAX_PIXELS // 1_000_000
GB_PER_MEGAPIXEL = 0.16  # Relight + Save Layers of a 24 MP photo: 3.4 GB, the whole UI flow more (docs/benchmarks/addon.md)


def size_limits(max_megapixels: int) -> dict:
    """The core's size check's arguments for the panel's Max Photo Size: its pixels, and, at or
    below its default, the file's length weighed (set above, it also lets a header that claims more
    pixels than its file can hold, as `--max-pixels` does for `relight image`)."""
    return {"max_pixels": min(image_limits.MAX_PIXELS, int(max_megapixels) * 1_000_000),
            "weigh_file_size": max_megapixels <= DEFAULT_MEGAPIXELS}


def size_refused(exc: image_limits.ImageSizeError, name: str, max_megapixels: int) -> ValueError:
    """The core's refusal of a photo's size (relight.files.image_limits.check_declared_size) in the
    artist's words, with what allows it."""
    width, height, pixels = exc.width, exc.height, exc.pixels
    if width is None:  # Pillow's own bomb check spoke: the pixel count alone is known
        return _too_large(f"'{name}' is {'over ' if pixels is None else ''}"
                          f"{(pixels or image_limits.MAX_PIXELS) / 1e6:.3g} MP")
    mp = pixels / 1e6
    said = f"'{name}' is {width} x {height} pixels ({mp:.3g} MP)"
    if exc.limit == "side" or exc.limit == "pixels" and pixels > image_limits.MAX_PIXELS:
        return _too_large(said)
    if exc.limit == "pixels":
        need = math.ceil(mp)
        return ValueError(f"{said}, over Max Photo Size ({max_megapixels} MP): to relight it, raise Max Photo "
                          f"Size in the panel to {need} MP (it will need about {need * GB_PER_MEGAPIXEL:.0f} GB "
                          "of memory), or scale the photo down.")
    if exc.limit == "file":
        return ValueError(f"'{name}' claims {width} x {height} pixels ({mp:.3g} MP) in a file of "
                          f"{exc.file_bytes:,} bytes, more than such a file can hold: it is damaged or forged. "
                          f"Open another photo (or, if it is whole, set Max Photo Size above "
                          f"{DEFAULT_MEGAPIXELS} MP to decode it anyway).")
    if exc.limit == "memory":
        return ValueError(f"{said} needs about {exc.need_bytes / 2**30:.1f} GB of memory to read, and only "
                          f"{exc.free_bytes / 2**30:.1f} GB is free: close other programs or scale the photo down.")
    return ValueError(f"'{name}' is {width} x {height} pixels: it holds no image.")


def check_photo_pixels(width: int, height: int, name: str, max_megapixels: int = DEFAULT_MEGAPIXELS) -> None:
    """ValueError in the artist's words when a photo of this size (as Blender holds it) must not be
    decoded: the core's limits (relight.files.image_limits), with what allows it."""
    try:
        image_limits.check_declared_size(width, height, name, **size_limits(max_megapixels))
    except image_limits.ImageSizeError as exc:
        raise size_refused(exc, name, max_megapixels) from None


def _too_large(said: str) -> ValueError:
    return ValueError(f"{said}: too large to relight (at most {MOST_MEGAPIXELS} MP and "
                      f"{image_limits.MAX_SIDE:,} pixels a side). Scale it down in an image editor and open "
                      "the smaller copy.")


def check_photo_file(path: str, name: str, max_megapixels: int = DEFAULT_MEGAPIXELS):
    """The photo file's header (relight.files.photo_header.PhotoHeader) once its size passed the
    core's limits, before anything decodes it (Blender would decode a forged 20000 x 20000 JPEG
    into 1.6 GB); ValueError in the artist's words when it did not. None for a file the header
    reader refuses for another cause: Blender's loading or the decoder says what is wrong."""
    from relight.files.photo_header import read_header

    try:
        return read_header(path, **size_limits(max_megapixels))
    except image_limits.ImageSizeError as exc:
        raise size_refused(exc, name, max_megapixels) from None
    except image_limits.ImageFileError:
        return None


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
