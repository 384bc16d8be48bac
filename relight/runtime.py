"""Torch-free runtime: decompose a photo once with the ONNX network, relight it many times.

    r = Relighter("model.onnx")                   # SHA-256 checked before loading
    d = r.decompose(photo)                        # photo: linear float32 [H, W, 3]
    out = d.relight("studio", rotation_deg=90)    # linear float32 [H, W, 3]

The network runs on a crop around the person resized to the working size
(longest side, default 512), so its cost and memory do not grow with the
photo. Relighting evaluates rho * (T . L') + E . L' at working resolution
over the matte's pixels only (clamped at 0: negative light is SH ringing),
then brings the result to the photo's resolution with bilinear interpolation,
restores the photo's own fine detail (ratio of the photo to its
working-resolution version), and composites the person over the untouched
original with the matte, in cache-sized tiles on two threads. docs/runtime.md explains
these choices. Nothing here imports torch or bpy.
"""

from __future__ import annotations

import itertools
import math
import os
from collections import OrderedDict
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from relight import quality, sh
from relight.models import (CONVENTION_VERSION, INPUT_NAME, ONNX_FORMAT, OUTPUT_NAMES, REGISTRY_PATH,
                            default_model_path, expected_digest)
from relight.prt import to_network_input

__all__ = ["Relighter", "Decomposition", "RelightStats", "QUALITY_SIZES", "open_session", "resize_linear",
           "bilinear_rows"]

QUALITY_SIZES = quality.working_sizes()  # the presets' table lives in relight/quality.py
DEFAULT_WORKING_SIZE = QUALITY_SIZES[quality.DEFAULT]
FIND_SIZE = 256          # longest side of the first, person-finding pass
FIND_THRESHOLD = 0.5     # alpha above which a low-res pixel counts as the person
CROP_MARGIN = 0.05       # context kept around the person's box, as a fraction of its longest side
ALPHA_FLOOR = 1.0 / 255  # predicted alpha below this is background: those pixels stay untouched
DETAIL_EPS = 1e-3        # linear radiance added to both sides of the detail ratio (dark pixels)
DETAIL_MAX = 8.0         # cap on the detail ratio: a speck cannot blow up
STRIP_ROWS = 128         # full-resolution rows resampled at a time by layers() (bounds temporaries)
TILE_VALUES = 1 << 17    # float32 values per 3-channel tile in relight() (512 KiB): buffers stay in cache
BAND_ROWS = 256          # full-resolution rows per thread task in relight()
LIGHT_CACHE_SIZE = 32
MATTE_SOURCES = ("person", "network")  # where decompose() takes the matte from when no mask is given


# ------------------------------------------------------------------ resampling


def _axis_taps(n_out: int, n_in: int):
    """Bilinear taps (half-pixel centres, clamped edges): i0, i1 [n_out] and weight of i1."""
    s = (np.arange(n_out, dtype=np.float64) + 0.5) * (n_in / n_out) - 0.5
    s = np.clip(s, 0.0, n_in - 1)
    i0 = np.floor(s).astype(np.intp)
    i1 = np.minimum(i0 + 1, n_in - 1)
    return i0, i1, (s - i0).astype(np.float32)


class _Bilinear:
    """Bilinear upsampling of a small [h, w, C] map to [H, W, C], one row strip at a time.

    prepare() interpolates the columns once at the small map's h rows and keeps
    the differences between neighbouring rows; each output row is then one
    source row plus a weight times one difference row: two contiguous row
    gathers and a multiply-add per output pixel.
    """

    def __init__(self, out_h: int, out_w: int, in_h: int, in_w: int):
        self.rows = _axis_taps(out_h, in_h)
        self.cols = _axis_taps(out_w, in_w)
        self.identity = (out_h, out_w) == (in_h, in_w)

    def prepare(self, src: np.ndarray):
        """(columns-interpolated rows [h, W, C], row differences [h, W, C]) of `src`."""
        if self.identity:
            return src, None
        c0, c1, wc = self.cols
        cols = np.take(src, c0, axis=1)
        step = np.take(src, c1, axis=1)
        step -= cols
        # the weights repeated per channel: broadcasting a [W, 1] array against [W, C]
        # makes numpy loop over C elements at a time (an order of magnitude slower)
        channels = int(np.prod(src.shape[2:], dtype=np.intp))
        step *= np.repeat(wc, channels).reshape(wc.shape + src.shape[2:])
        cols += step
        diff = step  # reused: same shape, no longer needed
        np.subtract(cols[1:], cols[:-1], out=diff[:-1])
        diff[-1] = 0  # the last row's next row is itself (clamped edge)
        return cols, diff

    def strip(self, prepared, r0: int, r1: int) -> np.ndarray:
        cols, diff = prepared
        if diff is None:
            return cols[r0:r1]
        i0, i1, wr = (a[r0:r1] for a in self.rows)
        out = np.take(diff, i0, axis=0)
        out *= wr.reshape((-1,) + (1,) * (cols.ndim - 1))  # zero weight where i1 == i0
        out += np.take(cols, i0, axis=0)
        return out


