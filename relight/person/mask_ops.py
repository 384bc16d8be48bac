"""Operations on [h, w] masks (numpy only): binary dilation, connected parts, and box
means over windows. The person matte (relight.person.matte) and the relighting formula's matte
(relight.network.decomposition) use them; nothing here knows what a person is."""

from __future__ import annotations

import numpy as np

__all__ = ["box_mean", "dilate", "label", "window_sum"]


def dilate(inside: np.ndarray, radius: int) -> np.ndarray:
    """Binary dilation by a (2 radius + 1)^2 square (separable running maxima)."""
    out = inside.copy()
    for axis in (0, 1):
        grown = out.copy()
        n = out.shape[axis]
        for step in range(1, min(radius, n - 1) + 1):
            lo = [slice(None)] * 2
            hi = [slice(None)] * 2
            lo[axis], hi[axis] = slice(None, -step), slice(step, None)
            grown[tuple(hi)] |= out[tuple(lo)]
            grown[tuple(lo)] |= out[tuple(hi)]
        out = grown
    return out


def label(inside: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """8-connected parts of a bool [h, w] map: (labels [h, w] int32, 0 = none; areas, by label - 1).

    numpy finds the runs of each row and which runs of the row above each one overlaps or
    touches diagonally (two searches over the runs in row-major order); a union-find joins
    those pairs (a few per run, in Python: the pixels never are), and the labels are painted
    back by a running sum along the rows. Labels are numbered in row-major order of each
    part's first pixel.
    """
    h, w = inside.shape
    padded = np.zeros((h, w + 2), np.int8)
    padded[:, 1:-1] = inside
    edges = np.diff(padded, axis=1)                      # [h, w + 1]: +1 where a run starts, -1 past its end
    row, start = np.nonzero(edges == 1)
    _, end = np.nonzero(edges == -1)                     # the same runs, same order (row-major)
    n = row.size
    labels = np.zeros((h, w), np.int32)
    if n == 0:
        return labels, []
    stride = w + 2
    key_start, key_end = row * stride + start, row * stride + end
    # runs of the row above that touch run i (8-connected): start <= end_i and end >= start_i
    lo = np.searchsorted(key_end, (row - 1) * stride + start, side="left")
    hi = np.searchsorted(key_start, (row - 1) * stride + end, side="right")
    hi = np.maximum(hi, lo)
    count = hi - lo
    child = np.repeat(np.arange(n), count)
    above = np.repeat(lo - np.cumsum(count) + count, count) + np.arange(child.size)
    parent = list(range(n))

    def find(i: int) -> int:
        while parent[i] != i:
            parent[i] = parent[parent[i]]
            i = parent[i]
        return i

    for a, b in zip(child.tolist(), above.tolist()):
        ra, rb = find(a), find(b)
        if ra != rb:
            parent[max(ra, rb)] = min(ra, rb)
    roots = np.array([find(i) for i in range(n)])
    # a part's root is its first run (row-major): number the roots in that order
    is_root = roots == np.arange(n)
    number = np.cumsum(is_root).astype(np.int32)         # 1-based part number at each root
    run_label = number[roots]
    areas = np.bincount(run_label - 1, weights=end - start, minlength=int(number[-1])).astype(int).tolist()
    paint = np.zeros((h, w + 1), np.int32)
    np.add.at(paint, (row, start), run_label)
    np.add.at(paint, (row, end), -run_label)
    labels[:] = np.cumsum(paint, axis=1)[:, :w]
    return labels, areas

def window_sum(x: np.ndarray, r: int, axis: int) -> np.ndarray:
    """Sums over windows of 2r+1 along `axis` (0 or 1 of a 2-D array), clipped at the borders:
    2r+1 shifted slices of the zero-padded array added in float32. The matte's radii are 2-4,
    where this is 2-3x faster than running sums and exact to float32 rounding of 2r+1 terms
    (no differences of large running sums)."""
    n = x.shape[axis]
    pad = [(0, 0), (0, 0)]
    pad[axis] = (r, r)
    padded = np.pad(x.astype(np.float32, copy=False), pad)
    window = [slice(None), slice(None)]
    out = None
    for k in range(2 * r + 1):  # the window's k-th term: the padded array shifted by k
        window[axis] = slice(k, k + n)
        if out is None:
            out = padded[tuple(window)].copy()
        else:
            out += padded[tuple(window)]
    return out


def box_mean(x: np.ndarray, r: int) -> np.ndarray:
    """Mean over (2r+1)^2 windows, clipped at the borders."""
    h, w = x.shape
    count = (np.minimum(np.arange(h) + r, h - 1) - np.maximum(np.arange(h) - r, 0) + 1)[:, None] * \
            (np.minimum(np.arange(w) + r, w - 1) - np.maximum(np.arange(w) - r, 0) + 1)[None, :]
    return window_sum(window_sum(x, r, 0), r, 1) / count.astype(np.float32)
