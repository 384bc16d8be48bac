"""Person matte of a real photo: which pixels are the person, softly, at full resolution.

    m = person_matte(photo)            # photo: linear float32 [H, W, 3]
    m.alpha                            # [H, W] float32 in [0, 1], soft edges, hair kept
    m.box                              # (x0, y0, x1, y1): pixels where alpha > 0, end exclusive
    m.index, m.count                   # this person (1 = largest) of how many found

The segmenter is MediaPipe's selfie-segmentation network (Apache-2.0),
converted to ONNX by tools/convert_selfie_matte.py and loaded through the same
hash-checked path as the relighting models (relight.runtime.open_session).
It runs once at 256 x 256 on the photo squeezed to that size (as MediaPipe
feeds it); the people are the connected parts of its mask, largest first.
The chosen person's soft mask is then sharpened against the photo with a
guided filter at up to GUIDE_SIZE px and brought to full resolution
bilinearly, so the cost beyond the network is a few passes over a small
image and one over the full-resolution matte. docs/MATTE.md has the
measurements that chose this design. Nothing here imports torch or bpy.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relight.models import REGISTRY_PATH

__all__ = ["PersonMatte", "NoPersonError", "person_matte", "find_people", "matte_model_path",
           "MATTE_MODEL_NAME"]

MATTE_MODEL_NAME = "person-matte"       # its entry in relight/models/models.json
MATTE_MODEL_FILE = "person_matte.onnx"
NET_SIDE = 256                          # the shipped segmenter's input is NET_SIDE x NET_SIDE
GUIDE_SIZE = 512                        # longest side the edge is refined at
PERSON_THRESHOLD = 0.5                  # network probability above which a pixel is a person
MIN_PERSON_FRACTION = 0.002             # parts smaller than this share of the frame are noise
KEEP_RADIUS = 3                         # network pixels kept around the chosen person's part (its soft fringe)
GUIDE_RADIUS = 2                        # guided-filter window radius, in network pixels
GUIDE_EPS = 1e-3                        # guided-filter regulariser (guide in [0, 1])
ALPHA_FLOOR = 1.0 / 255                 # below: exactly background; above 1 - this: exactly person
MIN_SIDE = 32                           # px: smaller photos cannot show a person to segment


class NoPersonError(ValueError):
    """The segmenter found nobody in the photo."""


@dataclass
class PersonMatte:
    alpha: np.ndarray                   # [H, W] float32 in [0, 1]; 0 = untouched background
    box: tuple[int, int, int, int]      # (x0, y0, x1, y1) of alpha > 0, end exclusive
    index: int                          # which person: 1 = the largest
    count: int                          # people found


# ------------------------------------------------------------------ validation


def _check_photo(photo) -> np.ndarray:
    a = np.asarray(photo)
    if a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 1):
        raise ValueError(f"photo is greyscale {a.shape}: give linear RGB [H, W, 3] "
                         "(relight.photo.read_photo expands grey files to RGB)")
    if a.ndim == 3 and a.shape[2] in (2, 4):
        raise ValueError(f"photo has {a.shape[2]} channels (an alpha channel?): give linear RGB [H, W, 3]; "
                         "an alpha channel is a mask, not part of the photo")
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"photo must be linear RGB [H, W, 3], got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"photo must be linear float radiance, got dtype {a.dtype} "
                         "(decode 8/16-bit files with relight.photo.read_photo)")
    if min(a.shape[:2]) < MIN_SIDE:
        raise ValueError(f"photo is too small for a person matte ({a.shape[1]}x{a.shape[0]}; "
                         f"need at least {MIN_SIDE} px a side)")
    return a.astype(np.float32, copy=False)  # finiteness is checked on the shrunken photo


# ------------------------------------------------------------------ the network


_SESSION_LOCK = threading.Lock()
_SESSIONS: dict = {}


def matte_model_path(registry_path=REGISTRY_PATH) -> Path:
    """The shipped segmenter's file (its registry entry, else the default file name)."""
    from relight.models import load_registry

    entry = load_registry(registry_path)["models"].get(MATTE_MODEL_NAME)
    name = entry.get("file", MATTE_MODEL_FILE) if isinstance(entry, dict) else MATTE_MODEL_FILE
    return Path(registry_path).parent / name