def bilinear_rows(src: np.ndarray, out_h: int, out_w: int, r0: int = 0, r1: int | None = None) -> np.ndarray:
    """Rows r0:r1 of `src` ([h, w] or [h, w, C]) bilinearly resized to out_h x out_w."""
    src = np.asarray(src)
    up = _Bilinear(out_h, out_w, src.shape[0], src.shape[1])
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


def _grow(inside: np.ndarray) -> np.ndarray:
    """3x3 binary dilation of a [h, w] bool map (numpy only)."""
    out = inside.copy()
    out[1:] |= inside[:-1]
    out[:-1] |= inside[1:]
    rows = out.copy()
    out[:, 1:] |= rows[:, :-1]
    out[:, :-1] |= rows[:, 1:]
    return out


# ------------------------------------------------------------------ validation


def _check_photo(photo) -> np.ndarray:
    a = np.asarray(photo)
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"photo must be linear RGB [H, W, 3], got shape {a.shape}")
    if a.shape[0] < 2 or a.shape[1] < 2:
        raise ValueError(f"photo is too small ({a.shape[1]}x{a.shape[0]})")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"photo must be floating point linear radiance, got dtype {a.dtype}")
    a = a.astype(np.float32, copy=False)
    for r0 in range(0, a.shape[0], 1024):  # strips: no full-size boolean temporary
        if not np.all(np.isfinite(a[r0:r0 + 1024])):
            raise ValueError("photo contains NaN or Inf")
    return a


def _check_mask(mask, shape) -> np.ndarray:
    m = np.asarray(mask)
    if m.ndim == 3 and m.shape[2] == 1:
        m = m[..., 0]
    if m.shape != tuple(shape):
        raise ValueError(f"mask must be [H, W] = {tuple(shape)} like the photo, got {m.shape}")
    if m.dtype == bool:
        m = m.astype(np.float32)
    if not np.issubdtype(m.dtype, np.number):
        raise ValueError(f"mask must be numeric or bool, got dtype {m.dtype}")
    m = m.astype(np.float32, copy=False)
    if not np.all(np.isfinite(m)) or m.min() < 0 or m.max() > 1:
        raise ValueError("mask values must be finite and in [0, 1]")
    if not m.max() > 0:
        raise ValueError("mask is empty (all zero): it marks no person")
    return m


def _fit(h: int, w: int, longest: int) -> tuple[int, int]:
    """(h, w) scaled so the longer side is `longest`, at least 1 px each."""
    s = longest / max(h, w)
    return max(1, round(h * s)), max(1, round(w * s))


