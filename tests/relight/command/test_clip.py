"""relight.command.clip and relight.command.clip_maps: a clip relit frame by frame, stable over time."""

from __future__ import annotations

import io
import json
import math

import numpy as np
import pytest

from clip_support import background, person_clip, two_shots
from relight.network import quality
from relight.command.clip import LIGHT_WINDOW, ClipRelighter, CutDetector
from relight.command.clip_maps import (
    MATTE_AGREE_SCALE, MATTE_AREA_AGREE, MapSmoother, MatteSmoother, Stillness, history_weight,
)
from relight.lighting.light import sh_light
from relight.network.runtime import Relighter


@pytest.fixture(scope="module")
def relighter():
    """The shipped geometry-first model at Draft (96 px), one thread: a frame in ~30 ms."""
    return Relighter(quality.model_path("draft"), threads=1, working_size=quality.preset("draft").working_size)


@pytest.fixture(scope="module")
def clip12():
    return person_clip(12)


def test_a_generated_clip_relights_with_a_stable_light(relighter, clip12):
    light = sh_light("studio", relighter.sh_order)
    runner = ClipRelighter(relighter, light, stability=1.0, threads=1)
    results = [runner.relight(f) for f in clip12]
    assert all(r.person and r.image.shape == f.shape for r, f in zip(results, clip12))
    assert [r.cut for r in results] == [True] + [False] * 11
    raw = np.stack([r.light for r in results]).astype(np.float64)
    shot = np.stack([r.shot_light for r in results]).astype(np.float64)
    spread = raw.max(axis=0) - raw.min(axis=0)
    assert np.all(spread > 0), "the network's per-frame estimates should differ (else the test proves nothing)"
    # the shot light is the mean m_k of the last N = LIGHT_WINDOW estimates; once the window is full,
    # m_k - m_{k-1} = (l_k - l_{k-N}) / N: the light moves by at most 1/N of the estimates' spread a frame
    n = LIGHT_WINDOW
    assert n < 12
    slack = 1e-5 * np.abs(raw).max()
    for k in range(12):
        np.testing.assert_allclose(shot[k], raw[max(0, k - n + 1):k + 1].mean(axis=0), rtol=0, atol=slack)
    steps = np.abs(np.diff(shot[n - 1:], axis=0))
    assert np.all(steps <= spread / n + slack)
    assert np.abs(np.diff(raw[n - 1:], axis=0)).max() > steps.max()  # the raw estimates jump more


def test_stability_zero_is_relight_image_on_every_frame(relighter, clip12):
    light = sh_light("city", relighter.sh_order)
    runner = ClipRelighter(relighter, light, exposure_ev=0.5, stability=0.0, threads=1)
    for frame in clip12[:4]:
        got = runner.relight(frame)
        d = relighter.decompose(frame, augment=())   # the runner above runs the network once, as Draft
        np.testing.assert_array_equal(got.image, d.relight(light, 0.5))
        np.testing.assert_array_equal(got.light, d.light)


def test_the_clips_albedo_rule_is_the_graphs_inside_the_matte(relighter, clip12):
    """relight.command.clip re-derives each frame's albedo under the shot's light by
    relight.network.refine.consistent_albedo with the model's own `reliable`: under the network's own
    light and transport that must be the albedo the graph itself computed, wherever the
    graph's input was not faded by the matte (alpha 1: masked and unmasked input agree)."""
    from types import SimpleNamespace

    from relight.network.prt import to_network_input
    from relight.network.refine import CLIPPED, SATURATED, consistent_albedo

    d = relighter.decompose(clip12[3])
    config = json.loads(relighter.metadata["relight.network_config"])
    out = relighter.run_crop(d.photo_working, d.alpha)  # the graph on the masked crop, as decompose ran it
    frame = SimpleNamespace(photo_working=d.photo_working, network_alpha=out["alpha"][..., 0], alpha=d.alpha)
    albedo = consistent_albedo(frame, out["transport"], out["light"], config["reliable"])
    inside = d.alpha >= 1.0
    assert inside.sum() > 200
    # the graph decodes its sRGB input in float32 and sums the shading's 25 float32 products in
    # its own order (relative ~25 x 2^-24 of the largest term, which can be ~10x the sum: 2e-4
    # covers it); and its mean shading (the floor's scale) skips pixels saturated in the masked
    # input, ours in the unmasked crop: they differ on the edge ring, by the ratio of the means
    na, lum = frame.network_alpha, (out["transport"] @ out["light"]).mean(axis=-1)
    seen_saturated = to_network_input(d.photo_working, d.alpha).max(axis=-1) > 2 * CLIPPED - 1
    means = [float((lum * na * ~sat).sum() / (na * ~sat).sum())
             for sat in (seen_saturated, d.photo_working.max(axis=-1) >= SATURATED)]
    floor_shift = abs(means[1] / means[0] - 1.0)
    np.testing.assert_allclose(albedo[inside], out["albedo"][inside], rtol=2e-4 + floor_shift, atol=2e-5)
    # and off the matte the rule is not the masked one (what relight.command.clip fixes there)
    edge = (d.alpha > 0.05) & (d.alpha < 0.95)
    assert edge.sum() > 50
    assert np.abs(albedo[edge] - out["albedo"][edge]).max() > 1e-2


