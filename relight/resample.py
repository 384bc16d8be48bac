"""Resampling of float images: the area/bilinear resizer and the one bilinear upsampler.

`resize_linear` (Pillow) brings a photo to the network's working size and back
down for the person matte: box (area) filter when shrinking, bilinear when
enlarging. `Bilinear` upsamples small maps (the relit person, the matte) to the
photo's resolution with half-pixel centres and clamped edges; every caller
(the compositor's tiles, the layers' strips, the person matte) goes through its
`columns` and `between`, so they give the same values bit for bit.
"""

from __future__ import annotations

import numpy as np

__all__ = ["Bilinear", "SourceRows", "axis_taps", "bilinear_rows", "resize_linear"]


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
