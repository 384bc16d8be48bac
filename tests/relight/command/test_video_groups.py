"""`relight video` with several people (issue 47): everyone relit under the shot's one light, each
tracked so they keep their identity (relight.command.clip_people), the record's people; and a clip of
one person relit exactly as before."""

from __future__ import annotations

import json

import numpy as np
import pytest

from clip_support import person_clip, write_frames
from relight.cli import main
from relight.imaging.colour import srgb_decode, srgb_encode
from relight.command import cli_video
from relight.command.clip import ClipRelighter
from relight.command.clip_people import MISSED_FRAMES, Tracker
from relight.files.photo import read_photo
from relight.lighting.light import sh_light
from relight.network import quality
from relight.network.runtime import Relighter

H, W = 200, 300
# (bundled person, height at frame i, left edge at frame i): the left one shrinks and walks right, the
# right one grows and walks left, so the size ranks swap at frame 3 while each stays on their side
PEOPLE = (("biden", lambda i: 180 - 6 * i, lambda i: 40 + 3 * i),
          ("obama_standing", lambda i: 150 + 8 * i, lambda i: 170 - 2 * i))
# the same two touching, then overlapping: Balanced's pose detector separates them (Draft's selfie matte would not)
TOUCHING = (PEOPLE[0], ("obama_standing", lambda i: 150 + 8 * i, lambda i: 118 - 2 * i))


def _group_clip(n: int, people=PEOPLE):
    """n linear frames [H, W, 3] of the people pasted over a gradient, and each one's true matte per frame."""
    from evaluation.pasted_groups import _cutout

    frames, mattes = [], []
    for i in range(n):
        canvas = np.broadcast_to(np.linspace([0.55, 0.6, 0.65], [0.35, 0.38, 0.4], H, dtype=np.float32)[:, None],
                                 (H, W, 3)).copy()
        own = []
        for name, height, left in people:
            h, x = height(i), left(i)
            rgb, a = _cutout(name, h)
            w = min(a.shape[1], W - x)
            rows, cols = slice(H - h, H), slice(x, x + w)
            canvas[rows, cols] = a[:, :w, None] * rgb[:, :w] + (1 - a[:, :w, None]) * canvas[rows, cols]
            m = np.zeros((H, W), np.float32)
            m[rows, cols] = a[:, :w]
            own.append(m)
        frames.append(srgb_decode(canvas).astype(np.float32))
        mattes.append(own)
    return frames, mattes


@pytest.fixture(scope="module")
def group():
    return _group_clip(5)


@pytest.fixture(scope="module")
def draft():
    return Relighter(quality.model_path("draft"), threads=1, working_size=quality.preset("draft").working_size)


def _codes(image):
    return np.rint(np.clip(srgb_encode(np.clip(image, 0, 1)), 0, 1) * 255).astype(np.int16)


def _changed(relit, frame, matte) -> float:
    """The share of the person's core pixels (true matte > 0.9) that the relight moved by more than 2
    sRGB codes in some channel (left as they were: at most 1, the codes' rounding)."""
    core = matte > 0.9
    moved = np.abs(_codes(relit) - _codes(frame)).max(axis=2) > 2
    return float(moved[core].mean())


def test_two_people_are_both_relit_in_every_frame_and_keep_their_tracks(tmp_path, capsys):
    frames, mattes = _group_clip(5, TOUCHING)
    assert mattes[0][0].sum() > mattes[0][1].sum() and mattes[-1][0].sum() < mattes[-1][1].sum()  # sizes swap
    src = write_frames(tmp_path / "in", frames)
    # one EV up: a person relit moves by far more than the codes' rounding almost everywhere
    code = main(["video", str(src), "--light", "studio", "--exposure", "1", "--out", str(tmp_path / "out"),
                 "--quality", "balanced", "--threads", "1"])
    out, err = capsys.readouterr()
    assert code == 0, err
    assert "people: up to 2 found in a frame, up to 2 relit under the shot's one light, 2 tracked" in out
    for i, (frame, own) in enumerate(zip(frames, mattes)):
        relit = read_photo(tmp_path / "out" / f"f_{i + 1:04d}.png")[0]
        for k, matte in enumerate(own):
            assert _changed(relit, frame, matte) > 0.5, (i, k)
        # far from both people the frame is its input, code for code
        away = np.ones((H, W), bool)
        for matte in own:
            away &= np.convolve((matte > 0).any(axis=0), np.ones(41), "same")[None, :] == 0
        np.testing.assert_array_equal(_codes(relit)[away], _codes(frame)[away])
    record = json.loads((tmp_path / "out" / cli_video.JOB_FILE).read_text())["people"]
    assert (record["found"], record["relit"], record["frames_with_people_left"]) == (2, 2, 0)
    tracks = {t["track"]: t for t in record["tracks"]}
    assert sorted(tracks) == [1, 2] and all(t["frames"] == [0, 4] for t in tracks.values())
    # track 1 is the person on the left from the first frame (the larger there) to the last (the smaller):
    # each track's box centre lies within their own true matte's columns and outside the other's
    for box, own in (("first_box", mattes[0]), ("last_box", mattes[-1])):
        spans = [np.flatnonzero(m.max(axis=0) > 0.5)[[0, -1]] for m in own]
        for track, (mine, other) in ((1, spans), (2, spans[::-1])):
            centre = (tracks[track][box][2] + tracks[track][box][3]) / 2
            assert mine[0] <= centre <= mine[1] and not other[0] <= centre <= other[1], (box, track, spans, tracks)


