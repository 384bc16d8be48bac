"""Operations on [h, w] masks (numpy only): binary dilation, connected parts, and box
means over windows. The person matte (relight.matte) and the relighting formula's matte
(relight.decomposition) use them; nothing here knows what a person is."""

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


def window_sum(x: np.ndarray, r: int, axis: int) -> np.ndarray:
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


def box_mean(x: np.ndarray, r: int) -> np.ndarray:
    """Mean over (2r+1)^2 windows, clipped at the borders."""
    h, w = x.shape
    count = (np.minimum(np.arange(h) + r, h - 1) - np.maximum(np.arange(h) - r, 0) + 1)[:, None] * \
            (np.minimum(np.arange(w) + r, w - 1) - np.maximum(np.arange(w) - r, 0) + 1)[None, :]
    return window_sum(window_sum(x, r, 0), r, 1) / count.astype(np.float32)
