"""Relight Photo add-on: a relit photo survives saving and reopening the .blend.

Reopening restores the decomposition from the file kept next to the .blend
(no network run): the outputs are there and the dials relight at once. Without
its photo (moved, deleted, not an image, changed) the saved result comes back
from the saved decomposition alone with live dials and a lasting notice in the
panel; with nothing to restore from, no black image is left posing as a result.
Driven as a user would: operators, properties as the panel sets them,
save_as_mainfile (copy=True is File > Save Copy) and open_mainfile, files moved
and deleted on disk in between."""

from __future__ import annotations

import math
import os

import numpy as np
import pytest

import bpy

from blender_addon.blender import bl_dials, bl_images, bl_layers, bl_ops, bl_saved, bl_session
from blender_addon.logic import output_names
from blender_addon.worker import state
from relight.lighting.light import sh_light
from addon_support import draft_photo, draw_panel, pixels, write_person_png

LAYERS = ("relit", "albedo", "shading", "residual", "alpha")
# the saved decomposition holds the network's maps in float16 (11-bit mantissa):
# relative error <= 2^-11 per value, a few of them multiplied and summed
HALF = 4e-3


def _relight(name):
    return bpy.ops.relight_photo.relight(image_name=name, synchronous=True)


def test_save_and_reopen_restores_the_result_and_the_dials_work_at_once(addon, model):
    name = draft_photo(model, addon)
    bpy.context.scene.relight_photo.exposure = 0.5  # shading and residual follow the dials of Relight
    assert _relight(name) == {"FINISHED"}
    before = {layer: pixels(f"{name}.{layer}").copy() for layer in LAYERS}
    pid = bpy.data.images[name][bl_images.PHOTO_ID]
    blend = addon / "shot.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(blend)) == {"FINISHED"}
    saved = output_names.saved_relight_path(str(blend), pid)
    d = state.SESSIONS[pid].decomposition
    float32_bytes = 4 * sum(a.size for a in (d.albedo, d.transport, d.residual, d.photo_working, d.alpha))
    assert os.path.isfile(saved) and os.path.getsize(saved) < 0.55 * float32_bytes  # half floats

    bpy.ops.wm.open_mainfile(filepath=str(blend))
    assert state.SESSIONS[pid].saved_to == saved  # restored, not relit
    for layer in LAYERS:   # every output is back with the saved dials, not a blank image
        np.testing.assert_allclose(pixels(f"{name}.{layer}"), before[layer], rtol=HALF, atol=HALF)
    assert np.abs(before["relit"][..., :3] - pixels(name)[..., :3]).max() > 1e-2  # and it is relit

    settings = bpy.context.scene.relight_photo
    assert settings.exposure == 0.5
    settings.rotation = math.radians(70.0)  # the dial works without Relight
    turned = pixels(f"{name}.relit").copy()
    assert np.abs(turned - before["relit"]).max() > 1e-2
    # and gives what a fresh network run gives at the same dials
    assert _relight(name) == {"FINISHED"}
    fresh = pixels(f"{name}.relit")
    np.testing.assert_allclose(turned, fresh, rtol=HALF, atol=HALF)


def _panel_text(photo_name: str) -> str:
    """The panel's labels for the photo, without white space: a sentence wrapped over several
    labels (a long path may be cut anywhere) is found in it as `_words(sentence)`."""
    return _words(" ".join(text for kind, text in draw_panel(photo_name) if kind == "label"))


def _words(text: str) -> str:
    return "".join(text.split())


def _open_with_a_ui(blend, monkeypatch) -> None:
    """open_mainfile as with a UI (threads, timers): Blender's timer calls done by hand until the
    photos are read again and every output is written."""
    monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    assert bl_saved.poll_restore() is not None  # the first tick starts the worker
    state.RUNNING["restore"].wait(60)
    assert bl_saved.poll_restore() is None
    _run_layer_timer()


def _run_layer_timer() -> None:
    import time

    deadline = time.monotonic() + 60
    while bl_layers.poll_layers() is not None and time.monotonic() < deadline:
        time.sleep(0.01)
    assert "layers" not in state.RUNNING


