"""relight.person.mask_ops against scipy.ndimage (a test-only reference: the core is numpy only)."""

from __future__ import annotations

import numpy as np
import pytest
from scipy import ndimage

from relight.person.mask_ops import box_mean, dilate, label


@pytest.mark.parametrize("seed", range(4))
def test_label_finds_scipys_8_connected_parts(seed):
    rng = np.random.default_rng(seed)
    for _ in range(60):
        h, w = (int(v) for v in rng.integers(1, 48, 2))
        inside = rng.random((h, w)) < rng.uniform(0.05, 0.9)
        labels, areas = label(inside)
        ref, count = ndimage.label(inside, structure=np.ones((3, 3)))
        assert len(areas) == count and labels.dtype == np.int32
        assert np.array_equal(labels > 0, inside)
        # the same partition: each reference part is one label and each label one part
        pairs = np.unique(np.stack([ref[inside], labels[inside]]), axis=1)
        assert pairs.shape[1] == count
        # areas by label, labels numbered by each part's first pixel in row-major order
        assert np.array_equal(np.bincount(labels.ravel(), minlength=count + 1)[1:], areas)
        firsts = [np.flatnonzero(labels.ravel() == k)[0] for k in range(1, count + 1)]
        assert firsts == sorted(firsts)


def test_label_of_nothing_and_of_everything():
    labels, areas = label(np.zeros((5, 7), bool))
    assert areas == [] and not labels.any()
    labels, areas = label(np.ones((5, 7), bool))
    assert areas == [35] and np.all(labels == 1)


def test_diagonal_touch_joins_and_a_gap_separates():
    inside = np.zeros((4, 6), bool)
    inside[0, 0] = inside[1, 1] = True   # diagonal: one part
    inside[3, 3] = inside[3, 5] = True   # a column apart: two parts
    labels, areas = label(inside)
    assert areas == [2, 1, 1] and labels[0, 0] == labels[1, 1] != labels[3, 3] != labels[3, 5]


def test_dilate_is_scipys_square_dilation():
    rng = np.random.default_rng(9)
    inside = rng.random((30, 41)) < 0.05
    for radius in (1, 2, 5):
        ref = ndimage.binary_dilation(inside, structure=np.ones((2 * radius + 1,) * 2))
        assert np.array_equal(dilate(inside, radius), ref)


@pytest.mark.parametrize("r", [1, 3, 25])  # 25: wider than the image
def test_box_mean_is_the_mean_over_the_window_inside_the_image(r):
    rng = np.random.default_rng(10)
    x = rng.random((20, 27)).astype(np.float32)
    ones = np.ones_like(x)
    kernel = np.ones((2 * r + 1,) * 2, np.float32)
    ref = ndimage.convolve(x, kernel, mode="constant") / ndimage.convolve(ones, kernel, mode="constant")
    np.testing.assert_allclose(box_mean(x, r), ref, rtol=1e-5, atol=1e-6)
