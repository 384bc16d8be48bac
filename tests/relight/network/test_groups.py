"""Group photos (issue 47): everyone found, separated when they touch or overlap, relit together under one
light; a person too small left as they are and said so; the one-person path unchanged."""

from __future__ import annotations

import json

import numpy as np
import pytest

from evaluation.pasted_groups import PEOPLE, pasted_group
from relight.files.photo import write_image
from relight.lighting.light import sh_light
from relight.network import group as group_module
from relight.network.group import MIN_PERSON_PX, decompose_people
from relight.network.quality import preset
from relight.network.runtime import Relighter
from relight.person import matte as segmenter
from relight.imaging.box import Box

DRAFT = preset("draft").decompose_options(working_size=False)


@pytest.fixture(scope="module")
def relighter():
    return Relighter(working_size=128)


def _pair(names, gap):
    """Two bundled people side by side, bottom-aligned, `gap` px apart (0: touching), and their true mattes."""
    from evaluation.pasted_groups import _cutout

    (a_rgb, a), (b_rgb, b) = _cutout(names[0], 400), _cutout(names[1], 400)
    width = a.shape[1] + gap + b.shape[1]
    canvas = np.full((400, width, 3), 0.75, np.float32)
    mattes = np.zeros((2, 400, width), np.float32)
    for k, (rgb, m, x) in enumerate(((a_rgb, a, 0), (b_rgb, b, a.shape[1] + gap))):
        canvas[:, x:x + m.shape[1]] = m[..., None] * rgb + (1 - m[..., None]) * canvas[:, x:x + m.shape[1]]
        mattes[k, :, x:x + m.shape[1]] = m
    from relight.imaging.colour import srgb_decode
    return srgb_decode(canvas).astype(np.float32), mattes


def _iou(a, b):
    return ((a > 0.5) & (b > 0.5)).sum() / ((a > 0.5) | (b > 0.5)).sum()


@pytest.mark.parametrize("names, gap", [(("grace_hopper", "astronaut"), 0), (("obama", "biden"), 0),
                                        (("grace_hopper", "astronaut"), 200)])
def test_two_people_touching_or_apart_are_two(names, gap):
    """The issue's cases: grace_hopper and the astronaut touching were one person; Obama and Biden too."""
    photo, truth = _pair(names, gap)
    mattes = segmenter.mattes_of_checked_photo(photo)
    assert len(mattes) == 2
    for t in truth:   # each true person has a matte of their own, not their neighbour's
        assert max(_iou(m.alpha, t) for m in mattes) > 0.8
    assert np.all(np.sum([m.alpha for m in mattes], axis=0) <= 1.0 + 1e-6)


def test_a_pasted_group_overlapping_is_counted_and_separated():
    """Three people, each overlapping the next (the nearer in front): three mattes, each on its person."""
    g = pasted_group(1)
    assert len(g.names) == 3 and g.spacings == ["overlapping", "overlapping"]
    mattes = segmenter.mattes_of_checked_photo(g.photo)
    assert len(mattes) == 3
    assert min(max(_iou(m.alpha, t) for m in mattes) for t in g.mattes) > 0.8


def test_one_person_mattes_are_the_one_person_matte():
    """On every bundled single-person photo: one person, the very matte person_matte gives."""
    from relight.files.photo import read_photo

    for name in PEOPLE[:3]:
        suffix = ".png" if name == "camera" else ".jpg"
        photo, _ = read_photo(f"evaluation/data/matte_eval/{name}{suffix}")
        mattes = segmenter.mattes_of_checked_photo(photo)
        assert len(mattes) == 1
        assert np.array_equal(mattes[0].alpha, segmenter.person_matte(photo).alpha)


def test_the_one_person_path_is_unchanged(relighter):
    """One person found: the group's relight is the single decomposition's, bit for bit."""
    from relight.files.photo import read_photo

    photo, _ = read_photo("relight/data/examples/grace_hopper.jpg")
    light = np.asarray(sh_light("sunset", 4), np.float64)
    group = decompose_people(relighter, photo, **DRAFT)
    alone = relighter.decompose(photo, **DRAFT)
    assert group.count == 1 and group.record()["relit"] == [1]
    assert np.array_equal(group.relight(light), alone.relight(light))