def _session(model_path=None, threads: int | None = None, registry_path=REGISTRY_PATH):
    """The segmenter's onnxruntime session, hash-checked once and then shared."""
    from relight.runtime import open_session

    path = Path(model_path) if model_path is not None else matte_model_path(registry_path)
    key = (str(path.resolve()), threads, str(Path(registry_path).resolve()))
    with _SESSION_LOCK:
        if key not in _SESSIONS:
            session, _ = open_session(path, threads=threads, registry_path=registry_path)
            inputs, outputs = session.get_inputs(), session.get_outputs()
            shape = list(inputs[0].shape)
            if [i.name for i in inputs] != ["image"] or [o.name for o in outputs] != ["mask"] \
                    or len(shape) != 4 or shape[:2] != [1, 3] or not all(isinstance(v, int) for v in shape[2:]):
                raise ValueError(f"{path}: not a person matte model (expected image [1, 3, h, w] -> mask)")
            _SESSIONS[key] = session
        return _SESSIONS[key]


def _srgb_input(small_linear: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    from relight.colour import srgb_encode
    from relight.runtime import resize_linear

    x = resize_linear(small_linear, *size)  # squeezed to the network's shape, as MediaPipe feeds it
    return np.ascontiguousarray(srgb_encode(x).transpose(2, 0, 1)[None], dtype=np.float32)


def _area_shrink(image: np.ndarray, longest: int) -> np.ndarray:
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


# ------------------------------------------------------------------ people


def _label(inside: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """8-connected parts of a bool [h, w] map: (labels [h, w] int32, 0 = none; areas, by label - 1).

    Runs of each row are joined to the overlapping (or diagonally touching)
    runs of the row above with a union-find; numpy finds the runs.
    """
    h, w = inside.shape
    padded = np.zeros((h, w + 2), np.int8)
    padded[:, 1:-1] = inside
    edges = np.diff(padded, axis=1)
    runs = []                            # (row, start, end) per run
    row_runs: list[list[int]] = []
    parent: list[int] = []

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for r in range(h):
        starts = np.flatnonzero(edges[r] == 1)
        ends = np.flatnonzero(edges[r] == -1)
        here = []
        prev = row_runs[-1] if row_runs else []
        j = 0
        for s, e in zip(starts.tolist(), ends.tolist()):
            idx = len(runs)
            runs.append((r, s, e))
            parent.append(idx)
            here.append(idx)
            while j < len(prev) and runs[prev[j]][2] < s:  # ends before s - 1: cannot touch this or later runs
                j += 1
            k = j
            while k < len(prev) and runs[prev[k]][1] <= e:  # starts by e: touches (8-connected)
                a, b = find(idx), find(prev[k])
                if a != b:
                    parent[max(a, b)] = min(a, b)
                k += 1
        row_runs.append(here)
    labels = np.zeros((h, w), np.int32)
    roots: dict[int, int] = {}
    areas: list[int] = []
    for i, (r, s, e) in enumerate(runs):
        root = find(i)
        if root not in roots:
            roots[root] = len(roots) + 1
            areas.append(0)
        lab = roots[root]
        labels[r, s:e] = lab
        areas[lab - 1] += e - s
    return labels, areas


def _dilate(inside: np.ndarray, radius: int) -> np.ndarray:
    out = inside.copy()
    for _ in range(radius):
        grown = out.copy()
        grown[1:] |= out[:-1]
        grown[:-1] |= out[1:]
        rows = grown.copy()
        grown[:, 1:] |= rows[:, :-1]
        grown[:, :-1] |= rows[:, 1:]
        out = grown
    return out


def find_people(probability: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """People in a network mask [h, w]: (labels [h, w], 1 = largest; their areas in pixels).

    A person is an 8-connected part of probability > PERSON_THRESHOLD covering at
    least MIN_PERSON_FRACTION of the frame; smaller parts are dropped as noise.
    """
    labels, areas = _label(probability > PERSON_THRESHOLD)
    floor = MIN_PERSON_FRACTION * probability.size
    order = [i + 1 for i in sorted(range(len(areas)), key=lambda i: -areas[i]) if areas[i] >= floor]
    remap = np.zeros(len(areas) + 1, np.int32)
    for rank, lab in enumerate(order, start=1):
        remap[lab] = rank
    return remap[labels], [areas[lab - 1] for lab in order]


# ------------------------------------------------------------------ edge refinement


def _window_sum(x: np.ndarray, r: int, axis: int) -> np.ndarray:
    """Sums over windows of 2r+1 along `axis`, clipped at the borders (running sums in float64:
    one axis at a time keeps them small enough for the variance's differences)."""
    n = x.shape[axis]
    s = np.cumsum(x, axis=axis, dtype=np.float64)
    zero = np.zeros_like(np.take(s, [0], axis=axis))
    last = np.take(s, [n - 1], axis=axis)
    ahead = np.concatenate([s] + [last] * r, axis=axis)                # s[min(i + r, n - 1)]
    behind = np.concatenate([zero] * (r + 1) + [s], axis=axis)          # s[i - r - 1], 0 before the start
    idx = [slice(None)] * x.ndim
    idx[axis] = slice(r, r + n)
    hi = ahead[tuple(idx)]
    idx[axis] = slice(0, n)
    lo = behind[tuple(idx)]
    return (hi - lo).astype(np.float32)


def _box_mean(x: np.ndarray, r: int) -> np.ndarray:
    """Mean over (2r+1)^2 windows, clipped at the borders."""
    h, w = x.shape
    count = (np.minimum(np.arange(h) + r, h - 1) - np.maximum(np.arange(h) - r, 0) + 1)[:, None] * \
            (np.minimum(np.arange(w) + r, w - 1) - np.maximum(np.arange(w) - r, 0) + 1)[None, :]
    return _window_sum(_window_sum(x, r, 0), r, 1) / count.astype(np.float32)


# ------------------------------------------------------------------ the matte


def person_matte(photo, person: int | None = None, *, model_path=None, threads: int | None = None,
                 registry_path=REGISTRY_PATH, refine: bool = True) -> PersonMatte:
    """The matte of one person in `photo` (linear float32 [H, W, 3]).

    person: 1 = the largest person (default), 2 = the next, ...; NoPersonError
    (a ValueError) when the photo shows nobody, ValueError when `person` is
    out of range or the photo is not linear RGB at least MIN_SIDE px a side.
    """
    photo = _check_photo(photo)
    if person is not None and (isinstance(person, bool) or not isinstance(person, (int, np.integer))
                               or person < 1):
        raise ValueError(f"person must be 1 (the largest), 2, ... or None, got {person!r}")
    session = _session(model_path, threads, registry_path)
    H, W = photo.shape[:2]
    small = _area_shrink(photo, GUIDE_SIZE)
    # a NaN or Inf survives the block average (a sum of huge values may overflow to Inf:
    # refused too), so one check of the small image covers the photo at a fraction of the cost
    if not np.all(np.isfinite(small)):
        raise ValueError("photo contains NaN or Inf (or values too large to average)")
    chosen, index, count = _choose(_probability(session, small), person)
    from relight.runtime import bilinear_rows

    alpha_small = _refine(small, chosen) if refine else bilinear_rows(chosen, *small.shape[:2])
    # snapped at the small size: bilinear interpolation between equal values is exact, so the
    # full-resolution matte is exactly 0 (photo untouched) and exactly 1 where its taps are
    alpha_small[alpha_small < ALPHA_FLOOR] = 0.0
    alpha_small[alpha_small > 1.0 - ALPHA_FLOOR] = 1.0
    alpha = _upsample_support(alpha_small, H, W)
    return PersonMatte(alpha=alpha, box=_box(alpha), index=index, count=count)


_NOBODY = "no person found in the photo: give a mask (--mask) or a photo where a person is clearly visible"


def _probability(session, small: np.ndarray) -> np.ndarray:
    """The network's person probability [h, w] for the (shrunken) photo."""
    net_size = tuple(session.get_inputs()[0].shape[2:])
    probability = session.run(["mask"], {"image": _srgb_input(small, net_size)})[0][0, 0]
    if not np.all(np.isfinite(probability)):
        raise ValueError("the person matte network produced NaN/Inf: its weights are broken")
    return probability


def _choose(probability: np.ndarray, person: int | None):
    """(probability of the chosen person only, its index, how many people)."""
    labels, areas = find_people(probability)
    if not areas:
        raise NoPersonError(_NOBODY)
    index = 1 if person is None else int(person)
    if index > len(areas):
        raise ValueError(f"person {index} asked for, but the photo shows {len(areas)} "
                         f"{'person' if len(areas) == 1 else 'people'} (1 = the largest)")
    keep = _dilate(labels == index, KEEP_RADIUS)
    return np.where(keep, probability, np.float32(0.0)).astype(np.float32), index, len(areas)


def _box(alpha: np.ndarray) -> tuple[int, int, int, int]:
    """(x0, y0, x1, y1) of alpha > 0, end exclusive."""
    rows = np.flatnonzero(alpha.any(axis=1))
    if rows.size == 0:  # refinement erased a part the network saw: treat as nobody
        raise NoPersonError(_NOBODY)
    cols = np.flatnonzero(alpha[rows[0]:rows[-1] + 1].any(axis=0))
    return int(cols[0]), int(rows[0]), int(cols[-1]) + 1, int(rows[-1]) + 1


def _upsample_support(small: np.ndarray, H: int, W: int) -> np.ndarray:
    """`small` [h, w] bilinearly resized to [H, W], computed only over the rows and
    columns whose taps reach a non-zero value (zeros elsewhere, left to calloc)."""
    from relight.runtime import _axis_taps, _Bilinear

    h, w = small.shape
    if (h, w) == (H, W):
        return small
    out = np.zeros((H, W), np.float32)
    nz_rows = np.flatnonzero(small.any(axis=1))
    if nz_rows.size == 0:
        return out
    nz_cols = np.flatnonzero(small[nz_rows[0]:nz_rows[-1] + 1].any(axis=0))

    def span(n_out, n_in, lo, hi):
        i0, i1, _ = _axis_taps(n_out, n_in)
        touch = np.flatnonzero((i1 >= lo) & (i0 <= hi))
        return int(touch[0]), int(touch[-1]) + 1

    r0, r1 = span(H, h, nz_rows[0], nz_rows[-1])
    c0, c1 = span(W, w, nz_cols[0], nz_cols[-1])
    up = _Bilinear(H, W, h, w)
    cols, diff = up.prepare(small[..., None])
    cols, diff = np.ascontiguousarray(cols[:, c0:c1, 0]), np.ascontiguousarray(diff[:, c0:c1, 0])
    i0, _, wr = up.rows
    for a in range(r0, r1, 256):  # strips: the gathered rows stay in cache
        b = min(a + 256, r1)
        dst = out[a:b, c0:c1]
        np.take(diff, i0[a:b], axis=0, out=dst, mode="clip")   # written in place: no temporaries
        dst *= wr[a:b, None]
        dst += np.take(cols, i0[a:b], axis=0, mode="clip")
    return out


def _refine(small: np.ndarray, chosen: np.ndarray) -> np.ndarray:
    """The network's soft mask brought to `small`'s size and snapped to its edges.

    A fast guided filter (He and Sun 2015): the linear coefficients of alpha in
    the guide are fitted on a grid about the network's size, where box filters
    are cheap, then upsampled and applied to the guide at `small`'s size, so
    the edge follows the photo's own edges there.
    """
    from relight.runtime import bilinear_rows

    h, w = small.shape[:2]
    # grey guide, roughly perceptual (sqrt of linear luminance: cheaper than the sRGB curve)
    lum = small @ np.array([0.2126, 0.7152, 0.0722], np.float32)
    guide = np.sqrt(np.clip(lum, 0.0, 1.0)).astype(np.float32)
    coarse = _area_shrink(guide[..., None].repeat(3, axis=2), NET_SIDE)[..., 0] \
        if max(h, w) >= 2 * NET_SIDE else guide
    ch, cw = coarse.shape
    p = bilinear_rows(chosen, ch, cw)
    r = max(1, round(GUIDE_RADIUS * max(ch, cw) / NET_SIDE))
    mean_i, mean_p = _box_mean(coarse, r), _box_mean(p, r)
    a = (_box_mean(coarse * p, r) - mean_i * mean_p) / (_box_mean(coarse * coarse, r) - mean_i * mean_i
                                                        + np.float32(GUIDE_EPS))
    b = mean_p - a * mean_i
    a, b = _box_mean(a, r), _box_mean(b, r)
    if (ch, cw) != (h, w):
        a, b = bilinear_rows(a, h, w), bilinear_rows(b, h, w)
    out = a * guide + b
    np.clip(out, 0.0, 1.0, out=out)
    # where the network's mask (kept part) is zero the background stands: the filter
    # would otherwise bleed into background that looks like the person
    out[bilinear_rows(chosen, h, w) <= 0.0] = 0.0
    return out
