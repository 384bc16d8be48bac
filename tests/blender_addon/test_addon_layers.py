"""Relight Photo add-on: the outputs are made and handed to Blender one at a time, in place.

Issue 24: a 24 MP Relight peaked at 6.4 GB. What keeps it under 3 GB
(benchmarks/bench_addon_memory.py measures it) is asserted here on small
photos: each layer is made and written before the next is made, the relit image
and the layers are composited straight into the buffer Blender copies from
(same values as the full-size arrays they replace), the person-matte check image
is screen-sized, Relight again shares the photo and its person matte, and Save
Layers writes the same layers it would have computed all at once."""

from __future__ import annotations

import math

import numpy as np
import pytest

import bpy

from blender_addon.blender import bl_images, bl_layers
from blender_addon.worker import engine, state, work
from blender_addon.logic import pixel_buffers
from relight.lighting import sh
from relight.network.decomposition import Decomposition
from relight.lighting.light import sh_light
from relight.imaging.resample import resize_linear
from addon_support import pixels

ORDER = 4
# the in-place paths do the same float32 operations on the same values as the
# array-returning ones (only the memory layout differs): equal to rounding, far below this
SAME = 1e-6


def _decomposition(mask: bool, residual: bool = True, seed: int = 0) -> Decomposition:
    """A random decomposition of a 50 x 40 photo, the person in a crop seen at 12 x 10."""
    rng = np.random.default_rng(seed)
    h, w, n = 12, 10, sh.num_coeffs(ORDER)
    alpha = (rng.random((h, w)) > 0.3).astype(np.float32) * rng.uniform(0.5, 1.0, (h, w)).astype(np.float32)
    photo = rng.uniform(0.02, 0.9, (50, 40, 3)).astype(np.float32)
    box = (5, 45, 4, 36)
    full_mask = None
    if mask:
        full_mask = np.zeros((50, 40), np.float32)
        full_mask[5:45, 4:36] = rng.uniform(0.0, 1.0, (40, 32)).astype(np.float32)
    transport = rng.normal(0.0, 0.3, (h, w, n)).astype(np.float32)
    transport[..., 0] += 1.0
    return Decomposition(albedo=rng.uniform(0.1, 0.9, (h, w, 3)).astype(np.float32), transport=transport,
                         residual=rng.normal(0.0, 0.05, (h, w, n)).astype(np.float32) * residual,
                         light=sh_light("studio", ORDER), alpha=alpha, box=box, working_size=(h, w), photo=photo,
                         photo_working=resize_linear(photo[5:45, 4:36], h, w), mask=full_mask, sh_order=ORDER)


@pytest.mark.parametrize("mask", [False, True], ids=["network matte", "mask"])
@pytest.mark.parametrize("strength", [0.0, 0.4, 1.0])
def test_the_relit_buffer_is_the_relit_photo_packed(mask, strength):
    d = _decomposition(mask)
    light = sh_light("studio", ORDER)
    for exposure in (0.0, 1.3):
        buffer = engine.relit_rgba(d, light, 35.0, exposure, strength)
        relit = d.relight(engine.coefficients(d, light, 35.0), exposure_ev=exposure)
        want = pixel_buffers.to_blender_rgba(pixel_buffers.blend(relit, d.photo, strength), np.empty_like(buffer))
        np.testing.assert_allclose(buffer, want, atol=SAME, rtol=SAME)


@pytest.mark.parametrize("layer", ["alpha", "albedo", "shading", "residual"])
def test_each_layer_buffer_is_the_layer_packed(layer):
    d = _decomposition(mask=False, seed=1)
    session = state.PhotoSession(photo_id="p", source="p.png", photo=d.photo, decomposition=d, model_path="",
                                 quality="DRAFT", mask_key=("NETWORK", ""))
    light = sh_light("studio", ORDER)
    buffer = work.layer_buffer(session, layer, (light, 20.0, 0.5, 1.0))
    want = d.layer(layer, engine.coefficients(d, light, 20.0), 0.5)
    np.testing.assert_allclose(buffer, pixel_buffers.to_blender_rgba(want, np.empty_like(buffer)), atol=SAME, rtol=SAME)
    # the buffer's own memory is written (bottom row first), not a full-size map beside it
    assert buffer.reshape(50, 40, 4)[-1 - 20, 15, 3] == 1.0


