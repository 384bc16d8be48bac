"""Relight Photo add-on: everyone in the photo (issue 47).

Person "Everyone" (the default) relights every person the person matte finds with one press, under
the photo's one light (relight.network.group, as `relight image` without --person); Person N relights
that person alone; Save Layers writes the whole group's layers and one matte pass per person. The
photo: two bundled people pasted apart on a smooth background (evaluation/pasted_groups._cutout),
398 x 300; the person matte is the shipped one (Draft: its selfie segmenter finds both), the
relighting network the tests' random-weight tiny model.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

import bpy

from blender_addon.blender import bl_light
from blender_addon.logic import quality
from blender_addon.worker import engine, people, save_layers
from relight.files.exr import read_exr
from addon_support import addon_in_empty_scene, draw_panel, photo_session, pixels

H, W, GAP = 300, 398, 40


def _write_two_people(path) -> None:
    """obama_standing (260 px tall) and grace_hopper (200 px) standing 40 px apart, sRGB PNG."""
    from PIL import Image

    from evaluation.pasted_groups import _cutout

    img = np.empty((H, W, 3), np.float32)
    img[:] = np.linspace(0.55, 0.7, W)[None, :, None] * np.array([0.9, 0.95, 1.0])
    x = GAP
    for name, height in (("obama_standing", 260), ("grace_hopper", 200)):
        rgb, alpha = _cutout(name, height)
        w = rgb.shape[1]
        under = img[H - height:, x:x + w]
        img[H - height:, x:x + w] = rgb * alpha[..., None] + under * (1 - alpha[..., None])
        x += w + GAP
    assert x - GAP <= W
    Image.fromarray(np.round(img * 255).astype(np.uint8), "RGB").save(path)


@pytest.fixture
def group_photo(model, tmp_path):
    """The add-on in an empty scene, Mask Automatic at Draft with the tiny model and a turned studio
    light; the two people's photo loaded. Yields its image name."""
    with addon_in_empty_scene(tmp_path, model, mask_mode="AUTO", rotation=1.2, exposure=0.3, strength=1.0):
        _write_two_people(tmp_path / "two.png")
        yield bpy.data.images.load(str(tmp_path / "two.png")).name


def _core_group(run):
    """The two people as the core decomposes them for `relight image` (everyone, no --person)."""
    from relight.network.group import decompose_people

    s = bpy.context.scene.relight_photo
    preset = quality.preset(s.quality)
    return decompose_people(engine.open_relighter(run.model_path), run.photo, matte_method=preset.matte_method,
                            working_size=preset.working_size, **quality.network_options(s.quality))


def _mattes(run):
    from relight.person.matte import mattes_of_checked_photo

    return [m.alpha for m in mattes_of_checked_photo(run.photo, method=quality.preset(run.quality).matte_method)]


def test_everyone_is_the_default_and_one_press_relights_both_under_one_light(group_photo):
    name = group_photo
    s = bpy.context.scene.relight_photo
    assert s.person == "0"  # Everyone
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    run = photo_session(name)
    assert isinstance(run.decomposition, people.People) and len(run.decomposition.people) == 2
    assert (s.people_found, s.people_relit, run.people) == (2, 2, 2)
    assert any("2 people found, 2 relit" in text for kind, text in draw_panel(name) if kind == "label")
    assert bpy.context.window_manager.relight_photo_status.message.startswith(f"Relit '{name}' (2 people, one light) in")

    first, second = _mattes(run)
    relit = pixels(f"{name}.relit")[..., :3]
    nobody = (first == 0) & (second == 0)
    np.testing.assert_array_equal(relit[nobody], run.photo[nobody])  # the background is untouched
    for matte in (first, second):  # each person's pixels change
        inside = matte > 0.99
        assert inside.sum() > 2000
        assert np.abs(relit[inside] - run.photo[inside]).mean() > 0.02
    # the image is the core's group relight (relight image, everyone): one light for both
    group = _core_group(run)
    np.testing.assert_array_equal(run.decomposition.people[0].light, run.decomposition.people[1].light)
    np.testing.assert_allclose(run.decomposition.light, group.people[0].light, atol=1e-6)
    light, rotation, exposure, _ = bl_light.current_dials(bpy.context, run)
    want = group.relight(np.asarray(engine.coefficients(run.decomposition, light, rotation), np.float64),
                         exposure)
    np.testing.assert_allclose(relit, want, atol=1e-5)
    # the alpha output is the mattes' sum, the cut-out shows both
    np.testing.assert_allclose(pixels(f"{name}.alpha")[..., 0], first + second, atol=1e-6)
    np.testing.assert_allclose(pixels(f"{name}.matte")[..., 3], first + second, atol=1e-6)

    # a dial relights both again, no network run: +1 EV
    s.exposure = 1.3
    again = pixels(f"{name}.relit")[..., :3]
    np.testing.assert_array_equal(again[nobody], run.photo[nobody])
    coeffs = np.asarray(engine.coefficients(run.decomposition, light, rotation), np.float64)
    np.testing.assert_allclose(again, group.relight(coeffs, 1.3), atol=1e-5)
    for matte in (first, second):  # each person twice as bright, up to the soft edge's share of the photo
        inside = matte > 0.99
        assert 1.9 < again[inside].mean() / relit[inside].mean() < 2.01

    # Photo Light -> World takes the group's one light; Compositing Setup's proxy is the largest person's
    assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}
    assert bpy.ops.relight_photo.compositing_setup(image_name=name) == {"FINISHED"}
    from blender_addon.blender import bl_images
    from blender_addon.logic import person_proxy

    catcher = next(o for o in bpy.data.objects if o.get(bl_images.OUTPUT_OF) == run.photo_id
                   and o.get(bl_images.OUTPUT_LAYER) == "person")
    largest = run.decomposition.people[0]
    assert len(catcher.data.polygons) == int((largest.alpha >= person_proxy.COVERAGE).sum()) > 0