def test_each_person_keeps_their_track_when_the_sizes_swap(draft, group):
    frames, mattes = group
    runner = ClipRelighter(draft, sh_light("studio", draft.sh_order), threads=1, matte_method="selfie")
    results = [runner.relight(f) for f in frames]
    ranks = []
    for r, own in zip(results, mattes):
        assert r.person and r.found == 2 and len(r.people) == 2
        by_track = {p["track"]: p for p in r.people}
        assert sorted(by_track) == [1, 2]
        # track 1's box is around the left person (their true matte's centre column), track 2's the right one's
        for track, matte in zip((1, 2), own):
            centre = float((matte.sum(axis=0) * np.arange(W)).sum() / matte.sum())
            _, _, x0, x1 = by_track[track]["box"]
            assert x0 <= centre < x1, (track, centre, by_track)
        ranks.append(by_track[1]["person"])
    assert ranks[0] == 1 and ranks[-1] == 2  # the right person became the larger: the test sees the swap
    # one light for the shot: each frame's estimate is the mean of the two people's own
    fresh = ClipRelighter(draft, sh_light("studio", draft.sh_order), threads=1, matte_method="selfie")
    people = fresh.analyse(frames[0]).people()
    assert len(people) == 2 and not np.allclose(people[0][0].light, people[1][0].light)
    np.testing.assert_array_equal(results[0].light, np.mean([p[0].light for p in people], axis=0, dtype=np.float64)
                                  .astype(np.float32))


def test_a_person_entering_and_leaving_gets_a_track_of_their_own(draft):
    alone, _ = _group_clip(7, PEOPLE[:1])
    both, _ = _group_clip(7)
    frames = alone[:2] + both[2:5] + alone[5:]   # the right person walks in at frame 2, out at frame 5
    runner = ClipRelighter(draft, sh_light("studio", draft.sh_order), threads=1, matte_method="selfie")
    results = [runner.relight(f) for f in frames]
    assert [r.cut for r in results] == [True] + [False] * 6  # one shot: the filters carry on
    assert [sorted(p["track"] for p in r.people) for r in results] == [[1], [1], [1, 2], [1, 2], [1, 2], [1], [1]]
    record = runner.record()
    assert [(t["track"], t["frames"]) for t in record["tracks"]] == [(1, [0, 6]), (2, [2, 4])]
    assert (record["found"], record["relit"]) == (2, 2)


def test_a_resumed_group_clip_continues_exactly(draft, group):
    frames, _ = group
    light = sh_light("studio", draft.sh_order)
    whole = ClipRelighter(draft, light, threads=1, matte_method="selfie")
    want = [whole.relight(f).image for f in frames]
    first = ClipRelighter(draft, light, threads=1, matte_method="selfie")
    for f in frames[:3]:
        first.relight(f)
    state = {k: np.array(v) for k, v in first.state().items()}  # as np.savez / np.load gives it back
    assert {"tracks", "matte", "maps_grey", "track2_matte", "track2_maps_grey"} <= set(state)
    second = ClipRelighter(draft, light, threads=1, matte_method="selfie")
    second.load_state(state)
    for f, expected in zip(frames[3:], want[3:]):
        np.testing.assert_array_equal(second.relight(f).image, expected)
    assert second.record() == whole.record()


def test_a_state_saved_before_tracking_continues_as_its_one_person(draft):
    """A job checkpointed by the one-person code (its filters under the bare keys, no tracks) resumes
    with that person as track 1 and the frames an uninterrupted run gives."""
    frames = person_clip(6)
    light = sh_light("studio", draft.sh_order)
    whole = ClipRelighter(draft, light, threads=1, matte_method="selfie")
    want = [whole.relight(f).image for f in frames]
    first = ClipRelighter(draft, light, threads=1, matte_method="selfie")
    for f in frames[:3]:
        first.relight(f)
    new = {"tracks", "tracks_ended", "track_next", "frame", "people_counts"}
    old = {k: np.array(v) for k, v in first.state().items() if k not in new}
    assert {"matte", "maps_box", "lights"} <= set(old)
    second = ClipRelighter(draft, light, threads=1, matte_method="selfie")
    second.load_state(old)
    assert [t.number for t in second.tracker.tracks] == [1]
    for f, expected in zip(frames[3:], want[3:]):
        np.testing.assert_array_equal(second.relight(f).image, expected)


