"""Resampling of float images: the area/bilinear resizer and the one bilinear upsampler.

`resize_linear` (Pillow) brings a photo to the network's working size and back
down for the person matte: box (area) filter when shrinking, bilinear when
enlarging; `resize_longest` is it for a crop brought to a working size (its longest side). `Bilinear` upsamples small maps (the relit person, the matte) to the
photo's resolution with half-pixel centres and clamped edges; every caller
(the compositor's tiles, the layers' strips, the person matte) goes through its
`columns` and `between`, so they give the same values bit for bit. For the person
matte: `area_shrink` (block means), `upsample_support` (Bilinear over a matte's
non-zero part only) and `sample_points` (bilinear samples at arbitrary points).
"""

from __future__ import annotations

import numpy as np

__all__ = ["Bilinear", "SourceRows", "area_shrink", "axis_taps", "bilinear_rows", "fit_longest", "resize_linear",
           "resize_longest", "sample_points", "upsample_support"]


def axis_taps(n_out: int, n_in: int):
    """Bilinear taps (half-pixel centres, clamped edges): i0, i1 [n_out] and weight of i1."""
    s = (np.arange(n_out, dtype=np.float64) + 0.5) * (n_in / n_out) - 0.5
    s = np.clip(s, 0.0, n_in - 1)
    i0 = np.floor(s).astype(np.intp)
    i1 = np.minimum(i0 + 1, n_in - 1)
    return i0, i1, (s - i0).astype(np.float32)