def _unregister_timers() -> None:
    for timer in bl_ops._TIMERS:
        if bpy.app.timers.is_registered(timer):
            bpy.app.timers.unregister(timer)


@pytest.mark.parametrize("ui", [False, True], ids=["script", "ui"])
def test_a_photo_changed_on_disk_shows_the_saved_result_and_says_so(addon, model, monkeypatch, ui):
    name, pid, before, blend = _relit_and_saved(model, addon)
    from PIL import Image

    changed = np.asarray(Image.open(addon / "person.png")).copy()
    changed[:10] = 255
    Image.fromarray(changed).save(addon / "person.png")
    try:
        if ui:
            _open_with_a_ui(blend, monkeypatch)
        else:
            bpy.ops.wm.open_mainfile(filepath=str(blend))
    finally:
        _unregister_timers()
    session = state.SESSIONS[pid]
    assert session.photo_missing == f"The photo '{name}' changed since it was relit."
    for layer in LAYERS:  # the result as saved, not black and not the new photo's
        np.testing.assert_allclose(pixels(f"{name}.{layer}"), before[layer], rtol=HALF, atol=HALF)
    status = bpy.context.window_manager.relight_photo_status
    assert status.is_error and status.message == (
        f"The photo '{name}' changed since it was relit. The saved relight of the photo as it was is shown at "
        "48 x 72 and the dials work; press Relight to relight the photo as it is now.")
    assert _words(status.message) in _panel_text(name)
    bpy.context.scene.relight_photo.rotation = math.radians(40.0)  # a dial works on the saved result
    if ui:
        assert bl_dials.deferred_refresh() is None  # what Blender's idle timer calls
    assert np.abs(pixels(f"{name}.relit") - before["relit"]).max() > 1e-2
    # Relight takes the photo as it is now, and the notice goes
    assert _relight(name) == {"FINISHED"}
    assert not state.SESSIONS[pid].photo_missing and state.NOTICES == {}
    assert "changedsince" not in _panel_text(name)
    assert state.SESSIONS[pid].photo[:10].min() == pytest.approx(1.0)  # the white rows of the new photo


def test_with_a_ui_reopening_shows_the_saved_preview_and_the_dials_work_before_the_photo_is_read(
        addon, model, monkeypatch):
    name = draft_photo(model, addon)
    monkeypatch.setattr(bl_ops.work, "PREVIEW_LONG_SIDE", 24)  # our 72 x 48 photo counts as large
    assert _relight(name) == {"FINISHED"}
    pid = bpy.data.images[name][bl_images.PHOTO_ID]
    before = state.SESSIONS[pid].preview.relight(sh_light("studio", state.SESSIONS[pid].decomposition.sh_order))
    blend = addon / "shot.blend"
    monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)  # as with a UI: threads, timers
    try:
        bpy.ops.wm.save_as_mainfile(filepath=str(blend))  # the decomposition file: written by a thread
        assert len(bl_saved.SAVING) == 1
        bpy.ops.wm.open_mainfile(filepath=str(blend))    # which opening waits for
        assert bl_saved.SAVING == []
        # no timer has run yet: the preview is back from the saved file, on a provisional session
        session = state.SESSIONS[pid]
        assert session.provisional and session.photo.shape[:2] == (24, 16)
        np.testing.assert_allclose(pixels(f"{name}.preview")[..., :3], before, rtol=HALF, atol=HALF)
        with pytest.raises(RuntimeError, match="still being read"):
            bpy.ops.relight_photo.save_layers(filepath=str(addon / "x.exr"), image_name=name)
        settings = bpy.context.scene.relight_photo
        settings.rotation = math.radians(50.0)
        assert bl_dials.deferred_refresh() is None  # the dial already works, on the preview
        np.testing.assert_allclose(pixels(f"{name}.preview")[..., :3],
                                   session.preview.relight(sh_light("studio", session.preview.sh_order, rotation_deg=50.0)), atol=1e-5)
        assert bl_dials.full_when_resting() is not None  # the full size waits for the photo
        # the first timer tick starts the worker; once it has read the photo the
        # full-size layers follow the dial as it is now
        assert bl_saved.poll_restore() is not None
        state.RUNNING["restore"].wait(60)
        assert bl_saved.poll_restore() is None
        restored = state.SESSIONS[pid]
        assert not restored.provisional and restored.photo.shape[:2] == (72, 48)
        _run_layer_timer()  # the relit image at full size, then the other layers, one at a time
        full = restored.decomposition.relight(sh_light("studio", restored.decomposition.sh_order,
                                                                       rotation_deg=50.0))
        np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], full, atol=1e-5)
        assert all(tuple(bpy.data.images[f"{name}.{layer}"].size) == (48, 72) for layer in LAYERS)
    finally:
        for timer in bl_ops._TIMERS:
            if bpy.app.timers.is_registered(timer):
                bpy.app.timers.unregister(timer)