# ------------------------------------------------------------------ under bpy

LAYERS = ("alpha", "albedo", "shading", "residual")


@pytest.fixture
def addon_settings():
    """Neutral dials for the conftest `addon` fixture."""
    return {"rotation": 0.0, "exposure": 0.0, "strength": 1.0}


def _relight(name):
    return bpy.ops.relight_photo.relight(image_name=name, synchronous=True)


def _record(monkeypatch) -> list:
    """('make', layer) and ('write', layer) as work.layer_buffer and bl_layers' writes happen."""
    events = []
    make, write = work.layer_buffer, bl_layers.write_output
    monkeypatch.setattr(work, "layer_buffer", lambda s, layer, d: events.append(("make", layer)) or make(s, layer, d))
    monkeypatch.setattr(bl_layers, "write_output",
                        lambda s, layer, *a: events.append(("write", layer)) or write(s, layer, *a))
    return events


def test_relight_and_reopen_make_and_write_one_layer_at_a_time(addon, monkeypatch):
    name = bpy.data.images.load(str(addon / "person.png")).name
    events = _record(monkeypatch)
    assert _relight(name) == {"FINISHED"}
    one_by_one = [(kind, layer) for layer in LAYERS for kind in ("make", "write")]
    assert events == one_by_one
    events.clear()
    bpy.ops.wm.save_as_mainfile(filepath=str(addon / "shot.blend"))
    bpy.ops.wm.open_mainfile(filepath=str(addon / "shot.blend"))
    assert events == one_by_one  # restoring too (the relit image comes from the restore job itself)
    session = state.SESSIONS[bpy.data.images[name][bl_images.PHOTO_ID]]
    want = session.decomposition.layers(sh_light("studio", ORDER))
    for layer in ("albedo", "shading", "residual"):
        np.testing.assert_allclose(pixels(f"{name}.{layer}")[..., :3], want[layer], atol=1e-5)


def test_the_person_matte_check_image_is_screen_sized_on_a_large_photo(addon, monkeypatch):
    from evaluation.matte_eval import EVAL_DIR

    monkeypatch.setattr(work, "PREVIEW_LONG_SIDE", 128)  # grace_hopper.jpg, 512 x 600, counts as large
    photo = bpy.data.images.load(str(EVAL_DIR / "grace_hopper.jpg"))
    bpy.context.scene.relight_photo.mask_mode = "AUTO"
    assert _relight(photo.name) == {"FINISHED"}
    session = state.SESSIONS[photo[bl_images.PHOTO_ID]]
    preview = session.preview
    assert preview is not None and preview.size == (128, 109)
    matte = bpy.data.images[f"{photo.name}.matte"]
    assert tuple(matte.size) == (109, 128) and matte.alpha_mode == "STRAIGHT"
    cut_out = pixels(matte.name)
    np.testing.assert_allclose(cut_out[..., 3], preview.mask, atol=1e-7)
    np.testing.assert_allclose(cut_out[..., :3], preview.photo, atol=1e-7)
    # the layers themselves stay full size: '.alpha' is the person matte the relight used
    assert tuple(bpy.data.images[f"{photo.name}.alpha"].size) == (512, 600)
    np.testing.assert_allclose(pixels(f"{photo.name}.alpha")[..., 0], session.decomposition.mask, atol=1e-7)