def test_a_group_is_relit_together_under_one_light(relighter):
    """Two people: one light for both (the mean of their own estimates), each person's change added
    over the photo within their matte, the background bit for bit."""
    photo, _ = _pair(("obama", "biden"), 40)
    group = decompose_people(relighter, photo, **DRAFT)
    assert group.count == 2 and len(group.people) == 2
    assert np.array_equal(group.people[0].light, group.people[1].light)
    light = np.asarray(sh_light("sunset", 4), np.float64)
    out = group.relight(light)
    mattes = [d.person_matte.alpha for d in group.people]
    nobody = np.sum(mattes, axis=0) == 0
    assert np.array_equal(out[nobody], photo[nobody])
    expected = photo.copy()
    for d in group.people:   # each person alone over the photo, their change added
        expected += d.relight(light) - photo
    assert np.abs(out - expected).max() < 1e-5 * max(1.0, float(np.abs(expected).max()))
    for m in mattes:         # everyone is relit
        assert np.abs(out - photo)[m > 0.99].mean() > 0.01 * photo[m > 0.99].mean()


def test_a_person_too_small_is_left_as_they_are(relighter, monkeypatch):
    """A second person under MIN_PERSON_PX is left untouched and the record says why."""
    photo, truth = _pair(("obama", "biden"), 40)
    big = segmenter.mattes_of_checked_photo(photo)[0]
    tiny = np.zeros_like(big.alpha)
    tiny[10:10 + MIN_PERSON_PX - 8, 5:25] = 1.0     # a speck of a person, far from the others
    monkeypatch.setattr(segmenter, "mattes_of_checked_photo", lambda *a, **k: [
        segmenter.PersonMatte(big.alpha, big.box, 1, 2),
        segmenter.PersonMatte(tiny, Box.around(tiny), 2, 2)])
    group = decompose_people(relighter, photo, **DRAFT)
    record = group.record()
    assert record["found"] == 2 and record["relit"] == [1]
    assert record["left"][0]["person"] == 2 and "too small" in record["left"][0]["why"]
    out = group.relight(np.asarray(sh_light("sunset", 4), np.float64))
    assert np.array_equal(out[tiny > 0], photo[tiny > 0])


def test_relight_image_relights_everyone_and_records_the_count(tmp_path, capsys):
    from relight.cli import main

    photo, _ = _pair(("grace_hopper", "astronaut"), 0)
    path = tmp_path / "pair.png"
    write_image(path, photo)
    # Draft's matte is the selfie segmenter's alone, which sees two people touching as one: Balanced
    assert main(["image", str(path), "--light", "sunset", "--quality", "balanced", "--json",
                 "--out", str(tmp_path / "out.png")]) == 0
    record = json.loads(capsys.readouterr().out.splitlines()[0])
    assert record["people"]["found"] == 2 and record["people"]["relit"] == [1, 2]
    # --person picks one: the other is left as it was
    assert main(["image", str(path), "--light", "sunset", "--quality", "balanced", "--person", "2", "--json",
                 "--out", str(tmp_path / "two.png")]) == 0
    record = json.loads(capsys.readouterr().out.splitlines()[0])
    assert "people" not in record


def test_min_person_px_is_below_every_working_size():
    from relight.network.quality import PRESETS

    assert all(MIN_PERSON_PX < q.working_size for q in PRESETS)
    assert group_module.MIN_PERSON_PX == MIN_PERSON_PX


def test_relight_light_is_the_light_of_everyone(tmp_path, capsys):
    """`relight light` on a group photo: the photo's one light, fitted from every person (the record says
    how many), which is the mean of the people's own estimates."""
    from relight.cli import main

    photo, _ = _pair(("obama", "biden"), 40)
    path = tmp_path / "pair.png"
    write_image(path, photo)
    assert main(["light", str(path), "--quality", "draft", "--json", "--out", str(tmp_path / "light.exr")]) == 0
    record = json.loads(capsys.readouterr().out.splitlines()[0])
    assert record["people"]["found"] == 2 and record["people"]["relit"] == [1, 2]
    from relight.files.photo import read_photo

    group = decompose_people(Relighter(working_size=128), read_photo(path)[0], **DRAFT)  # the photo as saved
    expected = np.mean([np.asarray(d.light, np.float64) for d in group.people], axis=0)
    assert np.abs(np.asarray(record["coeffs"]) - expected).max() < 1e-6 * max(1.0, float(np.abs(expected).max()))


def test_mattes_found_before_are_not_looked_for_again(relighter, monkeypatch):
    """decompose_people(mattes=group.mattes): the same people, bit for bit, without the segmenters."""
    photo, _ = _pair(("obama", "biden"), 40)
    first = decompose_people(relighter, photo, **DRAFT)

    def segment(*args, **kwargs):
        raise AssertionError("the person matte ran again")

    monkeypatch.setattr(segmenter, "mattes_of_checked_photo", segment)
    again = decompose_people(relighter, photo, mattes=first.mattes, **DRAFT)
    light = np.asarray(sh_light("sunset", 4), np.float64)
    assert again.count == first.count == len(first.mattes) == 2
    assert np.array_equal(again.relight(light), first.relight(light))