def _relit_and_saved(model, folder):
    """Relight the photo with the dials moved off their defaults, save: (name, photo id, outputs, blend)."""
    name = draft_photo(model, folder)
    bpy.context.scene.relight_photo.exposure = 0.5
    assert _relight(name) == {"FINISHED"}
    outputs = {layer: pixels(f"{name}.{layer}").copy() for layer in LAYERS}
    pid = bpy.data.images[name][bl_images.PHOTO_ID]
    blend = folder / "shot.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(blend)) == {"FINISHED"}
    return name, pid, outputs, blend


def _assert_the_saved_result_with_live_dials(name, pid, before) -> str:
    """Every output is the saved one, the dials relight it; returns the panel's notice."""
    session = state.SESSIONS[pid]
    assert session.photo_missing and session.provisional
    for layer in LAYERS:  # the saved result, from the saved decomposition alone (a small photo is its own preview)
        np.testing.assert_allclose(pixels(f"{name}.{layer}"), before[layer], rtol=HALF, atol=HALF)
    status = bpy.context.window_manager.relight_photo_status
    notice = status.message
    assert status.is_error and notice.startswith(session.photo_missing)
    assert "The saved relight is shown at 48 x 72 and the dials work; for full size or Save Layers, point the " \
           "image at the photo again (Image > Replace) and press Relight." in notice
    bpy.context.scene.relight_photo.rotation = math.radians(70.0)  # a dial, as the artist turns it
    turned = pixels(f"{name}.relit")
    assert np.abs(turned - before["relit"]).max() > 1e-2
    expect = session.decomposition.relight(sh_light("studio", session.decomposition.sh_order, rotation_deg=70.0),
                                           exposure_ev=0.5)
    np.testing.assert_allclose(turned[..., :3], expect, atol=1e-5)
    assert status.message == notice  # the notice lasts while the dials work
    assert bl_dials.full_when_resting() is None  # no full-size relight waits forever for a photo that is gone
    return notice


@pytest.mark.parametrize("what", ["deleted", "moved", "not an image"])
def test_reopening_without_the_photo_shows_the_saved_result_and_the_dials_work(addon, model, what):
    name, pid, before, blend = _relit_and_saved(model, addon)
    photo = addon / "person.png"
    if what == "deleted":
        photo.unlink()
    elif what == "moved":
        (addon / "elsewhere").mkdir()
        photo.rename(addon / "elsewhere" / "person.png")
    else:
        photo.write_text("this text file was saved over the photo")
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    reason = state.SESSIONS[pid].photo_missing
    if what == "not an image":
        assert reason == f"'{name}' is not an image Blender can read (person.png)."
    else:
        assert reason == f"The photo file of '{name}' is missing ({photo}): it was moved or deleted."
    notice = _assert_the_saved_result_with_live_dials(name, pid, before)
    assert _words(notice) in _panel_text(name)  # wrapped to the sidebar's width, every word there
    # Save Layers refuses with the reason, in the panel too, and writes nothing
    status = bpy.context.window_manager.relight_photo_status
    with pytest.raises(RuntimeError, match="Saving layers needs the photo at full size"):
        bpy.ops.relight_photo.save_layers(filepath=str(addon / "layers.exr"), image_name=name)
    assert status.is_error and status.message.startswith(reason) and not (addon / "layers.exr").exists()


