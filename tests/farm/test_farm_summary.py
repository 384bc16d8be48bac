"""farm/execution/summary.py's colour flags use relight.imaging.colour (one sRGB, one luminance)."""

from __future__ import annotations

import colorsys

import numpy as np
import pytest

from farm.execution import summary
from relight.imaging.colour import srgb_encode


@pytest.mark.parametrize("rgb, dark", [((0.01, 0.01, 0.01), True), ((0.0, 0.027, 0.0), True),
                                       ((0.0, 0.028, 0.0), False), ((0.05, 0.05, 0.05), False)])
def test_dark_is_luminance_below_two_percent(rgb, dark):
    # 0.7152 * 0.027 = 0.0193 < 0.02 <= 0.7152 * 0.028 = 0.0200
    assert summary.is_dark(rgb) is dark


def test_saturated_is_measured_on_srgb_values():
    # linear (0.5, 0.02, 0.02) encodes to about (0.735, 0.152, 0.152): saturation 0.79, value 0.735
    assert np.allclose(srgb_encode(np.array([0.5, 0.02, 0.02])), [0.7354, 0.1517, 0.1517], atol=1e-3)
    assert summary.is_saturated((0.5, 0.02, 0.02))
    # linear (0.5, 0.1, 0.1) encodes to (0.735, 0.349, 0.349): saturation 0.53
    assert colorsys.rgb_to_hsv(*srgb_encode(np.array([0.5, 0.1, 0.1])))[1] == pytest.approx(0.525, abs=1e-2)
    assert not summary.is_saturated((0.5, 0.1, 0.1))
    assert not summary.is_saturated((0.03, 0.0, 0.0))  # saturated, but value 0.19 < 0.25
