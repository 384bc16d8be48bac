"""relight/imaging/box.py: the one box type (rows then columns, end exclusive) and the boxes the
matte, the runtime and the clip filters take from it."""

from __future__ import annotations

import numpy as np
import pytest

from relight.imaging.box import Box


def test_around_holds_every_pixel_above_the_threshold_and_no_more():
    rng = np.random.default_rng(3)
    for _ in range(50):
        mask = np.zeros((23, 31), np.float32)
        n = int(rng.integers(1, 12))
        ys, xs = rng.integers(0, 23, n), rng.integers(0, 31, n)
        mask[ys, xs] = rng.uniform(0.1, 1.0, n)
        b = Box.around(mask)
        assert b == (ys.min(), ys.max() + 1, xs.min(), xs.max() + 1)
        inside = np.zeros(mask.shape, bool)
        inside[b.rows, b.cols] = True
        assert not mask[~inside].any() and (b.height, b.width) == (b.y1 - b.y0, b.x1 - b.x0)
    assert Box.around(np.zeros((4, 5))) is None
    mask = np.array([[0.2, 0.7], [0.0, 0.4]])
    assert Box.around(mask, 0.5) == Box(0, 1, 1, 2) and Box.around(mask, 0.7) is None  # strictly above


def test_grown_scaled_union_stay_in_the_image():
    b = Box(2, 5, 3, 9)
    assert b.grown(3, 7, 10) == (0, 7, 0, 10) and b.grown(1, 100, 100) == (1, 6, 2, 10)
    # rescaling rounds starts down and ends up: it covers every pixel the box touches, never empty
    assert b.rescaled((10, 20), (25, 30)) == (5, 13, 4, 14)
    assert Box(7, 8, 0, 1).rescaled((1000, 1000), (10, 10)) == (0, 1, 0, 1)
    rng = np.random.default_rng(5)
    for _ in range(200):
        H, W, h, w = (int(v) for v in rng.integers(1, 4000, 4))
        y0, x0 = int(rng.integers(0, H)), int(rng.integers(0, W))
        big = Box(y0, int(rng.integers(y0 + 1, H + 1)), x0, int(rng.integers(x0 + 1, W + 1)))
        s = big.rescaled((H, W), (h, w))
        assert 0 <= s.y0 < s.y1 <= h and 0 <= s.x0 < s.x1 <= w
        # the tightest such box: each edge within one pixel of the exact scaled edge
        assert s.y0 * H <= big.y0 * h < (s.y0 + 1) * H and (s.y1 - 1) * H < big.y1 * h <= s.y1 * H
        assert s.x0 * W <= big.x0 * w < (s.x0 + 1) * W and (s.x1 - 1) * W < big.x1 * w <= s.x1 * W
    assert b.union(Box(0, 3, 6, 12)) == (0, 5, 3, 12) and b.union(None) is b
    assert b.contains(b) and b.contains((3, 5, 3, 8)) and not b.contains(Box(1, 5, 3, 9))
    assert not b.contains((2, 6, 3, 9)) and not b.contains((2, 5, 2, 9)) and not b.contains((2, 5, 3, 10))
    assert Box.whole(4, 6) == (0, 4, 0, 6)
    y0, y1, x0, x1 = b  # a tuple in this order: saved files write list(box)
    assert [y0, y1, x0, x1] == list(b) == [2, 5, 3, 9]


def _decomposition(box):
    from relight.network.decomposition import Decomposition

    h, w = 6, 8
    return Decomposition(albedo=np.full((h, w, 3), 0.5, np.float32), transport=np.zeros((h, w, 9), np.float32),
                         residual=np.zeros((h, w, 9), np.float32), light=np.zeros((9, 3), np.float32),
                         alpha=np.ones((h, w), np.float32), box=box, working_size=(h, w),
                         photo=np.zeros((9, 12, 3), np.float32), photo_working=np.zeros((h, w, 3), np.float32),
                         sh_order=2)


def test_the_decomposition_holds_the_box_type():
    d = _decomposition((1, 7, 2, 10))
    assert isinstance(d.box, Box) and d.box.rows == slice(1, 7) and d.box.cols == slice(2, 10)
    with pytest.raises(TypeError, match="x1"):
        _decomposition((1, 7, 2))  # three numbers are not a box