def test_stability_zero_relights_a_group_as_relight_image_does(tmp_path, capsys, group):
    frames, _ = group
    src = write_frames(tmp_path / "in", frames[:2])
    base = ["--light", "studio", "--quality", "draft", "--threads", "1"]
    assert main(["video", str(src), "--out", str(tmp_path / "out"), "--stability", "0", *base]) == 0
    assert main(["image", str(src / "f_0002.png"), "--out", str(tmp_path / "still.png"), *base]) == 0
    capsys.readouterr()
    from PIL import Image

    with Image.open(tmp_path / "still.png") as im:
        image = json.loads(im.info["relight"])
    assert image["people"]["found"] == 2 and len(image["people"]["relit"]) == 2
    np.testing.assert_array_equal(read_photo(tmp_path / "out" / "f_0002.png")[0], read_photo(tmp_path / "still.png")[0])


def test_a_person_too_small_is_left_as_they_are(monkeypatch, draft, group):
    from relight.network import group as group_module

    frames, mattes = group
    # the right person's box is 137-145 px tall in the first two frames, the left one's 168-174
    monkeypatch.setattr(group_module, "MIN_PERSON_PX", 160)
    runner = ClipRelighter(draft, sh_light("studio", draft.sh_order), threads=1, matte_method="selfie")
    for frame, (left, right) in zip(frames[:2], mattes[:2]):
        r = runner.relight(frame)
        assert r.found == 2 and [p["track"] for p in r.people] == [1]
        assert [(x["person"], x["px"] < 160) for x in r.left] == [(2, True)]
        assert _changed(r.image, frame, left) > 0.5
        np.testing.assert_array_equal(r.image[right > 0], frame[right > 0])
    record = runner.record()
    assert (record["found"], record["relit"], record["frames_with_people_left"]) == (2, 1, 2)


def test_one_person_by_default_is_the_one_person_path_bit_for_bit(tmp_path, capsys):
    src = write_frames(tmp_path / "in", person_clip(4))
    base = ["--light", "studio", "--quality", "draft", "--threads", "1"]
    assert main(["video", str(src), "--out", str(tmp_path / "everyone"), *base]) == 0
    out, _ = capsys.readouterr()
    assert "people:" not in out  # one person: the lines as they were
    assert main(["video", str(src), "--out", str(tmp_path / "one"), "--person", "1", *base]) == 0
    for i in range(1, 5):
        name = f"f_{i:04d}.png"
        np.testing.assert_array_equal(read_photo(tmp_path / "everyone" / name)[0], read_photo(tmp_path / "one" / name)[0])
    record = json.loads((tmp_path / "everyone" / cli_video.JOB_FILE).read_text())["people"]
    assert (record["found"], record["relit"], len(record["tracks"])) == (1, 1, 1)


class _Filters:
    """A stand-in for a track's (MapSmoother, MatteSmoother): Tracker only keeps them."""

    def __init__(self):
        self.made = 0

    def __call__(self):
        self.made += 1
        return (None, None)


def test_the_tracker_follows_people_entering_leaving_and_missed():
    tracker = Tracker(_Filters())
    a, b = (0, 100, 0, 40), (0, 100, 60, 100)
    assert [t.number for t in tracker.match([a], 0)] == [1]
    # someone enters on the right: a new track; the left person keeps theirs though listed second
    assert [t.number for t in tracker.match([b, (0, 100, 2, 42)], 1)] == [2, 1]
    # the right person is missed for fewer than MISSED_FRAMES frames: back under their own number
    for f in range(2, 2 + MISSED_FRAMES - 1):
        assert [t.number for t in tracker.match([(0, 100, 2, 42)], f)] == [1]
    assert [t.number for t in tracker.match([(0, 100, 2, 42), (0, 100, 61, 101)], 6)] == [1, 2]
    # the right person leaves for good: their track ends after MISSED_FRAMES frames
    for f in range(7, 7 + MISSED_FRAMES):
        tracker.match([(0, 100, 2, 42)], f)
    assert [t.number for t in tracker.tracks] == [1]
    assert [(t["track"], t["frames"]) for t in tracker.record()] == [(1, [0, 11]), (2, [1, 6])]
    # someone who comes back after that is a new identity; a box overlapping no track starts one too
    assert [t.number for t in tracker.match([(0, 100, 2, 42), (0, 100, 60, 100)], 12)] == [1, 3]
    # one person and one track are the same person whatever the overlap (a one-person clip as before)
    single = Tracker(_Filters())
    single.match([a], 0)
    assert [t.number for t in single.match([(0, 100, 200, 240)], 1)] == [1]