def test_a_cut_starts_a_new_shot_with_its_own_light(relighter):
    frames = two_shots(5, 4)
    light = sh_light("studio", relighter.sh_order)
    runner = ClipRelighter(relighter, light, stability=1.0, threads=1)
    results = [runner.relight(f) for f in frames]
    assert [r.cut for r in results] == [True, False, False, False, False, True, False, False, False]
    # after the cut the shot light averages the new shot's estimates only
    np.testing.assert_allclose(results[5].shot_light, results[5].light, rtol=0, atol=1e-6)
    np.testing.assert_allclose(results[6].shot_light, (results[5].light + results[6].light) / 2, rtol=0,
                               atol=1e-5 * np.abs(results[5].light).max())


def test_cut_detector_ignores_motion_and_sees_a_new_background():
    detector = CutDetector()
    frames = person_clip(6, step=4) + person_clip(2, tint=(0.5, 0.3, 0.1))
    cuts = [detector.update_histogram(detector.histogram(f)) for f in frames]
    assert cuts == [True, False, False, False, False, False, True, False]


def test_state_round_trip_continues_exactly(relighter, clip12):
    light = sh_light("studio", relighter.sh_order)
    whole = ClipRelighter(relighter, light, stability=0.7, threads=1)
    expected = [whole.relight(f).image for f in clip12]
    first = ClipRelighter(relighter, light, stability=0.7, threads=1)
    for f in clip12[:6]:
        first.relight(f)
    buffer = io.BytesIO()
    np.savez(buffer, **first.state())
    buffer.seek(0)
    with np.load(buffer) as saved:
        state = {k: saved[k] for k in saved.files}
    second = ClipRelighter(relighter, light, stability=0.7, threads=1)
    second.load_state(state)
    for f, want in zip(clip12[6:], expected[6:]):
        np.testing.assert_array_equal(second.relight(f).image, want)


def test_state_is_a_snapshot_the_next_frame_does_not_change(relighter, clip12):
    """relight.command.cli_video keeps state() after each frame written and saves it on Ctrl-C, while the
    next frame is finished: the filters must replace their arrays, never change them in place."""
    runner = ClipRelighter(relighter, sh_light("studio", relighter.sh_order), stability=0.5, threads=1)
    for f in clip12[:3]:
        runner.relight(f)
    state = runner.state()
    kept = {k: np.array(v, copy=True) for k, v in state.items()}
    assert {"still_reference", "held_light", "matte", "maps_grey"} <= set(state)
    runner.relight(clip12[3])
    for k, v in kept.items():
        np.testing.assert_array_equal(state[k], v, err_msg=k)


def test_a_frame_without_a_person_passes_through_and_the_next_starts_afresh(relighter, clip12):
    light = sh_light("studio", relighter.sh_order)
    runner = ClipRelighter(relighter, light, stability=0.5, threads=1)
    runner.relight(clip12[0])
    runner.relight(clip12[1])
    empty = background()
    result = runner.relight(empty)
    assert not result.person and result.image is empty
    after = runner.relight(clip12[2])
    np.testing.assert_array_equal(after.shot_light, after.light)  # a fresh shot: its own estimate
    # the frame's own alpha marks nobody: passed through too
    assert not runner.relight(clip12[3], np.zeros(clip12[3].shape[:2], np.float32)).person


def test_history_weight_gives_the_asked_window():
    for window in (1.0, 3.0, 9.0):
        k = history_weight(window)
        assert math.isclose((1 + k) / (1 - k), window)


