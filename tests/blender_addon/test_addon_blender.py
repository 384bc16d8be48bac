"""Relight Photo add-on under headless bpy: registration, the Relight operator in test mode,
live updates from the cached decomposition, masks, light transfer, HDR files and saving layers."""

from __future__ import annotations

import math

import numpy as np

import bpy

import blender_addon
from blender_addon.blender import bl_dials, bl_images, bl_session
from blender_addon.worker import state
from relight.files.exr import read_exr, write_exr
from relight.lighting.light import sh_light

from addon_support import H, W, pixels
from addon_panel_support import addon, settings  # noqa: F401 (the fixtures)
from addon_panel_support import TIGHT, relight, session
from tiny_model import ORDER



def test_register_unregister_register_again(addon):
    assert hasattr(bpy.types, "RELIGHT_PHOTO_PT_panel")
    panel = bpy.types.RELIGHT_PHOTO_PT_panel
    assert (panel.bl_space_type, panel.bl_region_type, panel.bl_category, panel.bl_label) == \
        ("IMAGE_EDITOR", "UI", "Relight", "Relight Photo")
    blender_addon.unregister()
    assert not hasattr(bpy.types, "RELIGHT_PHOTO_PT_panel")
    assert not hasattr(bpy.types.Scene, "relight_photo")
    assert bl_dials.on_depsgraph_update not in bpy.app.handlers.depsgraph_update_post
    blender_addon.register()
    assert hasattr(bpy.types.Scene, "relight_photo")
    assert bpy.app.handlers.depsgraph_update_post[:].count(bl_dials.on_depsgraph_update) == 1
    assert "relight_photo.relight" in {f"relight_photo.{n}" for n in dir(bpy.ops.relight_photo)}


# ------------------------------------------------------------------ the operator

def test_relight_writes_every_layer(addon, settings):
    name = addon["photo"]
    assert relight(name) == {"FINISHED"}
    for layer in ("relit", "albedo", "shading", "residual", "alpha"):
        image = bpy.data.images[f"{name}.{layer}"]
        assert tuple(image.size) == (W, H) and image.is_float
        assert image.colorspace_settings.name == ("Non-Color" if layer == "alpha" else "Linear Rec.709")
        assert np.all(np.isfinite(pixels(image.name)))
    albedo = pixels(f"{name}.albedo")[..., :3]
    alpha = pixels(f"{name}.alpha")[..., 0]
    assert albedo.min() >= 0 and albedo.max() <= 1 + TIGHT
    assert alpha.min() >= 0 and alpha.max() <= 1
    # the relit image is the runtime's relight of the cached decomposition
    run = session(name)
    expected = run.decomposition.relight(sh_light("studio", ORDER))
    np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], expected, atol=TIGHT)
    # and the photo is the PNG decoded to linear (what relight.files.photo reads)
    from relight.files.photo import read_photo

    linear, _ = read_photo(addon["folder"] / "person.png")
    np.testing.assert_allclose(run.photo, linear, atol=1e-6)


def test_invoking_without_a_window_runs_synchronously(addon, settings):
    # what a script or `blender -b` gets from the UI-style call
    assert bpy.ops.relight_photo.relight("INVOKE_DEFAULT", image_name=addon["photo"]) == {"FINISHED"}
    assert "job" not in state.RUNNING


def test_rotating_the_light_follows_the_sh_rotation(addon, settings):
    name = addon["photo"]
    relight(name)
    before = pixels(f"{name}.relit")[..., :3].copy()
    network_runs = session(name)
    settings.rotation = math.radians(90.0)  # property update: no network run
    assert session(name) is network_runs
    after = pixels(f"{name}.relit")[..., :3]
    rotated = sh_light("studio", ORDER, rotation_deg=90.0)  # the map recipe: project, rotate, normalize
    expected = network_runs.decomposition.relight(rotated)
    np.testing.assert_allclose(after, expected, atol=TIGHT)
    assert np.abs(after - before).max() > 1e-2  # the light really moved


def test_exposure_and_strength_update_live(addon, settings):
    name = addon["photo"]
    relight(name)
    d = session(name).decomposition
    photo = session(name).photo
    settings.exposure = 1.0
    np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], d.relight(sh_light("studio", ORDER), exposure_ev=1.0),
                               atol=2 * TIGHT)
    settings.strength = 0.25
    expected = photo + 0.25 * (d.relight(sh_light("studio", ORDER), exposure_ev=1.0) - photo)
    np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], expected, atol=2 * TIGHT)
    settings.strength = 0.0
    np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], photo, atol=1e-7)


def test_with_a_ui_dial_changes_are_coalesced_into_one_timer(addon, settings, monkeypatch):
    name = addon["photo"]
    relight(name)
    before = pixels(f"{name}.relit").copy()
    monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)
    settings.rotation = math.radians(10.0)
    settings.rotation = math.radians(20.0)
    settings.exposure = 0.5
    try:
        # nothing recomputed yet: one timer is waiting for the UI to be idle
        assert bpy.app.timers.is_registered(bl_dials.deferred_refresh)
        np.testing.assert_array_equal(pixels(f"{name}.relit"), before)
        assert bl_dials.deferred_refresh() is None  # what Blender's timer calls, once
        expected = session(name).decomposition.relight(sh_light("studio", ORDER, rotation_deg=20.0), exposure_ev=0.5)
        np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], expected, atol=2 * TIGHT)
    finally:
        if bpy.app.timers.is_registered(bl_dials.deferred_refresh):
            bpy.app.timers.unregister(bl_dials.deferred_refresh)


