"""Is there a person to relight? A photo too small, black, blown out or one flat colour is
refused, in the artist's words, before the network runs. Plain Python."""

from __future__ import annotations

import numpy as np

from relight.colour import LUMINANCE_WEIGHTS

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