def test_map_smoother_keeps_still_maps_and_follows_a_change():
    rng = np.random.default_rng(0)
    grey = rng.random((20, 16)).astype(np.float32)
    alpha = np.ones((20, 16), np.float32)
    maps = {"t": rng.random((20, 16, 5)).astype(np.float32)}
    smoother = MapSmoother(0.8)
    box, size = (10, 50, 20, 52), (20, 16)
    for _ in range(3):
        out = smoother.update(box, size, grey, alpha, maps)
    # a fixed point: k x + (1 - k) x == x up to float32 rounding
    np.testing.assert_allclose(out["t"], maps["t"], rtol=1e-6, atol=1e-6)
    # a new picture (grey changes by >= 0.5 everywhere): the history weight is at most
    # 0.8 exp(-(0.5 / 0.08)^2) < 1e-16, so the current maps come through
    new = {"t": maps["t"] + 1.0}
    out = smoother.update(box, size, np.where(grey > 0.5, grey - 0.5, grey + 0.5), alpha, new)
    np.testing.assert_allclose(out["t"], new["t"], rtol=0, atol=1e-6)


def test_map_smoother_holds_still_pixels_with_the_longer_window():
    rng = np.random.default_rng(1)
    grey = rng.random((12, 10)).astype(np.float32)
    alpha = np.ones((12, 10), np.float32)
    smoother = MapSmoother(0.5, hold=0.9)
    box, size = (0, 12, 0, 10), (12, 10)
    smoother.update(box, size, grey, alpha, {"t": np.zeros((12, 10, 1), np.float32)})
    still = np.zeros((12, 10), np.float32)
    still[:6] = 1.0
    out = smoother.update(box, size, grey, alpha, {"t": np.ones((12, 10, 1), np.float32)}, still)["t"][..., 0]
    # the photo agrees everywhere (grey unchanged): k = max(0.5, 0.9 x still)
    np.testing.assert_allclose(out[:6], 0.1, rtol=0, atol=1e-6)
    np.testing.assert_allclose(out[6:], 0.5, rtol=0, atol=1e-6)


def test_stillness_counts_sensor_noise_as_still_and_a_shift_as_change():
    from clip_support import noisy_still

    frames = noisy_still(3, 128)
    box = (8, 120, 8, 120)
    judge = Stillness(history_weight(33.0))
    judge.update(frames[0], box)
    assert not judge.still.any()  # nothing seen before: nothing is still
    for f in frames[1:]:
        judge.update(f, box)
        # noise of 2 codes, 3 x 3 pixels averaged (at 128 px a block is a pixel): the difference of
        # two frames has sd 2 sqrt(2) / 3 / 255 = 0.0037, so still = exp(-(d / 0.03)^2) averages
        # ~0.985 and its 1 % quantile (d = 2.6 sd) is ~0.90
        assert judge.still.mean() > 0.97 and np.quantile(judge.still, 0.01) > 0.85
    shifted = np.roll(frames[2], 2, axis=1)  # the picture moved by 2 px
    judge.update(shifted, box)
    assert (judge.still < 0.5).mean() > 0.3  # the textured photo changes over much of it
    # read on a working grid, and at full-resolution pixels: their blocks' (at 128 px a block is a
    # pixel), 0 off the blocks judged
    assert judge.on_grid(box, (56, 56)).shape == (56, 56)
    rows, cols = np.array([10, 60, 119, 3]), np.array([10, 100, 119, 60])
    np.testing.assert_array_equal(judge.at(rows, cols), [judge.still[2, 2], judge.still[52, 92],
                                                         judge.still[111, 111], 0.0])


def test_flow_mode_follows_a_moving_picture_better_than_plain_smoothing():
    h, w = 48, 64
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)

    def picture(shift):
        return (0.5 + 0.25 * np.sin((x - shift) / 4.0) * np.cos(y / 5.0)).astype(np.float32)

    alpha = np.ones((h, w), np.float32)
    errors = {}
    for mode in ("ema", "flow"):
        smoother = MapSmoother(0.8, mode)
        total = 0.0
        for t in range(6):
            grey = picture(1.5 * t)
            out = smoother.update((0, h, 0, w), (h, w), grey, alpha, {"g": grey[..., None]})
            total += float(np.abs(out["g"][8:-8, 8:-8, 0] - grey[8:-8, 8:-8]).mean())
        errors[mode] = total
    assert errors["flow"] < 0.5 * errors["ema"]