def _bbox(mask: np.ndarray, threshold: float):
    rows = np.flatnonzero(np.any(mask > threshold, axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(np.any(mask[rows[0]:rows[-1] + 1] > threshold, axis=0))
    return int(rows[0]), int(rows[-1]) + 1, int(cols[0]), int(cols[-1]) + 1


def _expand(box, height: int, width: int):
    y0, y1, x0, x1 = box
    pad = max(2, int(math.ceil(CROP_MARGIN * max(y1 - y0, x1 - x0))))
    return max(0, y0 - pad), min(height, y1 + pad), max(0, x0 - pad), min(width, x1 + pad)


# ------------------------------------------------------------------ lights


class _LightCache:
    """LRU of projected lights (per map file and order) and rotated lights."""

    def __init__(self, size: int = LIGHT_CACHE_SIZE):
        import threading

        self.size = size
        self.items: OrderedDict = OrderedDict()
        self.lock = threading.Lock()  # a UI thread and a worker may relight at once

    def get(self, key, make):
        with self.lock:
            if key in self.items:
                self.items.move_to_end(key)
                return self.items[key]
        value = make()  # outside the lock: a slow projection does not block other lights
        value.flags.writeable = False  # shared between callers
        with self.lock:
            self.items[key] = value
            while len(self.items) > self.size:
                self.items.popitem(last=False)
        return value


_CACHE = _LightCache()


def _fit_order(coeffs: np.ndarray, n: int) -> np.ndarray:
    """Truncate or zero-pad SH coefficients [m, 3] to n rows."""
    c = sh.validate_coeffs(coeffs)
    if c.shape[0] >= n:
        return c[:n]
    return np.concatenate([c, np.zeros((n - c.shape[0], 3), c.dtype)], axis=0)


def _map_key(light) -> tuple:
    path = Path(light)
    if path.is_file():
        st = path.stat()
        return ("file", str(path.resolve()), st.st_mtime_ns, st.st_size)
    return ("preset", str(light))


def resolve_light(light, order: int, rotation_deg: float = 0.0, normalize: bool = True) -> np.ndarray:
    """SH light [n, 3] (float64) for `light`: map path, preset name, SH array or Decomposition."""
    n = sh.num_coeffs(order)
    if isinstance(light, Decomposition):
        base = _fit_order(light.light, n)
    elif isinstance(light, (str, os.PathLike)):
        if isinstance(light, str) and not light:
            raise ValueError("light is an empty string: give an HDR map path or a preset name")
        from relight.envmap import light_from_map

        key = ("map", _map_key(light), order, bool(normalize))
        base = _CACHE.get(key, lambda: light_from_map(light, order, normalize=bool(normalize)))
    else:
        arr = np.asarray(light)
        if arr.dtype == object or not np.issubdtype(arr.dtype, np.number):
            raise ValueError(f"light must be an HDR path, preset name, SH array [n, 3] or Decomposition, "
                             f"got {type(light).__name__}")
        base = _fit_order(arr.astype(np.float64), n)
    try:
        rotation_deg = float(rotation_deg)
    except (TypeError, ValueError):
        raise ValueError(f"rotation must be a number of degrees, got {rotation_deg!r}") from None
    if not math.isfinite(rotation_deg):
        raise ValueError(f"rotation must be finite, got {rotation_deg}")
    if rotation_deg % 360.0 == 0.0:
        return np.array(base, dtype=np.float64)
    M = _CACHE.get(("rot", rotation_deg, order), lambda: sh.rotation_matrix(sh.z_rotation(rotation_deg), order))
    return M @ base


def _exposure_scale(exposure_ev) -> float:
    try:
        ev = float(exposure_ev)
    except (TypeError, ValueError):
        raise ValueError(f"exposure must be a number of EV stops, got {exposure_ev!r}") from None
    if not math.isfinite(ev) or abs(ev) > 64:
        raise ValueError(f"exposure must be finite and within +-64 EV, got {exposure_ev}")
    return 2.0 ** ev


# ------------------------------------------------------------------ compositing


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


class _SourceRows:
    """Rows of a small [h, w, C] map interpolated to the output width, with the
    difference to the next row: what _Bilinear.prepare computes for the whole
    map, one row at a time, for the rows a band of output needs."""

    def __init__(self, src: np.ndarray, up: _Bilinear, weights: np.ndarray):
        self.src, self.c0, self.c1, self.weights = src, up.cols[0], up.cols[1], weights
        self.rows: dict[int, np.ndarray] = {}

    def _row(self, k: int) -> np.ndarray:
        if k not in self.rows:
            # the same operations, in the same order, as _Bilinear.prepare: identical values
            row = np.take(self.src[k], self.c0, axis=0)
            step = np.take(self.src[k], self.c1, axis=0)
            step -= row
            step *= self.weights
            row += step
            self.rows[k] = row
        return self.rows[k]

    def pair(self, k: int) -> tuple[np.ndarray, np.ndarray]:
        """(row k, row k+1 - row k); the last row's next row is itself (clamped edge)."""
        row = self._row(k)
        if k + 1 >= self.src.shape[0]:
            return row, np.zeros_like(row)
        return row, self._row(k + 1) - row


class _Compositor:
    """Writes the relit person over the photo into `out`, one cache-sized tile at a time.

    Per full-resolution pixel: person = upsampled source (detail off), or
    max(0, (photo + eps) * Q - eps * 2^EV) with Q the upsampled, exposure-scaled
    quotient (detail on); then out = a * person + (1 - a) * photo. Each step is
    an in-place numpy loop over a tile of at most TILE_VALUES values, so a tile's
    buffers stay in cache and the photo and `out` cross main memory once.
    """

    def __init__(self, d: Decomposition, out: np.ndarray, source: np.ndarray, quotient: bool,
                 scale: np.float32):
        self.d, self.out, self.source, self.quotient = d, out, source, quotient
        self.offset = np.float32(DETAIL_EPS) * scale  # eps * 2^EV: exact for whole EV steps
        if not d._up.identity:
            # column weights repeated per channel: broadcasting [W, 1] against [W, 3]
            # makes numpy loop over 3 elements at a time (an order of magnitude slower)
            wc = d._up.cols[2]
            self.weights = (np.repeat(wc, 3).reshape(-1, 3), wc.reshape(-1, 1))

    def _upsample(self, rows: _SourceRows, r0: int, r1: int, k: int, dest: np.ndarray) -> np.ndarray:
        # the same operations, in the same order, as _Bilinear.strip: identical values
        row, diff = rows.pair(k)
        np.multiply(diff, self.d._up.rows[2][r0:r1, None, None], out=dest)
        dest += row
        return dest

    def band(self, tiles) -> None:
        d = self.d
        y0, _, x0, x1 = d.box
        shape = (max(r1 - r0 for r0, r1, _ in tiles), x1 - x0, 3)
        person_buf = np.empty(shape, np.float32)
        quotient_buf = np.empty(shape, np.float32) if self.quotient else None
        zeros = np.zeros(shape, np.float32) if self.quotient else None
        alpha3_buf, rest_buf = np.empty(shape, np.float32), np.empty(shape, np.float32)
        alpha_buf = np.empty(shape[:2] + (1,), np.float32)
        if not d._up.identity:
            source_rows = _SourceRows(self.source, d._up, self.weights[0])
            alpha_rows = _SourceRows(d.alpha[..., None], d._up, self.weights[1])
        for r0, r1, k in tiles:
            n = r1 - r0
            photo = d.photo[y0 + r0:y0 + r1, x0:x1]
            if k is None:
                person = self.source[r0:r1]  # no resampling: a view of relight()'s own array
            elif self.quotient:
                q = self._upsample(source_rows, r0, r1, k, quotient_buf[:n])
                person = np.add(photo, np.float32(DETAIL_EPS), out=person_buf[:n])
                person *= q
                person -= self.offset
                # the quotient is >= 0, but a pixel darker than its working-resolution
                # neighbourhood can land up to eps below 0 (array maximum: numpy's
                # scalar maximum has no SIMD loop)
                np.maximum(person, zeros[:n], out=person)
            else:
                # bilinear weights in [0, 1] of values >= 0: >= 0 in floating point too
                person = self._upsample(source_rows, r0, r1, k, person_buf[:n])
            if d.mask is not None:
                a = d.mask[y0 + r0:y0 + r1, x0:x1, None]
            elif k is None:
                a = d.alpha[r0:r1, :, None]  # already floored at decomposition
            else:
                a = self._upsample(alpha_rows, r0, r1, k, alpha_buf[:n])
                np.copyto(a, np.float32(0.0), where=a < ALPHA_FLOOR)
            # one alpha per channel: numpy broadcasts [.., 1] against [.., 3] with a
            # 3-element inner loop, 20x slower than three strided copies
            a3 = alpha3_buf[:n]
            for c in range(3):
                np.copyto(a3[..., c], a[..., 0])
            # a * person + (1 - a) * photo: exactly the photo where a == 0, the person where a == 1
            person *= a3
            rest = np.subtract(np.float32(1.0), a3, out=rest_buf[:n])
            target = self.out[y0 + r0:y0 + r1, x0:x1]
            np.multiply(photo, rest, out=target)
            target += person


@dataclass(frozen=True)
class RelightStats:
    """Negative light clamped to 0 by one relight, counted at working resolution
    over the matte's pixels (alpha > 0)."""

    clamped: int    # pixels with a channel of albedo * (T . L') + E . L' below 0
    pixels: int     # pixels of the matte
    darkest: float  # the most negative channel value before the clamp (0.0 when none)

    @property
    def fraction(self) -> float:
        return self.clamped / self.pixels if self.pixels else 0.0


# ------------------------------------------------------------------ decomposition


@dataclass
class Decomposition:
    """What the network saw in one photo, kept at working resolution.

    albedo [h, w, 3], transport [h, w, n], residual [h, w, n], alpha [h, w]
    and light [n, 3] belong to the crop `box` = (y0, y1, x0, x1) of the photo
    resized to `working_size` = (h, w). `photo` is the original (not copied).
    """

    albedo: np.ndarray
    transport: np.ndarray
    residual: np.ndarray
    light: np.ndarray
    alpha: np.ndarray
    box: tuple[int, int, int, int]
    working_size: tuple[int, int]
    photo: np.ndarray = field(repr=False)
    photo_working: np.ndarray = field(repr=False)   # the crop at working resolution
    mask: np.ndarray | None = field(default=None, repr=False)  # user mask (full resolution)
    sh_order: int = 4
    person_matte: object = field(default=None, repr=False)  # relight.matte.PersonMatte when it gave the mask

    def __post_init__(self):
        h, w = self.working_size
        n = sh.num_coeffs(self.sh_order)
        # matte pixels grown by one: the bilinear taps of every full-resolution
        # pixel inside the matte then read relit values, never the zeros around
        self._matte = np.flatnonzero(_grow(self.alpha > 0).reshape(-1))
        self._albedo_m = np.ascontiguousarray(self.albedo.reshape(-1, 3)[self._matte])
        self._transport_m = np.ascontiguousarray(self.transport.reshape(-1, n)[self._matte])
        self._residual_m = np.ascontiguousarray(self.residual.reshape(-1, n)[self._matte])
        inside = self.alpha.reshape(-1)[self._matte] > 0  # the grown ring is not the person
        self._inside = inside.astype(np.float32)
        self._inside_count = int(np.count_nonzero(inside))
        self.last_stats: RelightStats | None = None  # set by every relight (the latest call's)
        y0, y1, x0, x1 = self.box
        self._up = _Bilinear(y1 - y0, x1 - x0, h, w)
        self._alpha_prepared = None
        self._preview_weights = None

    @property
    def size(self) -> tuple[int, int]:
        """(H, W) of the photo."""
        return self.photo.shape[:2]

    def light_for(self, light, rotation_deg: float = 0.0, exposure_ev: float = 0.0,
                  normalize: bool = True) -> np.ndarray:
        """The SH light [n, 3] float32 that relight() would use."""
        L = resolve_light(light, self.sh_order, rotation_deg, normalize) * _exposure_scale(exposure_ev)
        return L.astype(np.float32)

    def relight_working(self, light, rotation_deg: float = 0.0, exposure_ev: float = 0.0,
                        normalize: bool = True) -> np.ndarray:
        """The relit person at working resolution, [h, w, 3], zero outside the matte:
        max(0, albedo * (T . L') + E . L') on the matte's pixels (float32 matmuls).

        A radiance is >= 0; negative values are SH truncation ringing (or network
        error), not light: they are set to 0 and counted in `last_stats`
        (docs/conventions.md, "Ringing and negative light").
        """
        L = self.light_for(light, rotation_deg, exposure_ev, normalize)
        h, w = self.working_size
        relit = self._albedo_m * (self._transport_m @ L)
        relit += self._residual_m @ L
        # per-pixel minimum as two column minima: relit.min(axis=1) loops 3 values at a time, 30x slower
        darkest = np.minimum(np.minimum(relit[:, 0], relit[:, 1]), relit[:, 2])
        np.minimum(darkest, np.float32(0.0), out=darkest)
        darkest *= self._inside  # only the person's pixels count, not the grown ring
        self.last_stats = RelightStats(clamped=int(np.count_nonzero(darkest)), pixels=self._inside_count,
                                       darkest=float(darkest.min()))
        np.maximum(relit, np.float32(0.0), out=relit)
        if self._matte.size == h * w:  # matte covers the crop: no scatter needed
            return relit.reshape(h, w, 3)
        out = np.zeros((h * w, 3), np.float32)
        out[self._matte] = relit
        return out.reshape(h, w, 3)

    def preview(self, light, rotation_deg: float = 0.0, exposure_ev: float = 0.0,
                normalize: bool = True) -> np.ndarray:
        """Fast composite at working resolution (the crop only), [h, w, 3]: for interactive use."""
        relit = self.relight_working(light, rotation_deg, exposure_ev, normalize)
        if self._preview_weights is None:
            # alpha repeated per channel: numpy broadcasts [h, w, 1] against [h, w, 3]
            # 3 values at a time, an order of magnitude slower
            a = np.repeat(self.alpha[..., None], 3, axis=2)
            self._preview_weights = (a, 1.0 - a)
        a, rest = self._preview_weights
        relit *= a
        relit += rest * self.photo_working
        return relit

    def relight(self, light, rotation_deg: float = 0.0, exposure_ev: float = 0.0,
                normalize: bool = True, detail: bool = True) -> np.ndarray:
        """The photo relit by `light`, linear float32 [H, W, 3] at full resolution.

        `light`: HDR map path, preset name, SH coefficients [m, 3] (truncated
        or zero-padded to the model's order) or another Decomposition (its
        estimated light). Maps are scaled to mean luminance 0.8 unless
        normalize=False; the light turns by rotation_deg about world Z and is
        scaled by 2**exposure_ev. Pixels outside the matte keep their values
        bit for bit. When the crop was resized for the network, `detail`
        relights the full-resolution photo by the upsampled quotient
        relit / photo of working resolution (keeps the photo's fine texture);
        without it the relit person is just upsampled. The relit person is
        >= 0 (negative light clamped; `last_stats` counts it).
        """
        scale = np.float32(_exposure_scale(exposure_ev))
        relit = self.relight_working(light, rotation_deg, 0.0, normalize)
        y0, y1, x0, x1 = self.box
        out = np.empty_like(self.photo)
        out[:y0], out[y1:] = self.photo[:y0], self.photo[y1:]
        out[y0:y1, :x0], out[y0:y1, x1:] = self.photo[y0:y1, :x0], self.photo[y0:y1, x1:]
        quotient = detail and not self._up.identity
        if quotient:
            source = (relit + DETAIL_EPS) / (self.photo_working + DETAIL_EPS)
            # capped: a bright speck averaged away at working resolution would
            # otherwise be multiplied by relit / (its dark surroundings)
            np.clip(source, 0.0, DETAIL_MAX, out=source)
        else:
            source = relit
        # exposure folded into what is upsampled: a power of two for whole EV
        # steps, so +1 EV still doubles the person exactly
        source *= scale
        compose = _Compositor(self, out, source, quotient, scale)
        bands = _bands(self._up.rows[0] if not self._up.identity else None, y1 - y0, x1 - x0)
        if len(bands) > 1 and (os.cpu_count() or 1) > 1:
            # numpy releases the GIL in its loops: one band per core at a time
            from concurrent.futures import ThreadPoolExecutor

            with ThreadPoolExecutor(max_workers=min(4, os.cpu_count() or 1)) as pool:
                list(pool.map(compose.band, bands))
        else:
            for band in bands:
                compose.band(band)
        return out

    def _alpha_strip(self, r0: int, r1: int) -> np.ndarray:
        y0, _, x0, x1 = self.box
        if self.mask is not None:
            return self.mask[y0 + r0:y0 + r1, x0:x1, None]
        if self._up.identity:
            return self.alpha[r0:r1, :, None]  # already floored at decomposition
        if self._alpha_prepared is None:
            self._alpha_prepared = self._up.prepare(self.alpha[..., None])
        a = self._up.strip(self._alpha_prepared, r0, r1)  # a fresh array
        a[a < ALPHA_FLOOR] = 0.0
        return a

    def full_alpha(self) -> np.ndarray:
        """The matte at full resolution [H, W] (zero outside the crop)."""
        H, W = self.size
        out = np.zeros((H, W), np.float32)
        y0, y1, x0, x1 = self.box
        for r0 in range(0, y1 - y0, STRIP_ROWS):
            r1 = min(r0 + STRIP_ROWS, y1 - y0)
            out[y0 + r0:y0 + r1, x0:x1] = self._alpha_strip(r0, r1)[..., 0]
        return out

    def layers(self, light=None, rotation_deg: float = 0.0, exposure_ev: float = 0.0,
               normalize: bool = True) -> dict[str, np.ndarray]:
        """Full-resolution albedo, shading T . L', residual E . L' ([H, W, 3], zero
        outside the matte) and alpha [H, W]; L' is the photo's own light when
        `light` is None. albedo * shading + residual is the relit person before
        the clamp at 0 (the layers keep their sign: linear, for compositing)."""
        L = self.light_for(self if light is None else light, rotation_deg, exposure_ev,
                           normalize)
        h, w = self.working_size
        maps = {}
        for name, values in (("albedo", self._albedo_m), ("shading", self._transport_m @ L),
                             ("residual", self._residual_m @ L)):
            small = np.zeros((h * w, 3), np.float32)
            small[self._matte] = values
            maps[name] = self._to_full(small.reshape(h, w, 3))
        maps["alpha"] = self.full_alpha()
        return maps

    def _to_full(self, small: np.ndarray) -> np.ndarray:
        H, W = self.size
        out = np.zeros((H, W, small.shape[2]), np.float32)
        prepared = self._up.prepare(small)
        y0, y1, x0, x1 = self.box
        for r0 in range(0, y1 - y0, STRIP_ROWS):
            r1 = min(r0 + STRIP_ROWS, y1 - y0)
            out[y0 + r0:y0 + r1, x0:x1] = self._up.strip(prepared, r0, r1)
        return out


# ------------------------------------------------------------------ the session


def open_session(path: str | os.PathLike, threads: int | None = None, providers: list | None = None,
                 registry_path: str | os.PathLike = REGISTRY_PATH):
    """(onnxruntime session, SHA-256) of a model file whose hash matches its record.

    The one loader of every shipped ONNX file (relighting networks and the
    person matte): the bytes are read once, hashed, compared with the
    registry's entry or the .sha256 file beside the model, and only then
    handed to onnxruntime, so nothing unchecked is ever loaded.
    """
    import hashlib

    import onnxruntime as ort

    path = Path(path)
    if not path.is_file():
        raise ValueError(f"model file not found: {path}")
    want = expected_digest(path, registry_path)
    data = path.read_bytes()  # hash exactly the bytes the session loads
    got = hashlib.sha256(data).hexdigest()
    if got != want:
        raise ValueError(f"{path}: SHA-256 mismatch (file {got[:16]}..., expected {want[:16]}...): "
                         "the model file is corrupt or was modified; refusing to load it")
    if threads is not None and (not isinstance(threads, int) or threads < 1):
        raise ValueError(f"threads must be a positive integer or None, got {threads!r}")
    opts = ort.SessionOptions()
    opts.intra_op_num_threads = threads or 0
    opts.inter_op_num_threads = 1
    opts.execution_mode = ort.ExecutionMode.ORT_SEQUENTIAL
    try:
        session = ort.InferenceSession(data, opts, providers=providers or ["CPUExecutionProvider"])
    except Exception as exc:  # onnxruntime raises its own exception types
        raise ValueError(f"{path}: onnxruntime cannot load it ({exc})") from None
    return session, got


class Relighter:
    """An onnxruntime session of a relighting network (SHA-256 checked first).

    model_path: the .onnx file (default: the registry's default model);
    threads: intra-op threads (None: onnxruntime's default, all cores);
    providers: onnxruntime execution providers (default CPU only);
    working_size: longest side of the crop the network sees (QUALITY_SIZES).
    """

    def __init__(self, model_path: str | os.PathLike | None = None, threads: int | None = None,
                 providers: list | None = None, working_size: int = DEFAULT_WORKING_SIZE,
                 registry_path: str | os.PathLike = REGISTRY_PATH):
        path = Path(model_path) if model_path is not None else default_model_path(registry_path)
        self.working_size = self._check_size(working_size)
        self.session, self.sha256 = open_session(path, threads, providers, registry_path)
        self.model_path = path
        self.metadata = dict(self.session.get_modelmeta().custom_metadata_map)
        self._read_metadata()

    @staticmethod
    def _check_size(size) -> int:
        if isinstance(size, str):
            if size not in QUALITY_SIZES:
                raise ValueError(f"quality must be one of {sorted(QUALITY_SIZES)}, got {size!r}")
            return QUALITY_SIZES[size]
        if not isinstance(size, (int, np.integer)) or not 16 <= size <= 4096:
            raise ValueError(f"working size must be an integer in [16, 4096], got {size!r}")
        return int(size)

    def _read_metadata(self) -> None:
        md, where = self.metadata, self.model_path
        if md.get("relight.format") != ONNX_FORMAT:
            raise ValueError(f"{where}: not a relighting model (metadata relight.format is "
                             f"{md.get('relight.format')!r}, expected {ONNX_FORMAT!r})")
        if md.get("relight.conventions") != CONVENTION_VERSION:
            raise ValueError(f"{where}: made for conventions {md.get('relight.conventions')!r}, "
                             f"this runtime implements {CONVENTION_VERSION!r}")
        try:
            self.sh_order = int(md["relight.sh_order"])
            self.size_multiple = int(md["relight.size_multiple"])
        except (KeyError, ValueError):
            raise ValueError(f"{where}: metadata lacks a valid relight.sh_order / relight.size_multiple") from None
        names = [o.name for o in self.session.get_outputs()]
        if sorted(names) != sorted(OUTPUT_NAMES) or [i.name for i in self.session.get_inputs()] != [INPUT_NAME]:
            raise ValueError(f"{where}: graph must map {INPUT_NAME!r} to {list(OUTPUT_NAMES)}, "
                             f"has {[i.name for i in self.session.get_inputs()]} -> {names}")

    def run(self, net_input: np.ndarray) -> dict[str, np.ndarray]:
        """Run the graph on [B, 3, H, W] (H, W multiples of size_multiple)."""
        values = self.session.run(list(OUTPUT_NAMES), {INPUT_NAME: np.ascontiguousarray(net_input, np.float32)})
        return dict(zip(OUTPUT_NAMES, values))

    def _run_image(self, linear: np.ndarray, mask: np.ndarray | None) -> dict[str, np.ndarray]:
        """Network outputs for one linear [h, w, 3] image, padded to size_multiple, unpadded after."""
        h, w = linear.shape[:2]
        m = self.size_multiple
        x = to_network_input(linear, mask)
        ph, pw = -h % m, -w % m
        if ph or pw:
            x = np.pad(x, ((0, ph), (0, pw), (0, 0)), mode="edge")
        out = self.run(x.transpose(2, 0, 1)[None])
        res = {k: v[0, :, :h, :w].transpose(1, 2, 0) for k, v in out.items() if k != "light"}
        res["light"] = out["light"][0]
        for k, v in res.items():
            if not np.all(np.isfinite(v)):
                raise ValueError(f"the network produced NaN/Inf in {k!r}: model weights are broken")
        return res

    def find_person(self, photo: np.ndarray):
        """Crop box (y0, y1, x0, x1) around the person, from a low-resolution pass of
        the matte head; the whole frame when the matte finds nobody."""
        H, W = photo.shape[:2]
        h, w = _fit(H, W, min(FIND_SIZE, self.working_size))
        alpha = self._run_image(resize_linear(photo, h, w), None)["alpha"][..., 0]
        box = _bbox(alpha, FIND_THRESHOLD)
        if box is None:
            return 0, H, 0, W
        sy, sx = H / h, W / w
        y0, y1, x0, x1 = box
        return _expand((int(y0 * sy), int(math.ceil(y1 * sy)), int(x0 * sx), int(math.ceil(x1 * sx))), H, W)

    def decompose(self, photo, mask=None, working_size: int | str | None = None, *,
                  matte: str = "network", person: int | None = None) -> Decomposition:
        """Run the network once on the person in `photo` (linear float32 [H, W, 3]).

        With `mask` ([H, W] in [0, 1]) the crop is the mask's box, the network
        input is masked, and the mask is the matte. Without one, `matte` says
        where the matte comes from: "person" runs the person segmenter
        (relight.matte.person_matte; `person` picks one of several, 1 = the
        largest; NoPersonError when there is nobody) and uses its matte as the
        mask; "network" (the default here, kept for comparison and for images
        that are not photos) takes the box from a low-resolution pass of the
        network's alpha head and that alpha as the matte. The chosen
        PersonMatte is kept as `person_matte` on the result.
        """
        if matte not in MATTE_SOURCES:
            raise ValueError(f"matte must be one of {MATTE_SOURCES}, got {matte!r}")
        photo = _check_photo(photo)
        size = self.working_size if working_size is None else self._check_size(working_size)
        H, W = photo.shape[:2]
        found = None
        if mask is None and matte == "person":
            from relight.matte import person_matte

            found = person_matte(photo, person)
            mask = found.alpha
        if mask is not None:
            mask = _check_mask(mask, (H, W))
            box = _expand(_bbox(mask, 0.0), H, W)
        else:
            box = self.find_person(photo)
        y0, y1, x0, x1 = box
        h, w = _fit(y1 - y0, x1 - x0, size)
        crop = resize_linear(photo[y0:y1, x0:x1], h, w)
        small_mask = None if mask is None else np.clip(resize_linear(mask[y0:y1, x0:x1], h, w), 0.0, 1.0)
        out = self._run_image(crop, small_mask)
        if small_mask is not None:
            alpha = small_mask
        else:
            alpha = np.where(out["alpha"][..., 0] < ALPHA_FLOOR, 0.0, out["alpha"][..., 0]).astype(np.float32)
        return Decomposition(
            albedo=np.ascontiguousarray(out["albedo"]), transport=np.ascontiguousarray(out["transport"]),
            residual=np.ascontiguousarray(out["residual"]), light=np.asarray(out["light"], np.float32),
            alpha=np.ascontiguousarray(alpha, dtype=np.float32), box=box, working_size=(h, w),
            photo=photo, photo_working=crop, mask=mask, sh_order=self.sh_order, person_matte=found)