def test_the_screen_sized_preview_of_a_large_photo_shows_everyone_relit(group_photo):
    name = group_photo
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    run = photo_session(name)
    # the preview a dial shows on a photo longer than 1.25 x its long side (here 200 px for 398)
    preview = engine.preview_decomposition(run.decomposition, 200)
    assert isinstance(preview, people.People) and preview.size == (151, 200) and len(preview.people) == 2
    light, rotation, exposure, _ = bl_light.current_dials(bpy.context, run)
    rgba = engine.relit_rgba(preview, light, rotation, exposure, 1.0).reshape(151, 200, 4)[::-1]
    nobody = preview.mask == 0
    np.testing.assert_array_equal(rgba[..., :3][nobody], preview.photo[nobody])
    for person in preview.people:
        inside = person.mask > 0.99
        assert inside.sum() > 500
        assert np.abs(rgba[..., :3][inside] - preview.photo[inside]).mean() > 0.02


def test_person_two_relights_only_them(group_photo):
    name = group_photo
    s = bpy.context.scene.relight_photo
    s.people_found = 2
    s.person = "2"
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    run = photo_session(name)
    assert not isinstance(run.decomposition, people.People)
    first, second = _mattes(run)
    np.testing.assert_array_equal(run.decomposition.mask, second)
    relit = pixels(f"{name}.relit")[..., :3]
    outside = second == 0
    np.testing.assert_array_equal(relit[outside], run.photo[outside])  # the first person too
    assert (first[outside] > 0.99).sum() > 2000
    inside = second > 0.99
    assert np.abs(relit[inside] - run.photo[inside]).mean() > 0.02


def test_save_layers_writes_the_group_and_a_matte_per_person(group_photo, tmp_path):
    name = group_photo
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    run = photo_session(name)
    target = tmp_path / "layers.exr"
    assert bpy.ops.relight_photo.save_layers(filepath=str(target), image_name=name) == {"FINISHED"}
    exr = read_exr(target)
    assert sorted(exr) == sorted(save_layers.channel_names(2))
    p1, p2 = exr["Relight.Person1.A"], exr["Relight.Person2.A"]
    first, second = _mattes(run)
    np.testing.assert_allclose(p1, first, atol=1e-6)
    np.testing.assert_allclose(p2, second, atol=1e-6)
    # the mattes sum to the Alpha pass (float32 round-off of one addition)
    np.testing.assert_allclose(p1 + p2, exr["Relight.Alpha.A"], atol=1e-6)
    # albedo, shading: the people's sum; shadow: the product of theirs; relit: the image
    light, rotation, exposure, _ = bl_light.current_dials(bpy.context, run)
    coeffs = engine.coefficients(run.decomposition, light, rotation)
    a, b = run.decomposition.people
    for layer in ("albedo", "shading"):
        got = np.dstack([exr[f"Relight.{layer.capitalize()}.{c}"] for c in "RGB"])
        np.testing.assert_allclose(got, a.layer(layer, coeffs, exposure) + b.layer(layer, coeffs, exposure),
                                   atol=1e-5)
    np.testing.assert_allclose(exr["Relight.Shadow.X"],
                               a.shadow_layer(coeffs, exposure) * b.shadow_layer(coeffs, exposure), atol=1e-6)
    relit = np.dstack([exr[f"Relight.Relit.{c}"] for c in "RGB"])
    np.testing.assert_allclose(relit, pixels(f"{name}.relit")[..., :3], atol=1e-6)
    assert math.isclose(float(exr["Relight.Relit.A"].min()), 1.0)


