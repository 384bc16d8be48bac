"""The clip relighter against a farm clip's ground truth: less flicker than per-frame
processing, no worse per frame. The fixture tests/data/farm_clip.npz is the first 12
frames of a farm clip of a person turning in place under a held-out light, relit to
another (made by tools/make_clip_fixture.py; 8-bit sRGB, 0.86 MB). And a still shot
with sensor noise (tests/support/clip_support.noisy_still) relit as still as it came."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from clip_support import lowpass_flicker, noisy_still, still_region
from model.evaluate_clips import evaluate_clip, flicker, jitter, relight_clip
from relight.network import quality
from relight.command.clip import ClipRelighter
from relight.lighting.light import sh_light
from relight.network.runtime import Relighter
from relight.files.video_io import decode_srgb

FIXTURE = Path(__file__).resolve().parents[2] / "data" / "farm_clip.npz"


@pytest.fixture(scope="module")
def clip():
    with np.load(FIXTURE) as z:
        return {"frames": decode_srgb(z["frames"]), "truth": decode_srgb(z["truth"]),
                "alpha": z["alpha"].astype(np.float32) / 255.0, "light": z["light"]}


def test_flicker_and_jitter_measure_change_relative_to_the_clip():
    alpha = np.ones((3, 4, 4), np.float32)
    still = np.full((3, 4, 4, 3), 0.5, np.float32)
    assert flicker(still, alpha) == 0.0 and jitter(still, alpha) == 0.0
    ramp = still * np.array([1.0, 1.1, 1.2], np.float32)[:, None, None, None]
    # |0.55 - 0.5| / 0.55 and |0.6 - 0.55| / 0.6, averaged; a ramp has no second difference
    assert flicker(ramp, alpha) == pytest.approx((0.05 / 0.55 + 0.05 / 0.6) / 2)
    assert jitter(ramp, alpha) == pytest.approx(0.0, abs=1e-7)
    blink = still * np.array([1.0, 1.2, 1.0], np.float32)[:, None, None, None]
    assert jitter(blink, alpha) == pytest.approx(0.1 / 0.6)


@pytest.mark.parametrize("working_size", [96, 128])
def test_the_stabilised_clip_flickers_a_third_as_much_at_the_same_accuracy(clip, working_size):
    # 96 px, where this clip's per-frame decompositions flicker (the stabiliser's job), and 128 px,
    # Balanced's size. The person segmenter finds only 550 of the person's ~1,400 pixels in 4 of the 12
    # frames: held into the other frames, or a frame cropped around its partial matte, the
    # stabilised clip lost 1.7-2.4 dB against the frames relit one by one (issue 45). Measured with
    # the release of 2026-11-28: per-frame +20.1% / +19.0% of the image, 25.13 / 25.45 dB; stabilised
    # +4.4% / +3.6%, 26.32 / 26.50 dB (docs/video.md)
    relighter = Relighter(quality.model_path("draft"), threads=1, working_size=working_size)
    per_frame = evaluate_clip(clip, relight_clip(clip, relighter, 0.0, "ema", "person")[0])
    stable = evaluate_clip(clip, relight_clip(clip, relighter, 0.5, "ema", "person")[0])
    assert per_frame["flicker_excess"] > 0.02
    assert stable["flicker_excess"] <= per_frame["flicker_excess"] / 3
    assert stable["jitter_excess"] <= per_frame["jitter_excess"] / 3
    # the accuracy goal: within 0.3 dB of the stills (measured: +1.2 / +1.1 dB)
    assert stable["psnr"] >= per_frame["psnr"] - 0.3


def test_a_noisy_still_shot_relights_still():
    """Issue 40: one still photo with sensor noise (2/255) through `relight video`'s default
    (Balanced, stability 0.5) changes from frame to frame, low-passed, at most twice as much as
    the input does. Measured (docs/video.md, "A still shot"): 1.11x here, 5.06x before the held
    grid, the stillness hold and the held light; per frame (stability 0) 14.7x. Two is the
    issue's goal: the photo's own noise passes through the detail transfer (1x), the network's
    remaining changes must not add as much again."""
    height = 256
    frames, region = noisy_still(6, height), still_region(height)
    preset = quality.preset("balanced")
    relighter = Relighter(quality.model_path("balanced"), threads=1, working_size=preset.working_size)
    light = sh_light("studio", relighter.sh_order)
    source = lowpass_flicker(frames, region)
    ratios, boxes = {}, {}
    for stability in (0.0, 0.5):
        runner = ClipRelighter(relighter, light, stability=stability, threads=1, matte_method=preset.matte_method)
        results = [runner.relight(f) for f in frames]
        ratios[stability] = lowpass_flicker([r.image for r in results], region) / source
        boxes[stability] = {r.changed for r in results}
    # the premise: each frame relit alone moves (else the shot would not test the stabiliser)
    assert ratios[0.0] > 4.0, ratios
    assert ratios[0.5] <= 2.0, ratios
    assert len(boxes[0.5]) == 1  # one crop for the whole shot: the segmenter's box jitter is held
