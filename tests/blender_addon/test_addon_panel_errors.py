"""Every error the add-on's user can meet, asserted on the report text, the modal run and the
panel's drawing under headless bpy."""

from __future__ import annotations


import numpy as np
import pytest

import bpy

from blender_addon.blender import bl_ops
from blender_addon.worker import state

from addon_support import H, W, draw_panel, write_person_png
from addon_panel_support import addon, settings  # noqa: F401 (the fixtures)
from addon_panel_support import expect_error, modal_operator, png_image, relight, session


# ------------------------------------------------------------------ errors

def test_error_no_image(addon, settings):
    expect_error("Open a photo in the Image Editor first.")
    expect_error("There is no image called 'nothing'.", image_name="nothing")


def test_error_photo_file_missing(addon, settings, tmp_path):
    path = tmp_path / "gone.png"
    write_person_png(path)
    image = bpy.data.images.load(str(path))
    path.unlink()
    try:
        expect_error(f"The photo file of 'gone.png' is missing ({path}): it was moved or deleted.", image_name=image.name)
    finally:
        bpy.data.images.remove(image)


def test_error_file_that_is_not_an_image(addon, settings, tmp_path):
    path = tmp_path / "notes.png"
    path.write_text("these are notes, not a photo\n")
    image = bpy.data.images.load(str(path), check_existing=False)
    try:
        expect_error("'notes.png' is not an image Blender can read (notes.png).", image_name=image.name)
    finally:
        bpy.data.images.remove(image)


def test_error_missing_model(addon, settings):
    settings.model_path = "/nonexistent/model.onnx"
    expect_error("The model file '/nonexistent/model.onnx' does not exist.", image_name=addon["photo"])


def test_error_empty_mask(addon, settings):
    mask = bpy.data.images.new("mask_black", W, H)
    mask.pixels.foreach_set(np.tile(np.array([0, 0, 0, 1], np.float32), W * H))
    settings.mask_mode = "IMAGE"
    settings.mask_image = mask
    expect_error("The mask is empty: it selects no pixel of the photo.", image_name=addon["photo"])
    settings.mask_image = None
    expect_error("Choose a mask image, or set the mask to Automatic.", image_name=addon["photo"])
    settings.mask_mode = "IMAGE_ALPHA"
    expect_error("The photo has no alpha channel to use as the mask.", image_name=addon["photo"])


def test_error_unreadable_hdr(addon, settings, tmp_path):
    bad = tmp_path / "broken.exr"
    bad.write_bytes(b"\x76\x2f\x31\x01 truncated")
    settings.light_kind = "HDR"
    settings.hdr_path = str(bad)
    expect_error("The HDR file 'broken.exr' cannot be read as an equirectangular map", image_name=addon["photo"])
    settings.hdr_path = str(tmp_path / "absent.hdr")
    expect_error("does not exist.", image_name=addon["photo"])


def test_error_no_world_and_no_light_photo(addon, settings):
    scene = bpy.context.scene
    old = scene.world
    try:
        scene.world = None
        settings.light_kind = "WORLD"
        expect_error("The scene has no World to take the light from.", image_name=addon["photo"])
    finally:
        scene.world = old
    settings.light_kind = "IMAGE"
    expect_error("Choose the photo to take the light from.", image_name=addon["photo"])


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

def test_modal_run_polls_the_worker_then_finishes(addon, settings):
    import time
    import types

    name = addon["photo"]
    state.SESSIONS.clear()
    op, context = modal_operator(name)
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
    op2, _ = modal_operator(name)
    op2._start(context)
    op3, _ = modal_operator(name)
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

@pytest.mark.parametrize("shape, value, message", [
    ((4, 4), 128, "The photo is only 4 x 4 pixels, too small to show a person: use a photo at least 32"),
    ((H, W), 0, "The photo is black: there is no person to see in it."),
    ((H, W), 255, "The photo is white (blown out): there is no person to see in it."),
])
def test_a_photo_without_a_visible_person_is_refused(addon, settings, tmp_path, shape, value, message):
    name = png_image(tmp_path / "plain.png", np.full(shape + (3,), value, np.uint8))
    try:
        expect_error(message, image_name=name)
        assert not any(i.name.startswith(f"{name}.") for i in bpy.data.images)  # no output was made
    finally:
        bpy.data.images.remove(bpy.data.images[name])