def _as_saved(run, photo, masks):
    """The core's Group of the session's people with the maps the saved relight holds (float16:
    engine._HALF; light and alpha float32) over `photo` with `masks`: what a restore must relight."""
    from relight.network.decomposition import Decomposition
    from relight.network.group import Group

    def half(a):
        return np.asarray(a).astype(np.float16).astype(np.float32)

    return Group(people=[Decomposition(albedo=half(d.albedo), transport=half(d.transport), residual=half(d.residual),
                                       light=d.light, alpha=d.alpha, box=d.box, working_size=d.working_size,
                                       photo=photo, photo_working=half(d.photo_working), mask=mask,
                                       sh_order=d.sh_order) for d, mask in zip(run.decomposition.people, masks)])


def test_everyone_relit_survives_save_and_reopen_with_and_without_the_photo(group_photo, tmp_path):
    from blender_addon.blender import bl_images
    from blender_addon.worker import state

    name = group_photo
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    run = photo_session(name)
    masks = [d.mask for d in run.decomposition.people]
    light, rotation, exposure, _ = bl_light.current_dials(bpy.context, run)
    coeffs = np.asarray(engine.coefficients(run.decomposition, light, rotation), np.float64)
    # with the photo: the photo read again, each person's matte found again; without it: the
    # saved copy of the photo and the mattes (float16)
    want = {"photo": _as_saved(run, run.photo, masks).relight(coeffs, exposure)}
    saved_photo = run.photo.astype(np.float16).astype(np.float32)
    want["saved"] = _as_saved(run, saved_photo, [m.astype(np.float16).astype(np.float32) for m in masks]) \
        .relight(coeffs, exposure)
    pid = bpy.data.images[name][bl_images.PHOTO_ID]
    blend = tmp_path / "group.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(blend)) == {"FINISHED"}
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    run = state.SESSIONS[pid]
    assert run.saved_to and isinstance(run.decomposition, people.People)  # restored, not relit
    assert len(run.decomposition.people) == 2 and run.people == 2
    for d, mask in zip(run.decomposition.people, masks):
        np.testing.assert_array_equal(d.mask, mask)
    np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], want["photo"], atol=1e-5)
    np.testing.assert_allclose(pixels(f"{name}.alpha")[..., 0], masks[0] + masks[1], atol=1e-6)
    # without the photo: every output from the saved relight alone, both people relit
    (tmp_path / "two.png").rename(tmp_path / "moved.png")
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    run = state.SESSIONS[pid]
    assert run.photo_missing and isinstance(run.decomposition, people.People)
    np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], want["saved"], atol=1e-5)


def test_relight_again_under_everyone_does_not_look_for_the_people_again(group_photo, monkeypatch):
    """A second press on the same photo under Everyone reuses the people the first found (the person
    matte is not run again) and gives the same people; another segmenter looks for them again."""
    from relight.person import matte as segmenter

    name = group_photo
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    first = photo_session(name)
    found, find = [], segmenter.mattes_of_checked_photo
    monkeypatch.setattr(segmenter, "mattes_of_checked_photo", lambda *a, **k: found.append(1) or find(*a, **k))
    s = bpy.context.scene.relight_photo
    s.rotation = math.radians(60.0)
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    again = photo_session(name)
    assert found == [] and isinstance(again.decomposition, people.People)
    assert [m.alpha is n.alpha for m, n in zip(again.decomposition.group.mattes, first.decomposition.group.mattes)] \
        == [True, True]
    from relight.network.quality import PRESETS

    other = next(p for p in PRESETS if p.matte_method != quality.preset(s.quality).matte_method)
    s.quality = other.key.upper()
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    assert found == [1]
