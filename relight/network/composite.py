"""Compositing: the relit person, upsampled to the photo's resolution, over the photo.

Per full-resolution pixel: person = upsampled source (detail off), or
max(0, (photo + eps) * Q - eps * 2^EV) with Q the upsampled, exposure-scaled
quotient relit / photo of working resolution (detail on); then
out = a * person + (1 - a) * photo. Each step is an in-place numpy loop over a
tile of at most TILE_VALUES values, so a tile's buffers stay in cache and the
photo and `out` cross main memory once; bands of tiles run on up to four
threads (numpy releases the GIL in its loops). docs/runtime.md explains these
choices.
"""

from __future__ import annotations

import itertools
import os

import numpy as np

from relight.imaging.resample import Bilinear, SourceRows

__all__ = ["ALPHA_FLOOR", "DETAIL_EPS", "composite"]

ALPHA_FLOOR = 1.0 / 255  # predicted alpha below this is background: those pixels stay untouched
DETAIL_EPS = 1e-3        # linear radiance added to both sides of the detail ratio (dark pixels)
TILE_VALUES = 1 << 17    # float32 values per 3-channel tile (512 KiB): buffers stay in cache
BAND_ROWS = 256          # full-resolution rows per thread task


def _tiles(i0: np.ndarray | None, rows: int, width: int) -> list[tuple[int, int, int | None]]:
    """Row ranges (r0, r1, k) covering `rows` output rows of `width` pixels: at most
    TILE_VALUES / 3 pixels each, and every row of a range interpolates between
    source rows k and k + 1 (k = i0[r0]; None when nothing is resampled)."""
    cap = max(1, TILE_VALUES // (3 * width))
    if i0 is None:
        return [(r, min(r + cap, rows), None) for r in range(0, rows, cap)]
    edges = [0, *(np.flatnonzero(np.diff(i0)) + 1).tolist(), rows]
    return [(r, min(r + cap, b), int(i0[a])) for a, b in itertools.pairwise(edges) for r in range(a, b, cap)]


def _bands(i0: np.ndarray | None, rows: int, width: int) -> list[list[tuple[int, int, int | None]]]:
    """The tiles grouped into bands of about BAND_ROWS rows (one thread task each)."""
    bands, current, start = [], [], 0
    for tile in _tiles(i0, rows, width):
        if current and tile[1] - start > BAND_ROWS:
            bands.append(current)
            current, start = [], tile[0]
        current.append(tile)
    return bands + [current] if current else bands


class _Compositor:
    """Writes the person over the photo into `out`, one band of tiles per call."""

    def __init__(self, photo: np.ndarray, box, up: Bilinear, alpha: np.ndarray, mask: np.ndarray | None,
                 out: np.ndarray, source: np.ndarray, quotient: bool, scale: np.float32, accumulate: bool = False):
        self.photo, self.box, self.up, self.alpha, self.mask = photo, box, up, alpha, mask
        self.accumulate = accumulate
        self.out, self.source, self.quotient = out, source, quotient
        self.packed = out.flags.c_contiguous  # else a strided view: written channel by channel
        self.offset = np.float32(DETAIL_EPS) * scale  # eps * 2^EV: exact for whole EV steps

    def band(self, tiles) -> None:
        up = self.up
        y0, _, x0, x1 = self.box
        shape = (max(r1 - r0 for r0, r1, _ in tiles), x1 - x0, 3)
        person_buf = np.empty(shape, np.float32)
        quotient_buf = np.empty(shape, np.float32) if self.quotient else None
        zeros = np.zeros(shape, np.float32) if self.quotient else None
        alpha3_buf, rest_buf = np.empty(shape, np.float32), np.empty(shape, np.float32)
        alpha_buf = np.empty(shape[:2] + (1,), np.float32)
        if not up.identity:
            source_rows = SourceRows(self.source, up)
            alpha_rows = SourceRows(self.alpha[..., None], up)
        for r0, r1, k in tiles:
            n = r1 - r0
            photo = self.photo[y0 + r0:y0 + r1, x0:x1]
            if k is None:
                person = self.source[r0:r1]  # no resampling: a view of the caller's own array
            elif self.quotient:
                q = up.between(*source_rows.pair(k), r0, r1, quotient_buf[:n])
                person = np.add(photo, np.float32(DETAIL_EPS), out=person_buf[:n])
                person *= q
                person -= self.offset
                # the quotient is >= 0, but a pixel darker than its working-resolution
                # neighbourhood can land up to eps below 0 (array maximum: numpy's
                # scalar maximum has no SIMD loop)
                np.maximum(person, zeros[:n], out=person)
            else:
                # bilinear weights in [0, 1] of values >= 0: >= 0 in floating point too
                person = up.between(*source_rows.pair(k), r0, r1, person_buf[:n])
            if self.mask is not None:
                a = self.mask[y0 + r0:y0 + r1, x0:x1, None]
            elif k is None:
                a = self.alpha[r0:r1, :, None]  # already floored at decomposition
            else:
                a = up.between(*alpha_rows.pair(k), r0, r1, alpha_buf[:n])
                np.copyto(a, np.float32(0.0), where=a < ALPHA_FLOOR)
            # one alpha per channel: numpy broadcasts [.., 1] against [.., 3] with a
            # 3-element inner loop, 20x slower than three strided copies
            a3 = alpha3_buf[:n]
            for c in range(3):
                np.copyto(a3[..., c], a[..., 0])
            # a * person + (1 - a) * photo: exactly the photo where a == 0, the person where a == 1
            person *= a3
            target = self.out[y0 + r0:y0 + r1, x0:x1]
            if self.accumulate:  # out holds other people already: add a * (person - photo)
                change = np.multiply(photo, a3, out=rest_buf[:n])
                np.subtract(person, change, out=change)
                for c in [slice(None)] if self.packed else range(3):
                    target[..., c] += change[..., c]
                continue
            rest = np.subtract(np.float32(1.0), a3, out=rest_buf[:n])
            if self.packed:
                np.multiply(photo, rest, out=target)
                target += person
            else:  # inner loops along the rows: across a strided pixel they would be 3 values long
                for c in range(3):
                    np.multiply(photo[..., c], rest[..., c], out=target[..., c])
                    target[..., c] += person[..., c]


def composite(photo: np.ndarray, box, up: Bilinear, alpha: np.ndarray, mask: np.ndarray | None,
              source: np.ndarray, quotient: bool, scale: np.float32, out: np.ndarray | None = None,
              accumulate: bool = False) -> np.ndarray:
    """The photo with the person of `source` (working resolution, the crop `box`)
    composited over it, float32 [H, W, 3]; outside the box the photo's values bit for bit.

    `source` is the relit person (quotient False) or the detail quotient (True),
    already multiplied by the exposure `scale`; `alpha` is the working-resolution
    matte, `mask` the user's full-resolution mask (used instead when given).
    `out`: where to write, [H, W, 3] float32, possibly a strided view (the RGB of
    an RGBA buffer, rows in any order), so a caller that packs the image anyway
    needs no full-size array besides its own (288 MB at 24 MP); same values. `accumulate`: `out`
    already holds a composite (other people over the photo, whose mattes and this one sum to <= 1):
    a * (person - photo) is added over the box and nothing else is written."""
    y0, y1, x0, x1 = box
    if accumulate and out is None:
        raise ValueError("accumulate needs the out it adds to")
    if out is None:
        out = np.empty_like(photo)
    elif out.shape != photo.shape or out.dtype != np.float32:
        raise ValueError(f"out must be float32 {photo.shape}, got {out.dtype} {out.shape}")
    for c in ([slice(None)] if out.flags.c_contiguous else range(3)) if not accumulate else ():
        o, p = out[..., c], photo[..., c]
        o[:y0], o[y1:] = p[:y0], p[y1:]
        o[y0:y1, :x0], o[y0:y1, x1:] = p[y0:y1, :x0], p[y0:y1, x1:]
    compose = _Compositor(photo, box, up, alpha, mask, out, source, quotient, scale, accumulate)
    bands = _bands(up.rows[0] if not up.identity else None, y1 - y0, x1 - x0)
    if len(bands) > 1 and (os.cpu_count() or 1) > 1:
        # numpy releases the GIL in its loops: one band per core at a time
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
            list(pool.map(compose.band, bands))
    else:
        for band in bands:
            compose.band(band)
    return out