def test_matte_smoother_damps_jitter_and_keeps_exact_background():
    history, delta = history_weight(9.0), 0.02
    smoother = MatteSmoother(history)
    frames = []
    for t in range(40):
        a = np.zeros((10, 10), np.float32)
        a[2:8, 2:8] = 0.5 + delta * (-1) ** t
        frames.append(smoother.update(a))
    assert np.all(frames[-1][:2] == 0) and np.all(frames[-1][:, :2] == 0)
    # alternating input 0.5 +- delta: the output alternates with amplitude A = (1 - k) delta / (1 + k),
    # k = history exp(-(d / scale)^2) with d = |input - previous output| <= 2 delta, so k >= k_low
    k_low = history * math.exp(-((2 * delta) / MATTE_AGREE_SCALE) ** 2)
    amplitude = abs(float(frames[-1][4, 4] - frames[-2][4, 4])) / 2
    assert amplitude <= (1 - k_low) / (1 + k_low) * delta + 1e-7
    # a real change (0.5 -> 1): k = history exp(-4) < 0.015, the matte moves almost all the way at once
    moved = smoother.update(np.where(frames[-1] > 0, np.float32(1.0), np.float32(0.0)))
    assert moved[4, 4] > 0.99


def test_matte_smoother_holds_a_lost_person_and_takes_a_found_one_where_the_picture_is_still():
    """Issue 45: a segmenter that finds part of a person in one frame: in a still picture the person
    is still there, so the lost part is held; a matte that grows by more than MATTE_AREA_AGREE found
    what was missed before, and is taken at once."""
    history, hold = history_weight(9.0), 0.99
    still = lambda rows, cols: np.ones(len(rows), np.float32)  # the picture is still everywhere
    full = np.zeros((20, 20), np.float32)
    full[2:18, 4:16] = 1.0
    part = np.where(np.arange(20)[:, None] < 10, full, np.float32(0.0))  # the top half: 50 % less
    smoother = MatteSmoother(history, hold)
    smoother.update(full, still=still)
    lost = smoother.update(part, still=still)
    assert np.all(lost[10:18, 4:16] >= hold - 1e-6) and np.array_equal(lost[2:10], part[2:10])
    smoother = MatteSmoother(history, hold)
    smoother.update(part, still=still)
    found = smoother.update(full, still=still)
    # k = history exp(-(1 / MATTE_AGREE_SCALE)^2) where the matte changed by 1: the current matte at once
    assert np.all(found[10:18, 4:16] >= 1.0 - history * np.exp(-(1.0 / MATTE_AGREE_SCALE) ** 2) - 1e-6)
    # growth within MATTE_AREA_AGREE is the segmenter's edge jitter: held where the picture is still
    grown = full.copy()
    grown[18, 4:16] = 1.0  # one more row: 12 of 192 pixels, 6 % < MATTE_AREA_AGREE
    assert 12 / 204 < MATTE_AREA_AGREE
    smoother = MatteSmoother(history, hold)
    smoother.update(full, still=still)
    jitter = smoother.update(grown, still=still)
    assert np.all(jitter[18, 4:16] <= 1.0 - hold + 1e-6)


@pytest.fixture(scope="module")
def random_model(tmp_path_factory):
    """A seeded random RelightNet (not photo-consistent: its albedo and E are smoothed as maps)."""
    from export.random_model import export_random_model

    path, _, _ = export_random_model(tmp_path_factory.mktemp("clip") / "tiny.onnx", seed=5, sh_order=4, width=4,
                                     depth=2)
    return Relighter(path, threads=1, working_size=quality.preset("draft").working_size)


@pytest.mark.parametrize("kind", ["shipped", "random"])
def test_a_still_clip_is_a_fixed_point(relighter, random_model, clip12, kind):
    """Frames that do not change relight as a single frame does: every smoothing averages equal
    values (the geometry model's albedo twin within its float32 tolerance, test above)."""
    model = relighter if kind == "shipped" else random_model
    matte = "person" if kind == "shipped" else "network"
    light = sh_light("studio", model.sh_order)
    still = ClipRelighter(model, light, stability=0.0, matte=matte, threads=1).relight(clip12[0]).image
    runner = ClipRelighter(model, light, stability=1.0, matte=matte, threads=1)
    assert (runner.reliable is None) == (kind == "random")
    for _ in range(4):
        got = runner.relight(clip12[0]).image
    # the relit person is the photo times a shading ratio: the albedo twin's relative error (2e-4)
    # passes through it, with room for the float32 sums of the composite
    np.testing.assert_allclose(got, still, rtol=1e-3, atol=1e-4)
    state = runner.state()
    assert ("map_albedo" in state) == (kind == "random") and ("map_residual" in state) == (kind == "random")