def test_relight_again_shares_the_photo_and_its_person_matte_but_not_a_changed_photo(addon, monkeypatch):
    from PIL import Image

    from evaluation.matte_eval import EVAL_DIR

    Image.open(EVAL_DIR / "grace_hopper.jpg").save(addon / "grace.png")
    photo = bpy.data.images.load(str(addon / "grace.png"))
    settings = bpy.context.scene.relight_photo
    settings.mask_mode = "AUTO"
    settings.person = "1"  # one person's matte is kept for the next press (Everyone finds everyone again)
    assert _relight(photo.name) == {"FINISHED"}
    pid = photo[bl_images.PHOTO_ID]
    first = state.SESSIONS[pid]
    found, find = [], engine.person_matte
    monkeypatch.setattr(engine, "person_matte", lambda *a: found.append(1) or find(*a))
    settings.rotation = math.radians(60.0)
    assert _relight(photo.name) == {"FINISHED"}
    again = state.SESSIONS[pid]
    assert again is not first and again.photo is first.photo and again.decomposition.mask is first.decomposition.mask
    assert found == [] and again.people == first.people
    # a preset with another person segmenter looks for the person again
    from relight.network import quality

    other = next(p for p in quality.PRESETS if p.matte_method != quality.preset(settings.quality).matte_method)
    before = settings.quality
    settings.quality = other.key.upper()
    try:
        assert _relight(photo.name) == {"FINISHED"}
        assert found == [1]
    finally:
        settings.quality = before
    assert _relight(photo.name) == {"FINISHED"}
    assert found == [1, 1]
    found.clear()
    # the file changes on disk: decoded again, and the person looked for again
    pixels_now = np.asarray(Image.open(addon / "grace.png")).copy()
    pixels_now[:20] = 0
    Image.fromarray(pixels_now).save(addon / "grace.png")
    photo.reload()
    assert _relight(photo.name) == {"FINISHED"}
    changed = state.SESSIONS[pid]
    assert changed.photo is not first.photo and found == [1]
    assert float(changed.photo[:20].max()) == 0.0


def test_save_layers_writes_the_layers_under_the_current_dials(addon):
    import OpenEXR

    from relight.files.exr import read_exr

    name = bpy.data.images.load(str(addon / "person.png")).name
    assert _relight(name) == {"FINISHED"}
    settings = bpy.context.scene.relight_photo
    settings.rotation, settings.exposure, settings.strength = math.radians(45.0), 0.7, 0.6
    out = addon / "layers.exr"
    assert bpy.ops.relight_photo.save_layers(filepath=str(out), image_name=name) == {"FINISHED"}
    assert OpenEXR.global_thread_count() >= 1  # compressed on the cores, not on one thread
    session = state.SESSIONS[bpy.data.images[name][bl_images.PHOTO_ID]]
    d = session.decomposition
    light = sh_light("studio", ORDER, rotation_deg=45.0)
    want = d.layers(light, exposure_ev=0.7)
    ch = read_exr(out)
    # the same float32 dot products of n terms, summed in another order (BLAS blocking, threads):
    # each within n u sum|E_i L_i| of the exact value (u = 2^-24), so two within twice that
    n = d.transport.shape[-1]
    L = light.astype(np.float32) * np.float32(2.0 ** 0.7)
    for key, pass_name in (("albedo", "Albedo"), ("shading", "Shading"), ("residual", "Residual")):
        got = np.dstack([ch[f"Relight.{pass_name}.{c}"] for c in "RGB"])
        part = {"albedo": None, "shading": d.transport, "residual": d.residual}[key]
        bound = 0.0 if part is None else 2 * n * 2.0 ** -24 * float((np.abs(part) @ np.abs(L)).max())
        np.testing.assert_allclose(got, want[key], atol=1e-6 + bound)
    np.testing.assert_allclose(ch["Relight.Alpha.A"], want["alpha"], atol=1e-6)
    relit = np.dstack([ch[f"Relight.Relit.{c}"] for c in "RGB"])
    np.testing.assert_allclose(relit, pixel_buffers.blend(d.relight(light, exposure_ev=0.7), d.photo, 0.6), atol=1e-6)
    np.testing.assert_allclose(relit, pixels(f"{name}.relit")[..., :3], atol=1e-6)  # what the panel shows
