"""The person's own colour along the matte's soft edge.

An edge pixel of the photo mixes the person and what is behind: I = a F + (1 - a) B. The
albedo layer divides the photo by the shading, so there it carried the old background into
every composite an artist made with it (a fringe of the photo's background over the new one).
The estimate here is a blur-fusion of the kind of Forte and Pitie (2021): smooth local colours
of the person F~ and of the background B~, each the alpha-weighted mean of the photo around the
pixel, then per pixel F = F~ + a (I - a F~ - (1 - a) B~), which moves F~ by the part of the
pixel that the two smooth colours do not explain. It is exact for a pixel whose true colours
are the local means, returns I where a = 1, and needs only smooth maps: they are computed at
the decomposition's working resolution and upsampled, and the last step runs per full-size strip.
"""

from __future__ import annotations

import numpy as np

from relight.person.mask_ops import box_mean

__all__ = ["smooth_colours", "foreground", "RADIUS"]

# working-resolution pixels: the window over which the person's and the background's local
# colours are averaged (a 128 px person: 7 px is a hand's width). Edge error on the held-out
# scenes (benchmarks/bench_edge_colour.py at 619862d) for radius 1 / 2 / 3 / 4 / 6: 0.154 / 0.134 / 0.129 /
# 0.128 / 0.128, against 0.224 for the photo itself
RADIUS = 3
WEIGHT_FLOOR = 1e-3  # the pixel's own weight in its window's means (see smooth_colours)


def smooth_colours(image: np.ndarray, alpha: np.ndarray, radius: int = RADIUS) -> np.ndarray:
    """[h, w, 6]: the person's (alpha-weighted) and the background's ((1 - alpha)-weighted) mean
    colour over (2 radius + 1)^2 windows of `image` [h, w, 3] with matte `alpha` [h, w]. Where a
    window holds (almost) none of a side, that side's colour fades to the pixel's own: the mean
    is taken with the pixel itself at weight WEIGHT_FLOOR (continuous in the inputs, so float
    rounding moves it by rounding only)."""
    image = np.asarray(image, np.float32)
    a = np.clip(np.asarray(alpha, np.float32), 0.0, 1.0)
    out = np.empty((*a.shape, 6), np.float32)
    floor = np.float32(WEIGHT_FLOOR)
    for k, w in enumerate((a, 1.0 - a)):
        total = box_mean(w, radius) + floor
        for c in range(3):
            out[..., 3 * k + c] = (box_mean(w * image[..., c], radius) + floor * image[..., c]) / total
    return out


def foreground(image: np.ndarray, alpha: np.ndarray, smooth: np.ndarray) -> np.ndarray:
    """The person's colour F [..., 3] of `image` [..., 3] with matte `alpha` [..., 1] and the
    smooth colours [..., 6] of smooth_colours (upsampled to the image's size): F~ + a (I - a F~ -
    (1 - a) B~), clipped at 0; exactly I where a = 1. A new array."""
    f, b = smooth[..., :3], smooth[..., 3:]
    residual = image - alpha * f - (1.0 - alpha) * b
    out = f + alpha * residual
    np.maximum(out, 0.0, out=out)
    full = alpha[..., 0] >= 1.0
    out[full] = image[full]  # exact where the pixel is all person (the formula is, up to rounding)
    return out
