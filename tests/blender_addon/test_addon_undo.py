"""Relight Photo add-on: undo and redo leave the outputs consistent with the panel (issue 40).

Blender's undo brings back the scene's settings (the light, the dials) but not the pixels of
the output images, which it does not keep: after Relight with a preset, Relight with an HDR
file and Ctrl+Z, `.relit` and `.shading` showed the HDR result while the panel showed the
preset, and `.alpha` was black (also after Redo). Every output must be the result of the
settings the panel shows, after undo and after redo. The operators are pressed as a click
does (`undo=True`: the undo step Blender pushes after an operator with the UNDO option).
"""

from __future__ import annotations

import numpy as np
import pytest

import bpy

import blender_addon
from blender_addon.blender import bl_images
from blender_addon.worker import state
from relight.files.exr import write_exr
from addon_support import pixels, write_person_png

ORDER = 4
CLOSE = 1e-5  # float32 relighting of the same decomposition twice: equal to rounding


@pytest.fixture
def addon(model, tmp_path):
    write_person_png(tmp_path / "person.png")
    sky = np.zeros((16, 32, 3), np.float32)
    sky[:8, :16] = (8.0, 6.0, 3.0)  # a bright patch up and to one side: far from the studio preset
    sky[8:] = 0.05
    write_exr(tmp_path / "sky.exr", {c: sky[..., i] for i, c in enumerate("RGB")})
    blender_addon.register()
    bpy.ops.wm.read_homefile(use_empty=True)
    s = bpy.context.scene.relight_photo
    s.model_path, s.quality, s.mask_mode = str(model), "DRAFT", "NETWORK"
    s.light_kind, s.preset = "PRESET", "studio"
    s.rotation, s.exposure, s.strength = 0.0, 0.0, 1.0
    bpy.ops.ed.undo_push(message="start")
    yield tmp_path
    bpy.ops.wm.read_homefile()
    blender_addon.unregister()


def _press_relight(name: str) -> set:
    # positional "EXEC_DEFAULT", True: run as a button press does, with its undo step
    return bpy.ops.relight_photo.relight("EXEC_DEFAULT", True, image_name=name, synchronous=True)


def _settings():
    return bpy.context.scene.relight_photo


def _set(**values) -> None:
    """Change settings as the panel does, then the undo step Blender pushes for a property edit."""
    settings = bpy.context.scene.relight_photo
    for key, value in values.items():
        setattr(settings, key, value)
    bpy.ops.ed.undo_push(message="panel")


def _expected(name: str) -> dict:
    """Every output the photo's session gives under the settings the panel shows now."""
    from blender_addon.worker import engine
    from blender_addon.blender.bl_light import current_dials

    pid = bpy.data.images[name][bl_images.PHOTO_ID]
    session = state.SESSIONS[pid]
    light, rotation, exposure, strength = current_dials(bpy.context, session)
    d = session.decomposition
    coeffs = engine.coefficients(d, light, rotation)
    want = d.layers(coeffs, exposure_ev=exposure)
    want["relit"] = d.relight(coeffs, exposure_ev=exposure)
    return want


def _assert_outputs_follow_the_panel(name: str) -> None:
    want = _expected(name)
    for layer in ("relit", "albedo", "shading", "residual"):
        np.testing.assert_allclose(pixels(f"{name}.{layer}")[..., :3], want[layer], atol=CLOSE, err_msg=layer)
    np.testing.assert_allclose(pixels(f"{name}.alpha")[..., 0], want["alpha"], atol=CLOSE, err_msg="alpha")


def test_undo_and_redo_of_a_second_relight_leave_the_outputs_of_the_settings_shown(addon):
    name = bpy.data.images.load(str(addon / "person.png")).name
    assert _press_relight(name) == {"FINISHED"}
    preset = {layer: pixels(f"{name}.{layer}").copy() for layer in ("relit", "shading", "alpha")}
    assert preset["alpha"][..., 0].max() > 0.5  # the figure is in the matte
    _set(light_kind="HDR", hdr_path=str(addon / "sky.exr"))
    assert _press_relight(name) == {"FINISHED"}
    hdr = {layer: pixels(f"{name}.{layer}").copy() for layer in ("relit", "shading")}
    assert np.abs(hdr["relit"] - preset["relit"]).max() > 0.05  # the two lights differ visibly

    assert bpy.ops.ed.undo() == {"FINISHED"}  # Ctrl+Z: back before the second Relight
    # undo frees and re-reads the scene's data: its settings are looked up again after each step
    assert _settings().light_kind == "HDR"  # the undo step is the press, not the light change
    _assert_outputs_follow_the_panel(name)
    assert bpy.ops.ed.undo() == {"FINISHED"}  # and before the light change: the panel shows Preset
    assert _settings().light_kind == "PRESET"
    _assert_outputs_follow_the_panel(name)
    np.testing.assert_allclose(pixels(f"{name}.relit"), preset["relit"], atol=CLOSE)
    np.testing.assert_allclose(pixels(f"{name}.alpha"), preset["alpha"], atol=CLOSE)

    assert bpy.ops.ed.redo() == {"FINISHED"}
    assert bpy.ops.ed.redo() == {"FINISHED"}  # Ctrl+Shift+Z twice: the HDR Relight again
    assert _settings().light_kind == "HDR"
    _assert_outputs_follow_the_panel(name)
    np.testing.assert_allclose(pixels(f"{name}.relit"), hdr["relit"], atol=CLOSE)
    np.testing.assert_allclose(pixels(f"{name}.alpha"), preset["alpha"], atol=CLOSE)  # not black


def test_with_a_ui_undo_remakes_the_outputs_on_a_worker_one_per_timer_call(addon, monkeypatch):
    from blender_addon.blender import bl_layers, bl_ops

    name = bpy.data.images.load(str(addon / "person.png")).name
    assert _press_relight(name) == {"FINISHED"}
    preset_alpha = pixels(f"{name}.alpha").copy()
    _set(light_kind="HDR", hdr_path=str(addon / "sky.exr"))
    assert _press_relight(name) == {"FINISHED"}
    monkeypatch.setattr(bl_layers, "updates_immediately", lambda: False)
    try:
        assert bpy.ops.ed.undo() == {"FINISHED"}
        assert bpy.ops.ed.undo() == {"FINISHED"}
        assert _settings().light_kind == "PRESET"
        # the handler only starts the worker: the main thread writes nothing itself
        assert "layers" in state.RUNNING and bpy.app.timers.is_registered(bl_layers.poll_layers)
        calls = 0
        while "layers" in state.RUNNING and calls < 200:
            state.RUNNING["layers"].wait(60)
            bl_layers.poll_layers()  # what Blender's timer calls
            calls += 1
        assert "layers" not in state.RUNNING and calls >= 5  # relit, alpha, albedo, shading, residual
        _assert_outputs_follow_the_panel(name)
        np.testing.assert_allclose(pixels(f"{name}.alpha"), preset_alpha, atol=CLOSE)
    finally:
        for timer in bl_ops._TIMERS:
            if bpy.app.timers.is_registered(timer):
                bpy.app.timers.unregister(timer)
        state.RUNNING.pop("layers", None)
