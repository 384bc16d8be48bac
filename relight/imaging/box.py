"""The one box type: a rectangle of image pixels, rows then columns, end exclusive.

    b = Box.around(matte)              # pixels where matte > 0; None when there are none
    photo[b.rows, b.cols]              # the crop
    y0, y1, x0, x1 = b                 # the tuple order (numpy's: rows, then columns)

A Box is a tuple, so the files that store one (the clip's resume state, the add-on's
saved results) keep writing `list(box)` in this order. PersonMatte.box,
Decomposition.box and the clip filters all hold this type.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

__all__ = ["Box"]


class Box(NamedTuple):
    """Pixels [y0, y1) x [x0, x1) of an image."""

    y0: int
    y1: int
    x0: int
    x1: int

    @classmethod
    def around(cls, mask: np.ndarray, threshold: float = 0.0) -> "Box | None":
        """The smallest box holding every pixel of `mask` [H, W] above `threshold`; None when
        no pixel is (rows are found first, then columns over those rows only)."""
        rows = np.flatnonzero(np.any(mask > threshold, axis=1))
        if rows.size == 0:
            return None
        y0, y1 = int(rows[0]), int(rows[-1]) + 1
        cols = np.flatnonzero(np.any(mask[y0:y1] > threshold, axis=0))
        return cls(y0, y1, int(cols[0]), int(cols[-1]) + 1)

    @classmethod
    def whole(cls, height: int, width: int) -> "Box":
        return cls(0, int(height), 0, int(width))

    @property
    def rows(self) -> slice:
        return slice(self.y0, self.y1)

    @property
    def cols(self) -> slice:
        return slice(self.x0, self.x1)

    @property
    def height(self) -> int:
        return self.y1 - self.y0

    @property
    def width(self) -> int:
        return self.x1 - self.x0

    def grown(self, pad: int, height: int, width: int) -> "Box":
        """`pad` pixels more on every side, kept inside an image of height x width."""
        return Box(max(0, self.y0 - pad), min(height, self.y1 + pad), max(0, self.x0 - pad), min(width, self.x1 + pad))

    def rescaled(self, size_from: tuple[int, int], size_to: tuple[int, int]) -> "Box":
        """The same region of the image resized from (H, W) `size_from` to `size_to`: starts
        rounded down, ends up (exact integer arithmetic), so it holds every pixel the box
        touches and is never empty."""
        (h0, w0), (h1, w1) = size_from, size_to
        return Box(self.y0 * h1 // h0, -(-self.y1 * h1 // h0), self.x0 * w1 // w0, -(-self.x1 * w1 // w0))

    def contains(self, other) -> bool:
        """Whether `other` (a Box or (y0, y1, x0, x1)) lies within this box."""
        y0, y1, x0, x1 = other
        return y0 >= self.y0 and y1 <= self.y1 and x0 >= self.x0 and x1 <= self.x1

    def union(self, other: "Box | None") -> "Box":
        """The smallest box holding both (this one when `other` is None)."""
        if other is None:
            return self
        return Box(min(self.y0, other.y0), max(self.y1, other.y1), min(self.x0, other.x0), max(self.x1, other.x1))
