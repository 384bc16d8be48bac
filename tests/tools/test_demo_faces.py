"""tools/demo.py's face box (the zooms of `make demo`'s faces sheet, issue 37): the head of a
person matte, found on synthetic mattes whose head is known."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def demo():
    spec = importlib.util.spec_from_file_location("demo_tool", ROOT / "tools" / "demo.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def _person(h, w, head_centre, head_radius, neck_w, shoulders_top, shoulder_w, bottom):
    """A matte: a head disc, a neck, then a trapezoid of shoulders and body to `bottom`."""
    y, x = np.mgrid[0:h, 0:w]
    cy, cx = head_centre
    m = (y - cy) ** 2 + (x - cx) ** 2 <= head_radius ** 2
    m |= (np.abs(x - cx) <= neck_w / 2) & (y >= cy) & (y < shoulders_top)
    m |= (np.abs(x - cx) <= shoulder_w / 2) & (y >= shoulders_top) & (y < bottom)
    return m.astype(np.float32)


@pytest.mark.parametrize("case", [
    # a portrait: the head is large, the shoulders fill the bottom
    dict(h=400, w=300, head_centre=(90, 150), head_radius=60, neck_w=50, shoulders_top=180, shoulder_w=280, bottom=400),
    # a full-body figure: a small head over a long body
    dict(h=800, w=300, head_centre=(60, 150), head_radius=25, neck_w=20, shoulders_top=100, shoulder_w=110, bottom=780),
])
def test_face_box_holds_the_head_and_not_the_shoulders(demo, case):
    m = _person(**case)
    y0, y1, x0, x1 = demo.face_box(m)
    cy, cx = case["head_centre"]
    r = case["head_radius"]
    # the head's disc lies inside (the box is 1.25 x the head: a margin of 1/8 each side)
    assert y0 <= cy - r and y1 >= cy + r and x0 <= cx - r and x1 >= cx + r
    # no wider than 1.25 x the head plus the neck's rows, and it stops above the shoulders' line
    assert (x1 - x0) <= 1.3 * (case["shoulders_top"] - (cy - r)) + 2
    assert y1 <= case["shoulders_top"] + 0.15 * (case["shoulders_top"] - (cy - r))


def test_face_box_refuses_an_empty_matte(demo):
    with pytest.raises(ValueError, match="empty"):
        demo.face_box(np.zeros((20, 20)))