def test_the_notice_lasts_in_the_panel_until_the_photo_is_relit(addon, model):
    name, pid, before, blend = _relit_and_saved(model, addon)
    (addon / "elsewhere").mkdir()
    (addon / "person.png").rename(addon / "elsewhere" / "person.png")
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    notice = bpy.context.window_manager.relight_photo_status.message
    assert "is missing" in notice and _words(notice) in _panel_text(name)
    # another photo relit: the status line speaks of it, the panel still says what is wrong with this one
    write_person_png(addon / "other.png")
    other = bpy.data.images.load(str(addon / "other.png")).name
    assert _relight(other) == {"FINISHED"}
    assert bpy.context.window_manager.relight_photo_status.message.startswith(f"Relit '{other}'")
    assert _words(notice) in _panel_text(name) and "ismissing" not in _panel_text(other)
    assert _words(notice) in _panel_text(f"{name}.relit")  # an output shows its photo's notice
    # Image > Replace with the moved file, then Relight: full size again, the notice gone, Save Layers works
    image = bpy.data.images[name]
    image.filepath = str(addon / "elsewhere" / "person.png")
    image.reload()
    bpy.context.scene.relight_photo.rotation = 0.0
    assert _relight(name) == {"FINISHED"}
    assert not state.SESSIONS[pid].photo_missing and pid not in state.NOTICES
    assert "ismissing" not in _panel_text(name)
    np.testing.assert_allclose(pixels(f"{name}.relit"), before["relit"], atol=1e-5)  # the network again
    assert bpy.ops.relight_photo.save_layers(filepath=str(addon / "layers.exr"), image_name=name) == {"FINISHED"}


def test_save_copy_keeps_a_decomposition_beside_the_copy(addon, model):
    name, pid, before, blend = _relit_and_saved(model, addon)
    (addon / "copies").mkdir()
    copy = addon / "copies" / "shot_copy.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(copy), copy=True) == {"FINISHED"}  # File > Save Copy
    assert os.path.isfile(output_names.saved_relight_path(str(copy), pid))
    assert bpy.data.filepath == str(blend)  # a copy: the open file stays the one saved before
    assert state.SESSIONS[pid].saved_to == output_names.saved_relight_path(str(blend), pid)  # the open file's own
    bpy.ops.wm.open_mainfile(filepath=str(copy))
    assert state.SESSIONS[pid].saved_to == output_names.saved_relight_path(str(copy), pid)
    for layer in LAYERS:
        np.testing.assert_allclose(pixels(f"{name}.{layer}"), before[layer], rtol=HALF, atol=HALF)
    settings = bpy.context.scene.relight_photo
    settings.rotation = math.radians(30.0)  # and the dials work in the copy
    assert np.abs(pixels(f"{name}.relit") - before["relit"]).max() > 1e-2


def test_a_file_reopened_without_its_photo_can_be_saved_as_a_copy_and_reopened_again(addon, model):
    name, pid, before, blend = _relit_and_saved(model, addon)
    (addon / "person.png").unlink()
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    assert state.SESSIONS[pid].photo_missing
    (addon / "copies").mkdir()
    copy = addon / "copies" / "shot_copy.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(copy), copy=True) == {"FINISHED"}  # File > Save Copy
    bpy.ops.wm.open_mainfile(filepath=str(copy))
    _assert_the_saved_result_with_live_dials(name, pid, before)


def test_a_blend_moved_without_its_relight_folder_leaves_no_black_results(addon, model):
    import shutil

    name, pid, _before, blend = _relit_and_saved(model, addon)
    (addon / "moved").mkdir()
    shutil.copy(blend, addon / "moved" / "shot.blend")  # the .blend and its photo, not shot_relight/
    shutil.copy(addon / "person.png", addon / "moved" / "person.png")
    bpy.ops.wm.open_mainfile(filepath=str(addon / "moved" / "shot.blend"))
    assert state.SESSIONS == {}
    assert not [image.name for image in bpy.data.images if bl_images.owner_of(image) == pid]
    status = bpy.context.window_manager.relight_photo_status
    message = (f"The saved relight of '{name}' is not next to this .blend (shot_relight/ was not moved with it): "
               "press Relight.")
    assert status.is_error and status.message == message and _words(message) in _panel_text(name)
    assert _relight(name) == {"FINISHED"}  # the photo is there: Relight brings the results back
    assert np.abs(pixels(f"{name}.relit")).max() > 0.05 and _words(message) not in _panel_text(name)
