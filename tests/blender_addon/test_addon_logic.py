"""Relight Photo add-on: the plain-Python logic (no bpy): quality table, masks,
lights, compositing, model lookup, the worker thread, manifest rules."""

from __future__ import annotations

import json
import re
import threading
from pathlib import Path

import numpy as np
import pytest

from blender_addon.worker import engine, jobs, work
from blender_addon.logic import (
    light_sources, mask_choice, output_names, photo_checks, photo_pixels, pixel_buffers, quality,
)
from blender_addon import manifest
from relight.lighting import sh, sh_projection
from relight.files.exr import write_exr
from relight.lighting.light import sh_light

ADDON_DIR = Path(__file__).resolve().parents[2] / "blender_addon"
EPS32 = float(np.finfo(np.float32).eps)


# ------------------------------------------------------------------ quality table

def test_quality_presets_are_ordered_and_match_the_runtime_sizes():
    from relight.network import quality as core_quality

    presets = [quality.preset(key) for key, _, _ in quality.enum_items()]
    work = [p.work() for p in presets]  # fastest first: more work in some part, less in none
    assert len(set(work)) == 3 and all(all(x <= y for x, y in zip(a, b)) for a, b in zip(work, work[1:]))
    assert presets == [core_quality.preset(key) for key in ("draft", "balanced", "best")]
    assert quality.preset(quality.DEFAULT_QUALITY).key == "balanced"
    assert [i[0] for i in quality.enum_items()] == ["DRAFT", "BALANCED", "BEST"]
    with pytest.raises(ValueError, match="unknown quality preset 'ULTRA'"):
        quality.preset("ULTRA")


# ------------------------------------------------------------------ names

def test_output_names_map_back_to_their_photo():
    assert output_names.output_name("p.png", "relit") == "p.png.relit"
    existing = {"p.png", "p.png.relit", "p.png.alpha"}
    assert output_names.source_of("p.png.relit", existing) == "p.png"
    assert output_names.source_of("p.png.alpha", existing) == "p.png"
    assert output_names.source_of("p.png", existing) == "p.png"
    # an image that merely ends like an output, with no such photo, is itself
    assert output_names.source_of("q.relit", existing) == "q.relit"
    with pytest.raises(ValueError, match="unknown layer"):
        output_names.output_name("p.png", "depth")


# ------------------------------------------------------------------ masks

def test_mask_modes():
    shape = (4, 6)
    assert mask_choice.choose_mask("AUTO", shape, None) is None
    alpha = np.linspace(0, 1, 24, dtype=np.float32).reshape(shape)
    np.testing.assert_array_equal(mask_choice.choose_mask("IMAGE_ALPHA", shape, alpha), alpha)
    # another image without a varying alpha: its grey level, the mean of R, G, B
    rgb = np.zeros(shape + (3,), np.float32)
    rgb[..., 1] = 0.6
    m = mask_choice.choose_mask("IMAGE", shape, None, rgb, np.ones(shape, np.float32), "m")
    np.testing.assert_allclose(m, 0.2, rtol=2 * EPS32)
    # with a varying alpha: the alpha
    np.testing.assert_array_equal(mask_choice.choose_mask("IMAGE", shape, None, rgb, alpha, "m"), alpha)


@pytest.mark.parametrize("args, message", [
    (("IMAGE_ALPHA", (4, 6), None), "The photo has no alpha channel"),
    (("IMAGE_ALPHA", (4, 6), np.zeros((4, 6), np.float32)), "The mask is empty"),
    (("IMAGE", (4, 6), None), "Choose a mask image"),
    (("IMAGE", (4, 6), None, np.ones((5, 6, 3), np.float32), None, "m.png"),
     "The mask image 'm.png' is 6x5 but the photo is 6x4"),
    (("IMAGE", (4, 6), None, np.zeros((4, 6, 3), np.float32), None, "m"), "The mask is empty"),
])
def test_bad_masks_are_one_sentence_errors(args, message):
    with pytest.raises(ValueError, match=re.escape(message)):
        mask_choice.choose_mask(*args)