def test_output_image_in_the_editor_maps_back_to_its_photo(addon, settings):
    name = addon["photo"]
    relight(name)
    # running again on the '.relit' image relights the photo, not the output
    assert relight(f"{name}.relit") == {"FINISHED"}
    assert settings.last_photo_id == bpy.data.images[name][bl_images.PHOTO_ID]
    assert f"{name}.relit.relit" not in bpy.data.images


def test_deleted_output_is_recreated_by_name(addon, settings):
    # undo or the user may remove output images: nothing keeps a pointer to them
    name = addon["photo"]
    relight(name)
    bpy.data.images.remove(bpy.data.images[f"{name}.relit"])
    settings.rotation = math.radians(30.0)
    assert f"{name}.relit" in bpy.data.images


def test_mask_from_the_photos_alpha(addon, settings):
    name = addon["cutout"]
    settings.mask_mode = "IMAGE_ALPHA"
    assert relight(name) == {"FINISHED"}
    alpha = pixels(f"{name}.alpha")[..., 0]
    source = pixels(name)[..., 3]
    # the user's mask is the matte: alpha 0 outside, 1 inside the figure
    np.testing.assert_allclose(alpha, source, atol=1e-6)
    relit = pixels(f"{name}.relit")[..., :3]
    np.testing.assert_array_equal(relit[source == 0], session(name).photo[source == 0])


def test_mask_from_another_image_uses_its_grey_code_values(addon, settings, tmp_path):
    from PIL import Image

    y, x = np.mgrid[0:H, 0:W]
    grey = np.where(x < W // 2, 255, 128).astype(np.uint8)  # 128 is 0.502 as stored, 0.216 decoded
    grey[: H // 4] = 0
    Image.fromarray(grey, "L").save(tmp_path / "mask_grey.png")
    mask = bpy.data.images.load(str(tmp_path / "mask_grey.png"))
    settings.mask_mode = "IMAGE"
    settings.mask_image = mask
    try:
        assert relight(addon["photo"]) == {"FINISHED"}
        alpha = pixels(f"{addon['photo']}.alpha")[..., 0]
        np.testing.assert_allclose(alpha, grey / 255.0, atol=1e-6)
    finally:
        settings.mask_image = None
        bpy.data.images.remove(mask)


def test_light_transfer_from_another_photo(addon, settings):
    src = bpy.data.images.load(str(addon["folder"] / "cutout.png"), check_existing=False)
    src.name = "lightsrc"
    settings.light_kind = "IMAGE"
    settings.light_image = src
    name = addon["photo"]
    assert relight(name) == {"FINISHED"}
    key = (src[bl_images.PHOTO_ID], str(addon["model"]), "DRAFT")
    other = state.LIGHT_SOURCES[key]
    expected = session(name).decomposition.relight(sh_light(other, ORDER))
    np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], expected, atol=TIGHT)


def test_hdr_file_light(addon, settings, tmp_path):
    env = np.zeros((16, 32, 3), np.float32) + 0.2
    env[:8, 8:12] = 5.0  # a bright patch in the upper sky
    path = tmp_path / "patch.exr"
    write_exr(path, {c: env[..., i] for i, c in enumerate("RGB")})
    settings.light_kind = "HDR"
    settings.hdr_path = str(path)
    name = addon["photo"]
    assert relight(name) == {"FINISHED"}
    expected = session(name).decomposition.relight(sh_light(str(path), ORDER))
    np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], expected, atol=TIGHT)


def test_save_layers_writes_a_multilayer_exr(addon, settings, tmp_path):
    name = addon["photo"]
    relight(name)
    settings.rotation = math.radians(45.0)
    out = tmp_path / "layers.exr"
    assert bpy.ops.relight_photo.save_layers(filepath=str(out), image_name=name) == {"FINISHED"}
    ch = read_exr(out)
    for p in ("Relit", "Albedo", "Shading", "Residual"):
        assert all(f"Relight.{p}.{c}" in ch for c in "RGB")
    relit = np.dstack([ch[f"Relight.Relit.{c}"] for c in "RGB"])
    np.testing.assert_allclose(relit, pixels(f"{name}.relit")[..., :3], atol=1e-7)
    # albedo * shading + residual is the relit person wherever the matte is 1
    albedo = np.dstack([ch[f"Relight.Albedo.{c}"] for c in "RGB"])
    shading = np.dstack([ch[f"Relight.Shading.{c}"] for c in "RGB"])
    residual = np.dstack([ch[f"Relight.Residual.{c}"] for c in "RGB"])
    assert ch["Relight.Alpha.A"].shape == (H, W)
    assert np.all(np.isfinite(albedo * shading + residual))