class Bilinear:
    """Bilinear upsampling of a small [h, w, C] map to [H, W, C], a row strip at a time.

    The columns are interpolated once per source row (`columns`); an output row
    is then one such row plus a weight times its difference to the next
    (`between`): two contiguous row reads and a multiply-add per output pixel.
    """

    def __init__(self, out_h: int, out_w: int, in_h: int, in_w: int):
        self.rows = axis_taps(out_h, in_h)
        self.cols = axis_taps(out_w, in_w)
        self.identity = (out_h, out_w) == (in_h, in_w)

    def column_weights(self, channel_shape: tuple = ()) -> np.ndarray:
        """The column weights repeated per channel, [W, *channel_shape]: broadcasting a
        [W, 1] array against [W, C] makes numpy loop over C elements at a time (an
        order of magnitude slower)."""
        wc = self.cols[2]
        channels = int(np.prod(channel_shape, dtype=np.intp))
        return np.repeat(wc, channels).reshape(wc.shape + tuple(channel_shape))

    def columns(self, src: np.ndarray, weights: np.ndarray, axis: int = 1) -> np.ndarray:
        """Rows [k, w, ...] (axis 1), or one row [w, ...] (axis 0), interpolated to the
        output width: [k, W, ...] or [W, ...] (a fresh array)."""
        c0, c1, _ = self.cols
        out = np.take(src, c0, axis=axis)
        step = np.take(src, c1, axis=axis)
        step -= out
        step *= weights
        out += step
        return out

    def between(self, row: np.ndarray, diff: np.ndarray, r0: int, r1: int, out: np.ndarray) -> np.ndarray:
        """Output rows r0:r1 = row + weight * diff, written into `out` (which may be `diff`).

        `row` and `diff` are one source row and its difference to the next (all
        output rows between the same two source rows) or one gathered row each."""
        wr = self.rows[2][r0:r1]
        np.multiply(diff, wr.reshape((-1,) + (1,) * (out.ndim - 1)), out=out)
        out += row
        return out

    def prepare(self, src: np.ndarray):
        """(columns-interpolated rows [h, W, C], differences to the next row [h, W, C]) of `src`."""
        if self.identity:
            return src, None
        cols = self.columns(src, self.column_weights(src.shape[2:]))
        diff = np.empty_like(cols)
        np.subtract(cols[1:], cols[:-1], out=diff[:-1])
        diff[-1] = 0  # the last row's next row is itself (clamped edge)
        return cols, diff

    def strip(self, prepared, r0: int, r1: int) -> np.ndarray:
        """Output rows r0:r1 from prepare()'s result (a fresh array unless identity)."""
        cols, diff = prepared
        if diff is None:
            return cols[r0:r1]
        i0 = self.rows[0][r0:r1]
        out = np.take(diff, i0, axis=0)
        return self.between(np.take(cols, i0, axis=0), out, r0, r1, out)

    def at(self, prepared, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """Output pixels (rows[k], cols[k]) from prepare()'s result, [n, C]: the values strip()
        gives there, computed for those pixels only."""
        src, diff = prepared
        if diff is None:
            return src[rows, cols]
        i0 = self.rows[0][rows]
        out = diff[i0, cols] * self.rows[2][rows].reshape((-1,) + (1,) * (diff.ndim - 2))
        out += src[i0, cols]
        return out


class SourceRows:
    """Source rows of a small [h, w, C] map interpolated to the output width, with the
    difference to the next row, computed on demand for the rows a band of output
    needs: what Bilinear.prepare computes for the whole map, one row at a time."""

    def __init__(self, src: np.ndarray, up: Bilinear):
        self.src, self.up = src, up
        self.weights = up.column_weights(src.shape[2:])
        self.rows: dict[int, np.ndarray] = {}

    def _row(self, k: int) -> np.ndarray:
        if k not in self.rows:
            self.rows[k] = self.up.columns(self.src[k], self.weights, axis=0)
        return self.rows[k]

    def pair(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(row k, row k+1 - row k); the last row's next row is itself (clamped edge)."""
        row = self._row(k)
        if k + 1 >= self.src.shape[0]:
            return row, np.zeros_like(row)
        return row, self._row(k + 1) - row


def bilinear_rows(src: np.ndarray, out_h: int, out_w: int, r0: int = 0, r1: int | None = None) -> np.ndarray:
    """Rows r0:r1 of `src` ([h, w] or [h, w, C]) bilinearly resized to out_h x out_w."""
    src = np.asarray(src)
    up = Bilinear(out_h, out_w, src.shape[0], src.shape[1])
    return up.strip(up.prepare(src), r0, out_h if r1 is None else r1)


def fit_longest(h: int, w: int, longest: int) -> tuple[int, int]:
    """(h, w) scaled so the longer side is `longest`, aspect kept, at least 1 px each."""
    s = longest / max(h, w)
    return max(1, round(h * s)), max(1, round(w * s))


def resize_linear(img: np.ndarray, out_h: int, out_w: int) -> np.ndarray:
    """Resize [H, W] or [H, W, C] float32 with Pillow: box (area) filter when
    shrinking, so no aliasing; bilinear when enlarging."""
    from PIL import Image

    a = np.asarray(img, dtype=np.float32)
    if a.shape[:2] == (out_h, out_w):
        return a.copy()
    shrinking = out_h * out_w < a.shape[0] * a.shape[1]
    method = Image.Resampling.BOX if shrinking else Image.Resampling.BILINEAR
    planes = a[..., None] if a.ndim == 2 else a
    out = np.empty((out_h, out_w, planes.shape[2]), np.float32)
    for c in range(planes.shape[2]):
        plane = Image.fromarray(np.ascontiguousarray(planes[..., c]), mode="F")
        out[..., c] = np.asarray(plane.resize((out_w, out_h), method))
    return out[..., 0] if a.ndim == 2 else out


def resize_longest(img: np.ndarray, longest: int) -> np.ndarray:
    """resize_linear of [H, W] or [H, W, C] to the size fit_longest gives: its longer side
    `longest`, aspect kept (a crop at the network's working size)."""
    return resize_linear(img, *fit_longest(*img.shape[:2], longest))


def area_shrink(image: np.ndarray, longest: int) -> np.ndarray:
    """[H, W, C] averaged over k x k blocks, k the largest integer keeping the longer side
    >= `longest` (k = 1: the image itself). Every k-th row is added in turn (each a
    vector add over whole rows), then every k-th column of that: a 12 MP photo is
    read once. A remainder of < k rows/columns at the end is dropped."""
    H, W = image.shape[:2]
    k = max(1, max(H, W) // longest)
    if k == 1:
        return image
    h, w = H // k, W // k
    rows = image[0:h * k:k].astype(np.float32)  # a copy: the sums go into it
    for i in range(1, k):
        rows += image[i:h * k:k]
    out = rows[:, 0:w * k:k].copy()
    for i in range(1, k):
        out += rows[:, i:w * k:k]
    out *= np.float32(1.0 / (k * k))
    return out


def upsample_support(small: np.ndarray, H: int, W: int) -> np.ndarray:
    """`small` [h, w] (>= 0, a matte) bilinearly resized to [H, W], computed only over the rows and
    columns whose taps reach a non-zero value (zeros elsewhere, left to calloc)."""
    h, w = small.shape
    if (h, w) == (H, W):
        return small
    from relight.imaging.box import Box

    out = np.zeros((H, W), np.float32)
    support = Box.around(small)  # small >= 0 (a matte): its non-zero pixels
    if support is None:
        return out

    def span(n_out, n_in, lo, hi):
        i0, i1, _ = axis_taps(n_out, n_in)
        touch = np.flatnonzero((i1 >= lo) & (i0 <= hi))
        return int(touch[0]), int(touch[-1]) + 1

    r0, r1 = span(H, h, support.y0, support.y1 - 1)
    c0, c1 = span(W, w, support.x0, support.x1 - 1)
    up = Bilinear(H, W, h, w)
    cols, diff = up.prepare(small[..., None])
    prepared = np.ascontiguousarray(cols[:, c0:c1, 0]), np.ascontiguousarray(diff[:, c0:c1, 0])
    for a in range(r0, r1, 64):  # strips: the gathered rows stay in cache
        b = min(a + 64, r1)
        out[a:b, c0:c1] = up.strip(prepared, a, b)
    return out


def sample_points(image: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Bilinear samples of image [h, w] or [h, w, C] at pixel coordinates (pixel centres at
    +0.5); zero outside the image (MediaPipe's zero border)."""
    h, w = image.shape[:2]
    flat = image.reshape(h * w, -1)
    x = np.asarray(x, np.float32) - np.float32(0.5)
    y = np.asarray(y, np.float32) - np.float32(0.5)
    x0 = np.floor(x)
    y0 = np.floor(y)
    fx, fy = x - x0, y - y0
    x0 = x0.astype(np.intp)
    y0 = y0.astype(np.intp)
    out = np.zeros(x.shape + (flat.shape[1],), np.float32)
    for dy, wy in ((0, 1 - fy), (1, fy)):
        yy = y0 + dy
        row_ok = (yy >= 0) & (yy < h)
        for dx, wx in ((0, 1 - fx), (1, fx)):
            xx = x0 + dx
            weight = wx * wy * (row_ok & (xx >= 0) & (xx < w))  # zero outside the image
            index = np.clip(yy, 0, h - 1) * w + np.clip(xx, 0, w - 1)
            out += np.take(flat, index, axis=0) * weight[..., None]
    return out if image.ndim == 3 else out[..., 0]