# ------------------------------------------------------------------ lights

def _equirect(h=16, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(0.1, 2.0, (h, 2 * h, 3)).astype(np.float32)


def test_hdr_file_light_accepts_an_exr_and_rejects_bad_files(tmp_path):
    env = _equirect()
    good = tmp_path / "env.exr"
    write_exr(good, {c: env[..., i] for i, c in enumerate("RGB")})
    resolved = light_sources.hdr_file_light(str(good), 4)
    np.testing.assert_array_equal(resolved.base, sh_projection.project_equirect(env, 4))  # projected once, here
    assert resolved.target == 0.8 and sh.mean_luminance(resolved.at(30.0)) == pytest.approx(0.8, rel=1e-12)
    with pytest.raises(ValueError, match="Choose an HDR file"):
        light_sources.hdr_file_light("", 4)
    with pytest.raises(ValueError, match="does not exist"):
        light_sources.hdr_file_light(str(tmp_path / "absent.exr"), 4)
    junk = tmp_path / "junk.hdr"
    junk.write_bytes(b"this is not an image")
    with pytest.raises(ValueError, match=r"^The HDR file 'junk.hdr' cannot be read as an equirectangular map"):
        light_sources.hdr_file_light(str(junk), 4)


def test_preset_light_checks_the_name():
    names = light_sources.preset_names()
    assert "studio" in names
    np.testing.assert_array_equal(light_sources.preset_light("studio", 2).at(45.0),
                                  sh_light("studio", 2, rotation_deg=45.0))
    with pytest.raises(ValueError, match="The light preset 'nowhere' is not available"):
        light_sources.preset_light("nowhere", 2)


def test_world_pixels_are_scaled_like_hdr_files():
    env = _equirect()
    coeffs = light_sources.equirect_light(env, 4).at(0.0)
    # the runtime scales maps to mean luminance 0.8 (docs/conventions.md)
    assert sh.mean_luminance(coeffs) == pytest.approx(0.8, rel=1e-9)
    raw = sh_projection.project_equirect(env, 4)
    # same direction in coefficient space: only a scale differs
    scale = coeffs[0, 0] / raw[0, 0]
    np.testing.assert_allclose(coeffs, raw * scale, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="twice as wide as high"):
        light_sources.equirect_light(env[:, :20], 4)
    # a black World: the artist's words, not "mean luminance 0 <= 0"
    with pytest.raises(ValueError, match=r"^The World is black, so it gives no light: raise its Background"):
        light_sources.equirect_light(np.zeros((8, 16, 3), np.float32), 4)


def test_black_hdr_file_is_named_in_the_artists_words(tmp_path):
    black = tmp_path / "black.exr"
    write_exr(black, {c: np.zeros((8, 16), np.float32) for c in "RGB"})
    with pytest.raises(ValueError) as info:
        light_sources.hdr_file_light(str(black), 4)
    assert str(info.value) == "The HDR file 'black.exr' is black, so it gives no light: choose another file."


# ------------------------------------------------------------------ photo checks

def _textured(h=64, w=48):
    rng = np.random.default_rng(0)
    return rng.uniform(0.05, 0.8, (h, w, 3)).astype(np.float32)


@pytest.mark.parametrize("photo, message", [
    (np.full((4, 4, 3), 0.5, np.float32), "The photo is only 4 x 4 pixels, too small to show a person"),
    (np.zeros((64, 48, 3), np.float32), "The photo is black: there is no person to see in it."),
    (np.full((64, 48, 3), 1e-3, np.float32), "The photo is black"),
    (np.ones((64, 48, 3), np.float32), "The photo is white (blown out)"),
    (np.full((64, 48, 3), 0.4, np.float32), "The photo is one flat colour"),
])
def test_photos_without_a_visible_person_are_refused(photo, message):
    with pytest.raises(ValueError) as info:
        photo_checks.check_photo_content(photo)
    assert str(info.value).startswith(message), str(info.value)


def test_ordinary_and_dark_but_real_photos_pass_the_checks():
    photo_checks.check_photo_content(_textured())
    photo_checks.check_photo_content(_textured() * 0.02)   # a dark photo (max ~0.016 linear) is not black
    photo_checks.check_photo_size(32, 32)
    with pytest.raises(ValueError, match="31 x 200 pixels"):
        photo_checks.check_photo_size(31, 200)


def test_blender_pixels_decode_like_the_file_and_round_trip():
    from relight.imaging.colour import srgb_decode

    rng = np.random.default_rng(1)
    codes = rng.integers(0, 256, (5, 7, 4)).astype(np.uint8)
    # Blender gives code / 255, bottom row first
    flat = (codes[::-1].astype(np.float32) / 255.0).reshape(-1)
    px = photo_pixels.photo_from_blender(flat, (5, 7, 4), srgb=True, with_alpha=True, name="p")
    # the float64 curve rounded once to float32: within half a float32 step (2^-24 relative)
    np.testing.assert_allclose(px.rgb, srgb_decode(codes[..., :3] / 255.0), rtol=2.0 ** -24, atol=0)
    np.testing.assert_allclose(px.alpha, codes[..., 3] / 255.0, rtol=2.0 ** -24, atol=0)
    # the digest is of the decoded values: equal for equal pixels, different otherwise
    again = photo_pixels.photo_from_blender(flat.copy(), (5, 7, 4), srgb=True, with_alpha=True, name="p")
    assert again.digest == px.digest
    flat[0] = 0.5
    assert photo_pixels.photo_from_blender(flat, (5, 7, 4), srgb=True, with_alpha=True, name="p").digest != px.digest
    # to_blender_rgba is the inverse layout: RGBA, bottom row first
    rgb = rng.uniform(0, 1, (5, 7, 3)).astype(np.float32)
    out = pixel_buffers.to_blender_rgba(rgb).reshape(5, 7, 4)
    np.testing.assert_array_equal(out[::-1, :, :3], rgb)
    np.testing.assert_array_equal(out[..., 3], 1.0)
    grey = pixel_buffers.to_blender_rgba(rgb[..., 0]).reshape(5, 7, 4)
    np.testing.assert_array_equal(grey[::-1, :, 2], rgb[..., 0])
    cut = pixel_buffers.to_blender_rgba(rgb, alpha=rgb[..., 1]).reshape(5, 7, 4)
    np.testing.assert_array_equal(cut[::-1], np.dstack([rgb, rgb[..., 1]]))
    tall = rng.uniform(0, 1, (300, 400, 4)).astype(np.float32)  # more rows than one block (163)
    np.testing.assert_array_equal(pixel_buffers.to_blender_rgba(tall).reshape(300, 400, 4)[::-1], tall)


def test_the_cli_and_the_addon_read_a_png_to_the_same_floats(tmp_path):
    """One decoder of 8-bit sRGB (relight.imaging.colour.decode_srgb_codes): `relight image` (relight.files.photo),
    the add-on's file reader and the pixels Blender hands over (code / 255) give the same floats."""
    from PIL import Image

    from relight.imaging.colour import srgb_decode
    from relight.files.photo import read_photo

    codes = np.zeros((16, 64, 4), np.uint8)
    codes[..., 0] = np.arange(256).reshape(4, 64).repeat(4, axis=0)  # every code value
    codes[..., 1] = codes[..., 0][::-1]
    codes[..., 2] = np.roll(codes[..., 0], 7, axis=1)
    codes[..., 3] = codes[..., 0][:, ::-1]
    path = tmp_path / "p.png"
    Image.fromarray(codes, "RGBA").save(path)
    cli_rgb, cli_alpha = read_photo(path)
    from_file = photo_pixels.read_file(str(path), (16, 64), True, "p.png")
    flat = (codes[::-1].astype(np.float32) / np.float32(255.0)).reshape(-1)  # as Blender stores bytes
    from_blender = photo_pixels.photo_from_blender(flat, (16, 64, 4), srgb=True, with_alpha=True, name="p.png")
    for px in (from_file, from_blender):
        np.testing.assert_array_equal(px.rgb, cli_rgb)  # one table: the same floats, not merely close
        np.testing.assert_array_equal(px.alpha, cli_alpha)
    assert from_file.digest == from_blender.digest
    np.testing.assert_allclose(cli_rgb, srgb_decode(codes[..., :3] / 255.0), rtol=2.0 ** -24, atol=0)


def test_the_relight_job_refuses_a_black_photo_before_loading_anything():
    black = photo_pixels.PhotoPixels(np.zeros((64, 48, 3), np.float32), None, "d")
    plan = dict(read_photo=lambda: black, relighter=None, model_path="/nonexistent/model.onnx",
                light=("PRESET", "studio"), mask=dict(mode="NETWORK"))
    progress = jobs.Progress()
    with pytest.raises(ValueError, match=r"^The photo is black"):  # not "the model file does not exist"
        work.relight_work(plan, progress, engine.CancelToken())
    assert [stage for stage, _t in progress.history] == ["Reading the photo"]


def test_buffer_pool_reuses_large_buffers_and_keeps_a_bounded_number():
    pool = pixel_buffers.BufferPool(keep=2)
    n = pixel_buffers.BufferPool.MIN_VALUES
    a = pool.take(n)
    pool.give(a)
    pool.give(a)                      # given twice: kept once
    assert len(pool) == 1 and pool.take(n) is a and len(pool) == 0
    pool.give(np.empty(16, np.float32))          # small: not pooled
    pool.give(np.empty(2 * n, np.float32)[:n])   # a view of someone else's memory: not pooled
    assert len(pool) == 0
    bufs = [np.empty(n, np.float32) for _ in range(3)]
    for b in bufs:
        pool.give(b)
    assert len(pool) == 2 and pool.take(n) in (bufs[1], bufs[2])  # the oldest went
    assert pool.take(n + 4).size == n + 4    # no buffer of that length: a new one


def test_an_8bit_file_read_by_the_worker_equals_blenders_codes(tmp_path):
    from PIL import Image

    rng = np.random.default_rng(2)
    codes = rng.integers(0, 256, (6, 9, 3)).astype(np.uint8)
    Image.fromarray(codes, "RGB").save(tmp_path / "p.png")
    from_file = photo_pixels.read_file(str(tmp_path / "p.png"), (6, 9), False, "p.png")
    flat = (codes[::-1].astype(np.float32) / 255.0).reshape(-1)
    from_blender = photo_pixels.photo_from_blender(flat, (6, 9, 3), srgb=True, with_alpha=False, name="p.png")
    np.testing.assert_array_equal(from_file.rgb, from_blender.rgb)
    assert from_file.digest == from_blender.digest
    with pytest.raises(ValueError, match="changed on disk since Blender loaded it"):
        photo_pixels.read_file(str(tmp_path / "p.png"), (7, 9), False, "p.png")


def test_saved_relight_sits_next_to_the_blend():
    assert output_names.saved_relight_path("/a/b/shot.blend", "abc") == "/a/b/shot_relight/abc.npz"


# ------------------------------------------------------------------ compositing

def test_strength_blends_linearly_between_photo_and_relit():
    rng = np.random.default_rng(3)
    photo = rng.uniform(0, 1, (5, 7, 3)).astype(np.float32)
    relit = rng.uniform(0, 2, (5, 7, 3)).astype(np.float32)
    relit[0] = photo[0]  # background row: the runtime leaves it bit for bit
    np.testing.assert_array_equal(pixel_buffers.blend(relit, photo, 0.0), photo)
    np.testing.assert_array_equal(pixel_buffers.blend(relit, photo, 1.0), relit)
    np.testing.assert_array_equal(pixel_buffers.blend(relit, photo, 7.0), relit)  # clamped to 1
    quarter = pixel_buffers.blend(relit, photo, 0.25)
    assert quarter.dtype == np.float32 and quarter.shape == photo.shape
    # (relit - photo) * 0.25 + photo: three float32 roundings of values <= 2
    np.testing.assert_allclose(quarter, 0.75 * photo + 0.25 * relit, atol=4 * EPS32)
    np.testing.assert_array_equal(quarter[0], photo[0])
    with pytest.raises(ValueError, match="differ in size"):
        pixel_buffers.blend(relit[:4], photo, 1.0)


def test_env_flag(monkeypatch):
    for value, expected in (("1", True), ("true", True), (" Yes ", True), ("on", True),
                            ("0", False), ("", False), ("no", False)):
        monkeypatch.setenv("RELIGHT_PHOTO_TEST_FLAG", value)
        assert jobs.env_flag("RELIGHT_PHOTO_TEST_FLAG") is expected
    monkeypatch.delenv("RELIGHT_PHOTO_TEST_FLAG")
    assert jobs.env_flag("RELIGHT_PHOTO_TEST_FLAG") is False


# ------------------------------------------------------------------ model lookup

def test_model_lookup(tmp_path, monkeypatch):
    from relight import models

    with pytest.raises(ValueError, match=r"^The model file '.*absent.onnx' does not exist\.$"):
        quality.model_path_for("BALANCED", str(tmp_path / "absent.onnx"))
    given = tmp_path / "m.onnx"
    given.write_bytes(b"x")
    assert quality.model_path_for("DRAFT", str(given)) == given
    empty = tmp_path / "reg" / "models.json"
    empty.parent.mkdir()
    empty.write_text(json.dumps({"format": models.REGISTRY_FORMAT, "default": None, "models": {}}))
    monkeypatch.setattr(models, "REGISTRY_PATH", empty)
    with pytest.raises(ValueError, match="No relighting model is installed"):
        quality.model_path_for("BEST")
    # a registered default whose file is gone
    empty.write_text(json.dumps({"format": models.REGISTRY_FORMAT, "default": "a",
                                 "models": {"a": {"file": "a.onnx", "sha256": "0" * 64}}}))
    with pytest.raises(ValueError, match="The relighting model 'a.onnx' is missing"):
        quality.model_path_for("BEST")
    (empty.parent / "a.onnx").write_bytes(b"x")
    assert quality.model_path_for("BEST") == empty.parent / "a.onnx"


def test_worker_errors_become_one_sentence():
    assert str(engine.user_error(ValueError("bad photo\nmore detail"))) == "bad photo."
    assert "lower quality" in str(engine.user_error(MemoryError()))
    assert str(engine.user_error(RuntimeError("ort crashed"))) == "The network failed (RuntimeError: ort crashed.)"
    with pytest.raises(ValueError, match="does not exist"):
        engine.open_relighter("/nonexistent/model.onnx")


# ------------------------------------------------------------------ worker thread

def test_background_job_runs_off_the_calling_thread():
    release = threading.Event()
    seen = {}

    def work():
        seen["thread"] = threading.current_thread()
        release.wait(10)
        return 42

    job = jobs.BackgroundJob(work, label="t")
    # the caller is not blocked: the job is still waiting for us
    assert job.poll() is jobs.JobState.RUNNING
    with pytest.raises(RuntimeError, match="has no result"):
        job.result
    release.set()
    assert job.wait(10) is jobs.JobState.DONE
    assert job.result == 42
    assert seen["thread"] is not threading.main_thread()


def test_cancel_token_stops_the_job_between_steps_and_sets_run_options():
    token = engine.CancelToken()
    options = token.run_options()
    assert options.terminate is False
    started, steps = threading.Event(), []

    def work():
        for i in range(1000):
            token.check()
            steps.append(i)
            started.set()
            threading.Event().wait(0.005)
        return "all"

    job = jobs.BackgroundJob(work, label="t", cancel_token=token)
    started.wait(10)
    job.cancel()
    assert job.poll() is jobs.JobState.CANCELLED
    job.wait(10)
    assert job.finished and len(steps) < 1000           # the work itself stopped
    assert isinstance(job.error, engine.Cancelled)
    assert options.terminate is True                    # a running inference is told to stop
    assert token.run_options().terminate is True        # and a later one never starts


def test_cancelled_job_drops_its_result_and_failed_job_keeps_its_error():
    release = threading.Event()
    job = jobs.BackgroundJob(lambda: release.wait(10) or "late", label="c")
    job.cancel()
    assert job.poll() is jobs.JobState.CANCELLED
    release.set()
    job.wait(10)
    assert job.poll() is jobs.JobState.CANCELLED
    with pytest.raises(RuntimeError):
        job.result

    def boom():
        raise ValueError("no person found")

    failed = jobs.BackgroundJob(boom, label="f")
    assert failed.wait(10) is jobs.JobState.FAILED
    assert isinstance(failed.error, ValueError)


# ------------------------------------------------------------------ what the Blender layer hands over

def test_layers_are_handed_to_blender_relit_first_in_a_fixed_order():
    buffers = {"matte": 1, "shading": 2, "relit": 3, "alpha": 4, "unknown": 5}
    assert output_names.layers_in_order(buffers) == ["relit", "alpha", "shading", "matte"]
    assert output_names.layers_in_order({}) == []


def test_mask_channels_of_stored_mask_pixels():
    grey = np.arange(4, dtype=np.float32).reshape(2, 2, 1)
    rgb, alpha = mask_choice.mask_channels(grey)
    assert rgb.shape == (2, 2, 3) and alpha is None
    assert np.array_equal(rgb[..., 2], grey[..., 0]) and np.array_equal(rgb[..., 0], rgb[..., 1])
    rgba = np.arange(16, dtype=np.float32).reshape(2, 2, 4)
    rgb, alpha = mask_choice.mask_channels(rgba)
    assert np.array_equal(rgb, rgba[..., :3]) and np.array_equal(alpha, [[3.0, 7.0], [11.0, 15.0]])
    assert mask_choice.mask_channels(rgba[..., :3])[1] is None


def test_saved_mask_key_gives_the_mask_inputs_it_was_run_with():
    auto = mask_choice.saved_mask_inputs(("AUTO", "3"))
    assert (auto["mode"], auto["person"], auto["use_photo_alpha"], auto["rgb"]) == ("AUTO", 3, False, None)
    alpha = mask_choice.saved_mask_inputs(["IMAGE_ALPHA", ""])
    assert (alpha["person"], alpha["use_photo_alpha"]) == (1, True)
    image = mask_choice.saved_mask_inputs(("IMAGE", "mask.png"))
    assert (image["name"], image["person"], image["alpha"]) == ("mask.png", 1, None)


def test_progress_bar_interpolates_inside_the_network_stage_only():
    progress = jobs.Progress()
    progress.stage, progress.fraction, progress.stage_started = jobs.NETWORK_STAGE, 0.10, 100.0
    assert jobs.shown_fraction(progress, 4.0, 0.45, now=102.0) == pytest.approx(0.10 + 0.5 * 0.45)
    assert jobs.shown_fraction(progress, 4.0, 0.30, now=110.0) == pytest.approx(0.40)  # capped at the share
    assert jobs.shown_fraction(progress, None, 0.45, now=102.0) == pytest.approx(0.10)  # no earlier run
    progress.stage = "Reading the photo"
    assert jobs.shown_fraction(progress, 4.0, 0.45, now=102.0) == pytest.approx(0.10)
    progress.fraction = 1.0
    assert jobs.shown_fraction(progress, None, 0.45) == pytest.approx(0.99)  # never full before the end


def test_a_polling_timer_waits_for_its_job_then_gets_it_once():
    release = threading.Event()
    job = jobs.BackgroundJob(lambda: release.wait(10) and 7, label="t")
    running = {"dial": job}
    assert jobs.finished_job(running, "layers", 0.05) == (None, None)  # no job: the timer stops
    assert jobs.finished_job(running, "dial", 0.05) == (None, 0.05)    # running: poll again
    release.set()
    assert job.wait(10) is jobs.JobState.DONE
    assert jobs.finished_job(running, "dial", 0.05) == (job, None) and job.result == 7


def test_saved_lights_come_back_as_the_same_coefficients():
    from blender_addon.worker import state

    coeffs = np.arange(27, dtype=np.float64).reshape(9, 3) / 7.0
    state.LIGHT_SOURCES.clear()
    try:
        state.LIGHT_SOURCES[("p1", "m.onnx", "BEST")] = coeffs
        session = state.PhotoSession(photo_id="p2", source="photo.png", photo=np.zeros((1, 1, 3)),
                                     decomposition=None, model_path="m.onnx", quality="BEST",
                                     mask_key=("AUTO", "1"), digest="abc")
        meta = work.save_meta(session)
        assert json.loads(json.dumps(meta))["mask_key"] == ["AUTO", "1"]  # plain JSON
        state.LIGHT_SOURCES.clear()
        work.restore_lights(meta["lights"])
        assert list(state.LIGHT_SOURCES) == [("p1", "m.onnx", "BEST")]
        assert np.array_equal(state.LIGHT_SOURCES[("p1", "m.onnx", "BEST")], coeffs)
        kept = np.ones((9, 3))
        state.LIGHT_SOURCES[("p1", "m.onnx", "BEST")] = kept
        work.restore_lights(meta["lights"])  # a source already known is kept
        assert state.LIGHT_SOURCES[("p1", "m.onnx", "BEST")] is kept
    finally:
        state.LIGHT_SOURCES.clear()


# ------------------------------------------------------------------ manifest

def test_source_manifest_follows_the_extension_rules():
    data = manifest.load(ADDON_DIR / "blender_manifest.toml")
    assert manifest.problems(data) == []
    assert data["name"] == "Relight Photo" and data["type"] == "add-on"
    assert set(data["permissions"]) == {"files"}
    assert sorted(data["platforms"]) == sorted(manifest.PLATFORMS)


@pytest.mark.parametrize("change, message", [
    (lambda d: d.pop("maintainer"), "missing required key 'maintainer'"),
    (lambda d: d.update(version="1.0"), "'version' must be a version string"),
    (lambda d: d.update(permissions={"files": "x", "network": "y"}), "only the 'files' permission"),
    (lambda d: d.update(blender_version_min="4.1.0"), "4.2.0 or later"),
    (lambda d: d.update(wheels=["./wheels\\a-1-py3-none-any.whl"]), "forward slashes"),
    (lambda d: d.update(wheels=["./wheels/a.whl"]), "does not follow"),
    (lambda d: d.update(license=["Apache-2.0"]), "SPDX"),
    (lambda d: d.update(platforms=["linux-x64"]), "'platforms' must be"),
])
def test_manifest_rule_violations_are_named(change, message):
    data = manifest.load(ADDON_DIR / "blender_manifest.toml")
    change(data)
    assert any(message in p for p in manifest.problems(data)), manifest.problems(data)


def test_manifest_wheels_must_exist_in_the_package(tmp_path):
    data = manifest.load(ADDON_DIR / "blender_manifest.toml")
    missing = manifest.problems(data, tmp_path)
    assert len(missing) == len(data["wheels"]) and all("not in the package" in m for m in missing)


def test_no_network_code_in_the_addon():
    # the add-on asks only for the 'files' permission; only the build script downloads
    pattern = re.compile(r"^\s*(import|from)\s+(urllib|requests|socket|http|ftplib|aiohttp|ssl)\b", re.M)
    offenders = [p.name for p in ADDON_DIR.rglob("*.py")
                 if p.name != "build.py" and pattern.search(p.read_text(encoding="utf-8"))]
    assert offenders == []
