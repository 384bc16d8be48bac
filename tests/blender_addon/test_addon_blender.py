"""Relight Photo add-on under headless bpy: registration, the Relight operator in
test mode, live updates from the cached decomposition, World lights, saving
layers, and every error the user can meet (asserted on the report text)."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import bpy

import blender_addon
from blender_addon.blender import bl_dials, bl_images, bl_light, bl_ops, bl_session, bl_world
from blender_addon.worker import state
from relight.lighting import presets, sh_projection, sh_rotation
from relight.files.exr import read_exr, write_exr
from relight.lighting.light import sh_light

from addon_support import H, W, draw_panel, new_node_world, pixels, write_person_png
from tiny_model import ORDER

# float32 arithmetic on values <= ~4 through a few dozen operations (SH dot
# products of 25 terms, bilinear taps, blend): far below 1e-5
TIGHT = 1e-5


@pytest.fixture(scope="module")
def addon(model, tmp_path_factory):
    folder = tmp_path_factory.mktemp("addon_photos")
    write_person_png(folder / "person.png")
    write_person_png(folder / "cutout.png", with_alpha=True)
    blender_addon.register()
    # the World tests here read the World alone: the startup scene's lamp would join its light
    # (lamps in, issue 38: tests/blender_addon/test_addon_lamps.py)
    for lamp in [obj for obj in bpy.data.objects if obj.type == "LIGHT"]:
        bpy.data.objects.remove(lamp)
    photo = bpy.data.images.load(str(folder / "person.png"))
    cutout = bpy.data.images.load(str(folder / "cutout.png"))
    yield {"model": model, "photo": photo.name, "cutout": cutout.name, "folder": folder}
    for image in list(bpy.data.images):
        if image.name.startswith(("person.png", "cutout.png", "mask", "lightsrc")):
            bpy.data.images.remove(image)
    blender_addon.unregister()


@pytest.fixture
def settings(addon):
    s = bpy.context.scene.relight_photo
    s.model_path = str(addon["model"])
    s.quality = "DRAFT"
    s.mask_mode = "NETWORK"  # the synthetic figure is no person to the person matte
    s.light_kind = "PRESET"
    s.preset = "studio"
    s.rotation = 0.0
    s.exposure = 0.0
    s.strength = 1.0
    s.hdr_path = ""
    s.light_image = None
    s.mask_image = None
    yield s
    s.light_kind = "PRESET"


def session(image_name: str) -> state.PhotoSession:
    """The add-on's session of a photo, found by the photo's stable id."""
    return state.SESSIONS[bpy.data.images[image_name][bl_images.PHOTO_ID]]


def relight(image_name: str, **kw):
    return bpy.ops.relight_photo.relight(image_name=image_name, synchronous=True, **kw)


# ------------------------------------------------------------------ registration

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


# ------------------------------------------------------------------ World light

def _env_world(path: Path, mapping_rotation=(0.0, 0.0, 0.0), vector_type="POINT"):
    world = new_node_world("relight_test_world")
    tree = world.node_tree
    if tree is None:  # Blender < 5 needs nodes switched on
        world.use_nodes = True
        tree = world.node_tree
    background = next(n for n in tree.nodes if n.type == "BACKGROUND")
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(str(path), check_existing=True)
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.vector_type = vector_type
    mapping.inputs["Rotation"].default_value = mapping_rotation
    coords = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(env.outputs["Color"], background.inputs["Color"])
    tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    tree.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    return world


def test_world_environment_texture_equals_relights_projection_of_the_file(addon, settings):
    path = presets.preset_path("studio")
    world = _env_world(path, (0.0, 0.0, math.radians(90.0)))
    scene = bpy.context.scene
    old = scene.world
    try:
        scene.world = world
        settings.light_kind = "WORLD"
        world_light, rotation = bl_light.target_light(bpy.context, ORDER, "")
        assert rotation == pytest.approx(-90.0)  # Mapping rotates the lookup: the light turns back
        coeffs = world_light.at(0.0)
        expected = sh_light(str(path), ORDER)
        # the same half-float texels read by Blender and by OpenEXR: equal up to
        # float32 summation order in the projection (~1e-6 relative)
        np.testing.assert_allclose(coeffs, expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())
    finally:
        scene.world = old
        bpy.data.worlds.remove(world)


def test_editing_the_world_relights_live(addon, settings):
    import types

    path = presets.preset_path("studio")
    world = _env_world(path)
    scene = bpy.context.scene
    old = scene.world
    updated = types.SimpleNamespace(id_type_updated=lambda kind: kind == "WORLD")
    try:
        scene.world = world
        settings.light_kind = "WORLD"
        name = addon["photo"]
        relight(name)
        d = session(name).decomposition
        np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], d.relight(sh_light(str(path), ORDER)), atol=TIGHT)
        # the user turns the Mapping node: Blender sends a depsgraph update
        world.node_tree.nodes["Mapping"].inputs["Rotation"].default_value[2] = math.radians(45.0)
        bl_dials.on_depsgraph_update(scene, updated)
        np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], d.relight(sh_light(str(path), ORDER, rotation_deg=-45.0)),
                                   atol=TIGHT)
    finally:
        scene.world = old
        bpy.data.worlds.remove(world)


def test_float_exr_photo_is_taken_as_linear(addon, settings, tmp_path):
    rng = np.random.default_rng(5)
    linear = rng.uniform(0.0, 3.0, (H, W, 3)).astype(np.float32)  # HDR values above 1 too
    path = tmp_path / "hdr_photo.exr"
    write_exr(path, {c: linear[..., i] for i, c in enumerate("RGB")})
    image = bpy.data.images.load(str(path))
    try:
        assert relight(image.name) == {"FINISHED"}
        np.testing.assert_array_equal(session(image.name).photo, linear)
    finally:
        for n in [i.name for i in bpy.data.images if i.name.startswith("hdr_photo.exr")]:
            bpy.data.images.remove(bpy.data.images[n])


def test_baked_world_agrees_with_the_direct_read_including_the_mapping_sign(addon, settings):
    # the Cycles bake renders what Blender shows, so it checks both the panorama
    # orientation and the sign given to the Mapping node's rotation
    path = presets.preset_path("studio")
    for vector_type in ("POINT", "TEXTURE"):
        world = _env_world(path, (0.0, 0.0, math.radians(60.0)), vector_type)
        try:
            direct = bl_world.read_world(world)
            assert direct.source.startswith("environment texture")
            want = sh_rotation.rotate(sh_projection.project_equirect(direct.equirect, ORDER),
                                      sh_rotation.z_rotation(direct.rotation_deg))
            baked = sh_projection.project_equirect(bl_world.bake_world(world, 128), ORDER)
            # 128 x 64 panorama with a 0.5 px filter vs the 512 x 256 file: measured
            # relative L2 difference 0.018; the opposite sign or no rotation gives 1.4
            err = np.linalg.norm(baked - want) / np.linalg.norm(want)
            assert err < 0.05, (vector_type, err)
        finally:
            bpy.data.worlds.remove(world)


def test_mapping_without_generated_coordinates_is_baked(addon, settings):
    # an unlinked Mapping input is the constant (0, 0, 0): the World is one flat
    # colour, which only the bake sees; reading the image directly would be wrong
    world = _env_world(presets.preset_path("studio"))
    try:
        tree = world.node_tree
        tree.links.remove(tree.nodes["Mapping"].inputs["Vector"].links[0])
        light = bl_world.read_world(world)
        assert light.source == "baked procedural world"
        spread = light.equirect.std(axis=(0, 1)) / light.equirect.mean(axis=(0, 1))
        assert np.all(spread < 1e-3), spread  # flat, up to the EXR's float rounding
    finally:
        bpy.data.worlds.remove(world)


def test_procedural_world_is_baked_and_tracked(addon, settings):
    world = new_node_world("relight_sky")
    tree = world.node_tree
    background = next(n for n in tree.nodes if n.type == "BACKGROUND")
    sky = tree.nodes.new("ShaderNodeTexSky")
    tree.links.new(sky.outputs["Color"], background.inputs["Color"])
    try:
        light = bl_world.read_world(world)
        assert light.source == "baked procedural world"
        assert light.equirect.shape == (64, 128, 3) and np.all(np.isfinite(light.equirect))
        # the sky is above the horizon: the upper half is brighter than the lower
        assert light.equirect[:32].mean() > light.equirect[32:].mean()
        key = bl_world.fingerprint(world)
        assert bl_world.fingerprint(world) == key
        sky.sun_elevation = 0.1
        assert bl_world.fingerprint(world) != key
    finally:
        bpy.data.worlds.remove(world)


# ------------------------------------------------------------------ errors

def _error(message_start: str, **kw):
    with pytest.raises(RuntimeError) as info:
        relight(**kw) if "image_name" in kw else bpy.ops.relight_photo.relight(synchronous=True)
    text = str(info.value)
    assert message_start in text, text
    # one sentence, no traceback
    assert "Traceback" not in text and text.strip().count("\n") == 0
    return text


def test_error_no_image(addon, settings):
    _error("Open a photo in the Image Editor first.")
    _error("There is no image called 'nothing'.", image_name="nothing")


def test_error_photo_file_missing(addon, settings, tmp_path):
    path = tmp_path / "gone.png"
    write_person_png(path)
    image = bpy.data.images.load(str(path))
    path.unlink()
    try:
        _error(f"The photo file of 'gone.png' is missing ({path}): it was moved or deleted.", image_name=image.name)
    finally:
        bpy.data.images.remove(image)


def test_error_file_that_is_not_an_image(addon, settings, tmp_path):
    path = tmp_path / "notes.png"
    path.write_text("these are notes, not a photo\n")
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        _error("'notes.png' is not an image Blender can read (notes.png).", image_name=image.name)
    finally:
        bpy.data.images.remove(image)


def test_error_missing_model(addon, settings):
    settings.model_path = "/nonexistent/model.onnx"
    _error("The model file '/nonexistent/model.onnx' does not exist.", image_name=addon["photo"])


def test_error_empty_mask(addon, settings):
    mask = bpy.data.images.new("mask_black", W, H)
    mask.pixels.foreach_set(np.tile(np.array([0, 0, 0, 1], np.float32), W * H))
    settings.mask_mode = "IMAGE"
    settings.mask_image = mask
    _error("The mask is empty: it selects no pixel of the photo.", image_name=addon["photo"])
    settings.mask_image = None
    _error("Choose a mask image, or set the mask to Automatic.", image_name=addon["photo"])
    settings.mask_mode = "IMAGE_ALPHA"
    _error("The photo has no alpha channel to use as the mask.", image_name=addon["photo"])


def test_error_unreadable_hdr(addon, settings, tmp_path):
    bad = tmp_path / "broken.exr"
    bad.write_bytes(b"\x76\x2f\x31\x01 truncated")
    settings.light_kind = "HDR"
    settings.hdr_path = str(bad)
    _error("The HDR file 'broken.exr' cannot be read as an equirectangular map", image_name=addon["photo"])
    settings.hdr_path = str(tmp_path / "absent.hdr")
    _error("does not exist.", image_name=addon["photo"])


def test_error_no_world_and_no_light_photo(addon, settings):
    scene = bpy.context.scene
    old = scene.world
    try:
        scene.world = None
        settings.light_kind = "WORLD"
        _error("The scene has no World to take the light from.", image_name=addon["photo"])
    finally:
        scene.world = old
    settings.light_kind = "IMAGE"
    _error("Choose the photo to take the light from.", image_name=addon["photo"])


def test_error_save_before_relight(addon, settings, tmp_path):
    state.SESSIONS.clear()
    with pytest.raises(RuntimeError, match="Relight the photo first: there are no layers to save yet."):
        bpy.ops.relight_photo.save_layers(filepath=str(tmp_path / "x.exr"), image_name=addon["photo"])


def test_save_layers_refusals_reach_the_panel_before_any_work(addon, settings, tmp_path, monkeypatch):
    import shutil

    name = addon["photo"]
    relight(name)
    status = bpy.context.window_manager.relight_photo_status
    computed = []
    monkeypatch.setattr(bl_ops.save_layers, "save_layers_work", lambda *a, **k: computed.append(1))  # never reached
    (tmp_path / "taken.exr").mkdir()
    cases = [(tmp_path / "taken.exr", f"'{tmp_path / 'taken.exr'}' is a folder: choose a file name for the layers."),
             (tmp_path / "no" / "l.exr", f"The folder '{tmp_path / 'no'}' does not exist: choose another place"),
             ]
    for target, message in cases:
        with pytest.raises(RuntimeError, match="Error: "):
            bpy.ops.relight_photo.save_layers(filepath=str(target), image_name=name)
        assert status.is_error and status.message.startswith(message), status.message
    h, w = session(name).photo.shape[:2]
    # one byte short of what the layers need: the EXR (its channels compressed to about half) and
    # the planes staged while it is written (blender_addon.worker.save_layers)
    free = (bl_ops.save_layers.LAYERS_EXR_CHANNELS // 2 + bl_ops.save_layers.STAGED_PLANES) * 4 * h * w - 1
    monkeypatch.setattr(shutil, "disk_usage", lambda _p: type("Usage", (), {"free": free})())
    with pytest.raises(RuntimeError, match="MB free; the layers need about"):
        bpy.ops.relight_photo.save_layers(filepath=str(tmp_path / "l.exr"), image_name=name)
    assert "free some space" in status.message and computed == [] and not (tmp_path / "l.exr").exists()


def test_a_bad_light_chosen_after_relighting_shows_in_the_panel(addon, settings):
    name = addon["photo"]
    relight(name)
    settings.light_kind = "HDR"
    settings.hdr_path = "/nonexistent/sky.exr"  # update callback: no operator to report
    status = bpy.context.window_manager.relight_photo_status
    assert status.is_error and status.message == "The HDR file '/nonexistent/sky.exr' does not exist."


# ------------------------------------------------------------------ the modal (UI) path
# Headless Blender has no window to deliver timer events, so these drive the
# operator's modal() by hand with the events Blender would send.

class _FakeWindowManager:
    def __init__(self):
        self.progress = []
        self.relight_photo_status = bpy.context.window_manager.relight_photo_status

    def progress_update(self, value):
        self.progress.append(value)

    def progress_end(self):
        self.progress.append("end")

    def event_timer_remove(self, _timer):
        pass


class _FakeWorkspace:
    def __init__(self):
        self.status = []

    def status_text_set(self, text):
        self.status.append(text)


def _modal_operator(image_name):
    import types

    cls = bl_ops.RELIGHT_PHOTO_OT_relight
    op = types.SimpleNamespace(image_name=image_name, synchronous=False, _job=None, _timer=None,
                               _plan=None, _pending=None, _result=None, _started=0.0, reports=[],
                               _dial_values=cls._dial_values)
    op.report = lambda kind, text: op.reports.append((set(kind), text))
    for name in ("_make_plan", "_start", "_install", "_write_next", "_done", "_error", "_cleanup",
                 "stop_polling", "_show_progress", "modal"):
        setattr(op, name, getattr(cls, name).__get__(op))
    context = types.SimpleNamespace(scene=bpy.context.scene, window_manager=_FakeWindowManager(),
                                    workspace=_FakeWorkspace(), space_data=None, window=None)
    return op, context


def test_modal_run_polls_the_worker_then_finishes(addon, settings):
    import time
    import types

    name = addon["photo"]
    state.SESSIONS.clear()
    op, context = _modal_operator(name)
    op._start(context)
    assert "job" in state.RUNNING
    timer = types.SimpleNamespace(type="TIMER")
    result = {"PASS_THROUGH"}
    deadline = time.monotonic() + 120
    while result == {"PASS_THROUGH"} and time.monotonic() < deadline:
        time.sleep(0.02)
        result = op.modal(context, timer)
    assert result == {"FINISHED"}
    assert "job" not in state.RUNNING and session(name) is not None
    assert context.window_manager.progress[-1] == "end"
    assert context.workspace.status[-1] is None  # the header text is given back
    assert op.reports and op.reports[-1][1].startswith(f"Relit '{name}' in")
    # a second Relight while one is running is refused with one sentence
    op2, _ = _modal_operator(name)
    op2._start(context)
    op3, _ = _modal_operator(name)
    with pytest.raises(ValueError, match="A relight is already running"):
        op3._start(context)
    with pytest.raises(RuntimeError, match="A relight is already running"):
        relight(name)  # the synchronous path refuses too, and leaves the running job alone
    assert state.RUNNING["job"] is op2._job
    # Esc: cancelled at once, the worker's late result is dropped
    assert op2.modal(context, types.SimpleNamespace(type="ESC")) == {"CANCELLED"}
    assert "job" not in state.RUNNING
    assert op2.reports[-1] == ({"WARNING"}, "Relighting cancelled.")
    assert context.window_manager.relight_photo_status.running is False


@pytest.mark.parametrize("kind, shown", [("WORLD", "label"), ("HDR", "hdr_path"), ("PRESET", "preset"),
                                         ("IMAGE", "light_image")])
def test_panel_draws_every_light_kind(addon, settings, kind, shown):
    settings.light_kind = kind
    log = draw_panel(addon["photo"])
    names = [entry[1] for entry in log]
    assert ("operator", "relight_photo.relight") in log and ("operator", "relight_photo.save_layers") in log
    assert {"rotation", "exposure", "strength", "quality", "mask_mode"} <= set(names)
    if shown == "label":
        assert any(text.startswith("World: ") for kind_, text in log if kind_ == "label")
    else:
        assert shown in names


# ------------------------------------------------------------------ wrong results are never a success

def _png(path: Path, rgb: np.ndarray) -> str:
    from PIL import Image

    Image.fromarray(rgb, "RGB").save(path)
    return bpy.data.images.load(str(path)).name


@pytest.mark.parametrize("shape, value, message", [
    ((4, 4), 128, "The photo is only 4 x 4 pixels, too small to show a person: use a photo at least 32"),
    ((H, W), 0, "The photo is black: there is no person to see in it."),
    ((H, W), 255, "The photo is white (blown out): there is no person to see in it."),
])
def test_a_photo_without_a_visible_person_is_refused(addon, settings, tmp_path, shape, value, message):
    name = _png(tmp_path / "plain.png", np.full(shape + (3,), value, np.uint8))
    try:
        _error(message, image_name=name)
        assert not any(i.name.startswith(f"{name}.") for i in bpy.data.images)  # no output was made
    finally:
        bpy.data.images.remove(bpy.data.images[name])


def _count_bakes(monkeypatch) -> list:
    """Counts Cycles bakes; each also delivers the depsgraph update the bake's
    render causes in Blender (it must not start a second bake)."""
    import types

    bakes, real = [], bl_world._bake
    updated = types.SimpleNamespace(id_type_updated=lambda kind: kind == "WORLD")

    def counting(world, width):
        bakes.append(world.name)
        bl_dials.on_depsgraph_update(bpy.context.scene, updated)  # sent while the bake renders
        return real(world, width)

    monkeypatch.setattr(bl_world, "_bake", counting)
    return bakes


def test_a_world_texture_without_an_image_is_refused_not_baked_magenta(addon, settings, monkeypatch, tmp_path):
    bakes = _count_bakes(monkeypatch)
    world = _env_world(presets.preset_path("studio"))
    scene = bpy.context.scene
    old = scene.world
    try:
        scene.world = world
        settings.light_kind = "WORLD"
        env = next(n for n in world.node_tree.nodes if n.type == "TEX_ENVIRONMENT")
        env.image = None  # Blender renders this magenta
        _error("The World's texture node 'Environment Texture' has no image, which Blender shows as magenta",
               image_name=addon["photo"])
        # an image whose file is gone is magenta too
        write_person_png(tmp_path / "sky.png")
        env.image = bpy.data.images.load(str(tmp_path / "sky.png"))
        (tmp_path / "sky.png").unlink()
        _error("The World's image 'sky.png' cannot be read (is its file missing?)", image_name=addon["photo"])
        assert bakes == []
    finally:
        scene.world = old
        bpy.data.worlds.remove(world)
        if "sky.png" in bpy.data.images:
            bpy.data.images.remove(bpy.data.images["sky.png"])


def test_one_bake_per_world_change_cached_by_its_node_state(addon, settings, monkeypatch):
    import types

    bakes = _count_bakes(monkeypatch)
    state.WORLDS.clear()
    world = new_node_world("relight_flat_world")  # the default World: a Background colour, baked
    background = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    background.inputs["Color"].default_value = (0.8, 0.6, 0.4, 1.0)
    scene = bpy.context.scene
    old = scene.world
    updated = types.SimpleNamespace(id_type_updated=lambda kind: kind == "WORLD")
    try:
        scene.world = world
        name = addon["photo"]
        assert relight(name) == {"FINISHED"}  # under a preset
        settings.light_kind = "WORLD"          # a dial: relit live from the World, one bake
        assert len(bakes) == 1
        assert relight(name) == {"FINISHED"}   # the same World: its cached light
        assert len(bakes) == 1
        first = pixels(f"{name}.relit").copy()
        settings.rotation = math.radians(40.0)   # dials move the light, not the World: no bake
        settings.exposure = 0.5
        assert len(bakes) == 1
        assert np.abs(pixels(f"{name}.relit") - first).max() > 1e-3
        background.inputs["Color"].default_value = (0.2, 0.4, 0.9, 1.0)  # an edit of the World: one bake
        bl_dials.on_depsgraph_update(scene, updated)
        assert len(bakes) == 2
        bl_dials.on_depsgraph_update(scene, updated)  # more updates, same node state: none
        world.name = "relight_flat_world_renamed"   # the name is not part of the light
        settings.rotation = math.radians(10.0)
        assert len(bakes) == 2
        background.inputs["Color"].default_value = (0.8, 0.6, 0.4, 1.0)  # back to a state seen before
        bl_dials.on_depsgraph_update(scene, updated)
        assert len(bakes) == 2
    finally:
        scene.world = old
        bpy.data.worlds.remove(world)


def test_a_renamed_photo_keeps_its_outputs_and_dials(addon, settings):
    name = addon["photo"]
    photo = bpy.data.images[name]
    assert relight(name) == {"FINISHED"}
    relit = bpy.data.images[f"{name}.relit"]
    pointer = relit.as_pointer()
    try:
        photo.name = "renamed.png"
        import types

        # Blender's depsgraph update for the rename: the outputs follow at once
        bl_dials.on_depsgraph_update(bpy.context.scene, types.SimpleNamespace(id_type_updated=lambda k: k == "IMAGE"))
        assert {i.name for i in bpy.data.images if i.name.startswith("renamed.png.")} >= \
            {f"renamed.png.{layer}" for layer in ("albedo", "alpha", "relit", "residual", "shading")}
        assert not any(bl_images.owner_of(i) and i.name.startswith(f"{name}.") for i in bpy.data.images)
        impostor = bpy.data.images.new(name, 8, 8)  # a new image takes the old name: it is not the photo
        settings.rotation = math.radians(60.0)
        assert "renamed.png.relit" in bpy.data.images and f"{name}.relit" not in bpy.data.images
        assert bpy.data.images["renamed.png.relit"].as_pointer() == pointer  # the same datablock, renamed
        expected = session("renamed.png").decomposition.relight(sh_light("studio", ORDER, rotation_deg=60.0))
        np.testing.assert_allclose(pixels("renamed.png.relit")[..., :3], expected, atol=TIGHT)
        # Relight pressed on the output relights its photo, not the image now called like the old photo
        assert relight("renamed.png.relit") == {"FINISHED"}
        assert settings.last_photo_id == photo[bl_images.PHOTO_ID]
        assert not any(i.name.startswith(f"{name}.") for i in bpy.data.images)
        bpy.data.images.remove(impostor)
    finally:
        photo.name = name
    settings.rotation = 0.0
    assert bpy.data.images[f"{name}.relit"].as_pointer() == pointer


def test_a_duplicated_photo_gets_its_own_identity(addon, settings):
    name = addon["photo"]
    relight(name)
    copy = bpy.data.images[name].copy()
    try:
        assert copy[bl_images.PHOTO_ID] == bpy.data.images[name][bl_images.PHOTO_ID]  # Blender copies it
        assert relight(copy.name) == {"FINISHED"}
        assert copy[bl_images.PHOTO_ID] != bpy.data.images[name][bl_images.PHOTO_ID]
        assert f"{copy.name}.relit" in bpy.data.images and f"{name}.relit" in bpy.data.images
    finally:
        for image in [i for i in bpy.data.images if i.name.startswith(copy.name)]:
            bpy.data.images.remove(image)


def test_esc_stops_the_network_while_it_runs(addon, settings, monkeypatch):
    import time
    import types

    from relight.network.quality import QualityPreset

    # a working size that makes the tiny network run for seconds, so Esc lands inside it
    slow = QualityPreset("draft", "Draft", None, 1024, "slow")
    monkeypatch.setattr(bl_ops.quality, "preset", lambda key: slow)
    name = addon["photo"]
    state.SESSIONS.clear()
    op, context = _modal_operator(name)
    op._start(context)
    job = op._job
    deadline = time.monotonic() + 60
    while not job.progress.stage.startswith("Running the network") and time.monotonic() < deadline:
        time.sleep(0.01)
    time.sleep(0.2)  # the first network pass is running now
    assert job.poll() is bl_ops.jobs.JobState.RUNNING
    assert op.modal(context, types.SimpleNamespace(type="ESC")) == {"CANCELLED"}
    assert op.reports[-1] == ({"WARNING"}, "Relighting cancelled.")
    job.wait(60)
    # the worker itself stopped inside the network pass (onnxruntime was told to terminate), nothing kept
    assert job.finished and isinstance(job.error, bl_ops.engine.Cancelled)
    assert job.cancel_token.stopped_inference
    assert state.SESSIONS == {} and "job" not in state.RUNNING


def test_a_large_photo_shows_a_preview_while_the_dial_moves_then_the_full_size(addon, settings, monkeypatch):
    name = addon["photo"]
    monkeypatch.setattr(bl_ops.work, "PREVIEW_LONG_SIDE", 24)  # our 72 x 48 photo is "large" against 24 px
    relight(name)
    run = session(name)
    run.preview = bl_ops.engine.preview_decomposition(run.decomposition, 24)
    assert run.preview is not None and run.preview.size == (24, 16)
    monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)
    try:
        settings.rotation = math.radians(30.0)
        assert bl_dials.deferred_refresh() is None   # what Blender's idle timer calls
        # the preview: the same relight, screen-sized, in its own image; the full-size one is not resized
        assert tuple(bpy.data.images[f"{name}.preview"].size) == (16, 24)
        assert tuple(bpy.data.images[f"{name}.relit"].size) == (W, H)
        small = run.preview.relight(sh_light("studio", ORDER, rotation_deg=30.0))
        np.testing.assert_allclose(pixels(f"{name}.preview")[..., :3], small, atol=TIGHT)
        assert bpy.app.timers.is_registered(bl_dials.full_when_resting)
        bpy.app.timers.unregister(bl_dials.full_when_resting)
        assert bl_dials.full_when_resting() is None  # the dial rests: the full size runs on a worker
        job = state.RUNNING["dial"]
        job.wait(60)
        assert bl_dials.poll_full_size() is None
        assert tuple(bpy.data.images[f"{name}.relit"].size) == (W, H)
        full = run.decomposition.relight(sh_light("studio", ORDER, rotation_deg=30.0))
        np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], full, atol=TIGHT)
        # a full-size result that arrives after another dial move is dropped
        bl_dials.start_full_size(run, bl_light.current_dials(bpy.context, run)).wait(60)
        settings.rotation = math.radians(50.0)
        before = pixels(f"{name}.relit").copy()
        bl_dials.deferred_refresh()
        assert bl_dials.poll_full_size() is None
        np.testing.assert_array_equal(pixels(f"{name}.relit"), before)  # the late result was not written
    finally:
        for timer in bl_ops._TIMERS:
            if bpy.app.timers.is_registered(timer):
                bpy.app.timers.unregister(timer)
        state.RUNNING.pop("dial", None)


def test_editors_showing_the_result_switch_between_preview_and_full_size(addon, settings, monkeypatch):
    import types

    name = addon["photo"]
    monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)
    relight(name)
    run = session(name)
    run.preview = bl_ops.engine.preview_decomposition(run.decomposition, 24)
    try:
        settings.rotation = math.radians(15.0)
        bl_dials.deferred_refresh()
    finally:
        for timer in bl_ops._TIMERS:
            if bpy.app.timers.is_registered(timer):
                bpy.app.timers.unregister(timer)
    relit, preview = bpy.data.images[f"{name}.relit"], bpy.data.images[f"{name}.preview"]
    # a window with two Image Editors (one on the result, one on the photo) and a 3D view
    on_result = types.SimpleNamespace(type="IMAGE_EDITOR", regions=[],
                                      spaces=types.SimpleNamespace(active=types.SimpleNamespace(
                                          image=relit, zoom=(0.25, 0.25))))
    on_photo = types.SimpleNamespace(type="IMAGE_EDITOR", regions=[],
                                     spaces=types.SimpleNamespace(active=types.SimpleNamespace(
                                         image=bpy.data.images[name], zoom=(1.0, 1.0))))
    view3d = types.SimpleNamespace(type="VIEW_3D", regions=[], spaces=types.SimpleNamespace(active=None))
    window = types.SimpleNamespace(screen=types.SimpleNamespace(areas=[on_result, on_photo, view3d]))
    assert bl_dials.show_in_editors(run, "preview", [window]) == 1
    assert on_result.spaces.active.image == preview and on_photo.spaces.active.image == bpy.data.images[name]
    assert bl_dials.show_in_editors(run, "relit", [window]) == 1
    assert on_result.spaces.active.image == relit
    assert bl_dials.show_in_editors(run, "relit", [window]) == 0  # already there


# ------------------------------------------------------------------ the person matte (Mask: Automatic)

def test_automatic_mask_is_the_person_matte_shown_as_a_cut_out(addon, settings):
    from relight.person.matte import person_matte
    from evaluation.matte_eval import EVAL_DIR

    photo = bpy.data.images.load(str(EVAL_DIR / "grace_hopper.jpg"))
    settings.mask_mode = "AUTO"
    settings.person = "1"
    try:
        assert relight(photo.name) == {"FINISHED"}
        run = session(photo.name)
        from relight.network import quality

        want = person_matte(run.photo, 1, method=quality.preset(settings.quality).matte_method)  # the preset's
        assert settings.people_found == want.count >= 1 and run.people == want.count
        # the matte the relight used is the person matte, and '.matte' shows the photo cut out by it
        np.testing.assert_array_equal(run.decomposition.mask, want.alpha)
        cut_out = pixels(f"{photo.name}.matte")
        np.testing.assert_allclose(cut_out[..., 3], want.alpha, atol=1e-7)
        np.testing.assert_allclose(cut_out[..., :3], run.photo, atol=1e-7)
        np.testing.assert_allclose(pixels(f"{photo.name}.alpha")[..., 0], want.alpha, atol=1e-7)
        inside = want.alpha > 0.5
        assert 0.05 < inside.mean() < 0.95  # a person, not the frame or nothing
        # outside the matte the photo is untouched
        relit = pixels(f"{photo.name}.relit")[..., :3]
        np.testing.assert_array_equal(relit[want.alpha == 0], run.photo[want.alpha == 0])
        # a person the photo does not have: one sentence naming how many there are
        settings.people_found = want.count + 1
        settings.person = str(want.count + 1)
        _error(f"Person {want.count + 1} is chosen, but the photo shows only {want.count} ",
               image_name=photo.name)
    finally:
        settings.person = "1"
        settings.people_found = 0
        settings.mask_mode = "NETWORK"
        for image in [i for i in bpy.data.images if i.name.startswith("grace_hopper.jpg")]:
            bpy.data.images.remove(image)


def test_automatic_mask_with_nobody_in_the_photo_says_so(addon, settings, tmp_path):
    y, x = np.mgrid[0:H, 0:W]
    wall = np.dstack([40 + (x * 3) % 50, 60 + (y * 2) % 40, np.full((H, W), 90)]).astype(np.uint8)
    name = _png(tmp_path / "wall.png", wall)  # the background of our figure photo, without the figure
    settings.mask_mode = "AUTO"
    try:
        _error("No person was found in the photo: set Mask to Network Matte", image_name=name)
    finally:
        settings.mask_mode = "NETWORK"
        bpy.data.images.remove(bpy.data.images[name])


def test_panel_shows_the_person_list_and_the_stage_of_a_running_relight(addon, settings):
    settings.mask_mode = "AUTO"
    settings.people_found, settings.people_relit = 2, 2
    status = bpy.context.window_manager.relight_photo_status
    status.running, status.stage, status.progress, status.elapsed = True, "Running the network", 0.42, 3.25
    try:
        log = draw_panel(addon["photo"])
        labels = [text for kind, text in log if kind == "label"]
        assert ("prop", "person") in log
        from blender_addon.blender import bl_props

        # Everyone, then one per person
        assert [item[0] for item in bl_props._person_items(settings, None)] == ["0", "1", "2"]
        assert "2 people found, 2 relit; '.matte' shows the cut-out" in labels
        assert "Running the network: 42% (3.2 s)" in labels and "Esc cancels" in labels
    finally:
        status.running, status.stage, status.progress, status.elapsed = False, "", 0.0, 0.0
        settings.people_found = settings.people_relit = 0
        settings.mask_mode = "NETWORK"


def test_with_a_ui_the_relit_image_comes_first_and_the_other_layers_follow(addon, settings, monkeypatch):
    import time
    import types

    from blender_addon.blender import bl_layers
    from blender_addon.worker import work

    events = []  # each layer made, then written, before the next is made: one full-size buffer at a time
    make, write = work.layer_buffer, bl_layers.write_output
    monkeypatch.setattr(work, "layer_buffer", lambda s, layer, d: events.append(("make", layer)) or make(s, layer, d))
    monkeypatch.setattr(bl_layers, "write_output",
                        lambda s, layer, *a: events.append(("write", layer)) or write(s, layer, *a))
    name = addon["photo"]
    state.SESSIONS.clear()
    for layer in ("relit", "albedo", "shading", "residual", "alpha"):
        if f"{name}.{layer}" in bpy.data.images:
            bpy.data.images.remove(bpy.data.images[f"{name}.{layer}"])
    op, context = _modal_operator(name)
    op._start(context, layers_later=True)  # what invoke() does with a window
    result, deadline = {"PASS_THROUGH"}, time.monotonic() + 120
    while result == {"PASS_THROUGH"} and time.monotonic() < deadline:
        time.sleep(0.02)
        result = op.modal(context, types.SimpleNamespace(type="TIMER"))
    assert result == {"FINISHED"} and op.reports[-1][1].endswith("; the other layers follow.")
    assert f"{name}.relit" in bpy.data.images and f"{name}.albedo" not in bpy.data.images
    try:
        deadline = time.monotonic() + 60
        while bl_ops.poll_layers() is not None and time.monotonic() < deadline:  # as Blender's timer calls it
            time.sleep(0.01)
        assert "layers" not in state.RUNNING
        assert events == [(kind, layer) for layer in ("alpha", "albedo", "shading", "residual")
                          for kind in ("make", "write")]
        run = session(name)
        want = run.decomposition.layers(sh_light("studio", ORDER))
        for layer in ("albedo", "shading", "residual"):
            np.testing.assert_allclose(pixels(f"{name}.{layer}")[..., :3], want[layer], atol=TIGHT)
        np.testing.assert_allclose(pixels(f"{name}.alpha")[..., 0], want["alpha"], atol=TIGHT)
    finally:
        if bpy.app.timers.is_registered(bl_ops.poll_layers):
            bpy.app.timers.unregister(bl_ops.poll_layers)
        state.RUNNING.pop("layers", None)


def test_the_quality_preset_decides_the_networks_test_time_work(addon, settings):
    """Best runs the preset's augmentations (and refinement, which a network with a residual E
    skips: its albedo is not photo-consistent); Draft runs the network once."""
    from relight.network import quality

    name = addon["photo"]
    settings.quality = "BEST"
    try:
        assert relight(name) == {"FINISHED"}
        best = quality.preset("best")
        choices = session(name).decomposition.choices
        assert choices["augment"] == [[float(s), bool(m)] for s, m in best.augment]
        assert session(name).decomposition.has_residual  # the tiny random paper-layout network
        assert choices["refine"]["stopped"] == "off"
        assert choices["working_size"] == best.working_size
    finally:
        settings.quality = "DRAFT"
    assert relight(name) == {"FINISHED"}
    assert session(name).decomposition.choices["augment"] == []
