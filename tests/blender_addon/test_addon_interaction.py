"""The add-on as a user works with it under headless bpy: renamed and duplicated photos, Esc,
the preview while a dial moves, the automatic mask, the panel's stages, the quality presets."""

from __future__ import annotations

import math

import numpy as np

import bpy

from blender_addon.blender import bl_dials, bl_images, bl_light, bl_ops, bl_session
from blender_addon.worker import state
from relight.lighting.light import sh_light

from addon_support import H, W, draw_panel, pixels
from addon_panel_support import addon, settings  # noqa: F401 (the fixtures)
from addon_panel_support import TIGHT, expect_error, modal_operator, png_image, relight, session
from tiny_model import ORDER



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
    op, context = modal_operator(name)
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
        expect_error(f"Person {want.count + 1} is chosen, but the photo shows only {want.count} ",
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
    name = png_image(tmp_path / "wall.png", wall)  # the background of our figure photo, without the figure
    settings.mask_mode = "AUTO"
    try:
        expect_error("No person was found in the photo: set Mask to Network Matte", image_name=name)
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
    op, context = modal_operator(name)
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
