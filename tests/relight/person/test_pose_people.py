"""relight.person.pose_people: which detections are segmented, and how often the networks are asked."""

from __future__ import annotations

import math

import pytest

from evaluation.matte_eval import EVAL_DIR
from relight.files.photo import read_photo
from relight.person import matte, pose_people
from relight.person.pose_people import SAME_SQUARE_SCALE, SAME_SQUARE_SHIFT, SAME_SQUARE_TURN, same_square

SQUARE = (300.0, 400.0, 1000.0, 0.1)   # centre x, centre y, side, turn


def _moved(dx=0.0, dy=0.0, scale=1.0, turn=0.0):
    x, y, side, rotation = SQUARE
    return (x + dx, y + dy, side * scale, rotation + turn)


@pytest.mark.parametrize("other, same", [
    (_moved(), True),
    (_moved(dx=0.9 * SAME_SQUARE_SHIFT * 1000.0), True),
    (_moved(dx=1.1 * SAME_SQUARE_SHIFT * 1000.0), False),
    # the shift is measured against the smaller side: a grown square may not move as far
    (_moved(dy=0.9 * SAME_SQUARE_SHIFT * 1000.0, scale=1.1), True),
    (_moved(dy=0.9 * SAME_SQUARE_SHIFT * 1000.0, scale=0.8), False),
    (_moved(scale=0.99 * SAME_SQUARE_SCALE), True),
    (_moved(scale=1.01 * SAME_SQUARE_SCALE), False),
    (_moved(scale=1 / (1.01 * SAME_SQUARE_SCALE)), False),
    (_moved(turn=0.9 * SAME_SQUARE_TURN), True),
    (_moved(turn=-1.1 * SAME_SQUARE_TURN), False),
])
def test_same_square_within_each_tolerance_and_symmetric(other, same):
    assert same_square(SQUARE, other) is same
    assert same_square(other, SQUARE) is same


def test_same_square_turns_wrap_around_a_half_turn():
    """roi() gives turns in [-pi, pi): a person upside down at +-pi is one turn, not two."""
    a = (0.0, 0.0, 100.0, math.pi - 0.5 * SAME_SQUARE_TURN)
    b = (0.0, 0.0, 100.0, -math.pi + 0.4 * SAME_SQUARE_TURN)
    assert same_square(a, b) and same_square(b, a)
    assert not same_square(a, (0.0, 0.0, 100.0, 0.0))


def _counted(monkeypatch):
    """Counts the detector's runs and records each square the pose model segments."""
    calls = {"detect": 0, "squares": []}
    detect, pose_mask = pose_people.detect, pose_people.pose_mask

    def counting_detect(*args, **kwargs):
        calls["detect"] += 1
        return detect(*args, **kwargs)

    def recording_pose_mask(session, image, square, grid_shape, k):
        calls["squares"].append(square)
        return pose_mask(session, image, square, grid_shape, k)

    monkeypatch.setattr(pose_people, "detect", counting_detect)
    monkeypatch.setattr(pose_people, "pose_mask", recording_pose_mask)
    return calls


def test_a_portrait_is_searched_over_windows_once_and_each_square_segmented_once(monkeypatch):
    """astronaut.jpg (512 x 512, one person): the first look runs the detector on the whole picture and
    on 3 x 3 windows of 0.6 of its side; the second look (the person painted out) on the whole picture
    only, and finds nobody. The windows find the astronaut again and again: no two squares segmented are
    the same square, and fewer are segmented than were found."""
    photo, _ = read_photo(EVAL_DIR / "astronaut.jpg")
    found = []
    candidates = pose_people.candidates

    def recording_candidates(*args, **kwargs):
        found.extend(c := candidates(*args, **kwargs))
        return c

    monkeypatch.setattr(pose_people, "candidates", recording_candidates)
    calls = _counted(monkeypatch)
    mattes = matte.mattes_of_checked_photo(photo, threads=1)
    assert len(mattes) == 1
    assert calls["detect"] == 1 + 3 * 3 + 1
    squares = calls["squares"]
    assert not any(same_square(a, b) for i, a in enumerate(squares) for b in squares[i + 1:])
    assert 1 <= len(squares) < len(found)
