"""Issue 37 in the farm: framings cut at the posed body's own joints (farm/synthesis/camera.py), hard
lights beside the maps (farm/synthesis/hard_lights.py), the head mask (the `head` channel), and that the
scenes of before stay the same (same seed: same body, clothes, light maps and camera)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

try:
    import bpy
except ImportError:
    bpy = None

from farm.synthesis import camera, hard_lights
from farm.synthesis.scene_options import SceneOptions
from relight.lighting import sh
from relight.lighting.sh_projection import project_equirect

needs_bpy = pytest.mark.skipif(bpy is None, reason="needs bpy (the farm extra)")
CUT = ("three-quarter", "waist-up", "head-and-shoulders", "face")


def test_framing_lists_parse_and_bad_ones_are_refused():
    assert camera.parse_framings("all") == camera.FRAMINGS
    assert camera.parse_framings("face, waist-up") == ("face", "waist-up")
    for bad in ("", "portrait", "face,,closeup"):
        with pytest.raises(ValueError, match="framing"):
            camera.parse_framings(bad)
    with pytest.raises(ValueError, match="framing"):
        SceneOptions(framing="portrait").validate()
    for share in (-0.1, 1.5, True):
        with pytest.raises(ValueError, match="hard_lights"):
            SceneOptions(hard_lights=share).validate()


def _stick_person():
    """A standing person of points: legs and torso a column 0.3 m wide, a head ball of radius
    0.11 m at 1.62 m; landmarks at the heights of an adult."""
    rng = np.random.default_rng(0)
    z = rng.uniform(0.0, 1.5, 4000)
    body = np.stack([rng.uniform(-0.15, 0.15, z.size), rng.uniform(-0.1, 0.1, z.size), z], axis=1)
    d = rng.normal(size=(1500, 3))
    head = 0.11 * d / np.linalg.norm(d, axis=1, keepdims=True) + [0.0, 0.0, 1.62]
    verts = np.concatenate([body, head])
    marks = camera.landmarks(verts, np.array([[0.0, 0.0, 1.52], [0.15, 0, 1.42], [-0.15, 0, 1.42],
                                              [0.1, 0, 0.92], [-0.1, 0, 0.92], [0.1, 0, 0.5], [-0.1, 0, 0.5],
                                              [0.03, -0.08, 1.65], [-0.03, -0.08, 1.65]]),
                             ["head", "upperarm01.L", "upperarm01.R", "upperleg01.L", "upperleg01.R",
                              "lowerleg01.L", "lowerleg01.R", "eye.L", "eye.R"], head)
    return verts, marks


def test_landmarks_come_from_the_joints_and_the_head_vertices():
    _, marks = _stick_person()
    assert marks.head_top == pytest.approx(1.73, abs=2e-3)  # the ball's top
    assert (marks.shoulders, marks.hips, marks.knees, marks.eyes_z) == pytest.approx((1.42, 0.92, 0.5, 1.65))


@pytest.mark.parametrize("framing", CUT)
def test_cut_framings_keep_the_head_and_cut_below_their_band(framing):
    verts, marks = _stick_person()
    rng = np.random.default_rng(7)
    low, high, _ = camera.band(framing, marks)
    for _ in range(15):
        cam = camera.frame_shot(verts, marks, framing, rng)
        uv = cam.project(verts)
        top = cam.project(np.array([[0.0, 0.0, marks.head_top]]))[0]
        assert abs(top[0]) < 0.5 and top[1] < 0.49  # the head's top is in the frame
        feet = uv[verts[:, 2] < 0.05]
        assert np.all(feet[:, 1] < -0.5)  # the feet are cut
        # the band's bottom on the frame's bottom edge (a steep camera sees a little more behind it)
        band_uv = uv[(verts[:, 2] >= low) & (verts[:, 2] <= high)]
        # or, where the band is wider than the frame allows, the frame widened in 5 % steps until it fits
        # (or a low camera came within a step of MIN_DEPTH_M of the body below the band)
        widened = np.abs(band_uv[:, 0]).max() > 0.49 / 1.05 or cam.to_camera(verts)[:, 1].min() < 0.25
        assert band_uv[:, 1].min() < -0.49 or widened
        # head room: the band's top (the head's) (1 - fill) of the frame below the top edge
        if not widened:
            assert band_uv[:, 1].max() == pytest.approx(0.5 - (1.0 - cam.fill), abs=0.01)
        below = uv[verts[:, 2] < low - 0.5 * (high - low)]
        assert np.all(below[:, 1] < -0.5), framing
        lo, hi = camera.FOCAL_RANGE[framing]
        assert lo <= cam.focal_mm <= hi and abs(cam.pitch_deg) <= 35.0 and abs(cam.roll_deg) <= 15.0
        rows = cam.world_to_camera
        assert np.allclose(rows @ rows.T, np.eye(3), atol=1e-12)
        assert math.degrees(math.asin(rows[1, 2])) == pytest.approx(cam.pitch_deg, abs=1e-9)
        record = cam.as_dict()
        assert record["framing"] == framing and record["shot"]["band_z"] == [low, high]
        assert record["shot"]["camera_above_eyes_m"] == pytest.approx(cam.location[2] - 1.65)
        json.dumps(record)


def test_framings_vary_roll_and_camera_height_as_photographers_do():
    verts, marks = _stick_person()
    rng = np.random.default_rng(1)
    cams = [camera.frame_shot(verts, marks, "head-and-shoulders", rng) for _ in range(200)]
    rolls = np.array([c.roll_deg for c in cams])
    heights = np.array([c.shot["camera_above_eyes_m"] for c in cams])
    assert 1.5 < rolls.std() < 6.0 and (np.abs(rolls) > 8.0).mean() > 0.03  # mostly level, now and then tilted
    assert (heights > 0.05).mean() > 0.15 and (heights < -0.05).mean() > 0.15  # above and below the eyes


def test_full_body_only_draws_nothing_and_keeps_the_camera():
    cam = camera.Camera(np.zeros(3), np.eye(3), 50.0, 0.0, 0.0, 0.8, [0.0, 0.0])
    assert camera.reframe(cam, np.zeros((3, 3)), None, "full-body", [1, 2, 2]) is cam


# ------------------------------------------------------------------ hard lights


def _power(pixels):
    from relight.lighting.sh_projection import equirect_directions

    _, solid = equirect_directions(*pixels.shape[:2])
    return (pixels * solid[:, None, None]).sum(axis=(0, 1))


def test_a_lobe_map_integrates_to_its_powers_and_its_sh_is_the_lobes_direction():
    d = hard_lights.direction(60.0, 30.0)
    colour = [1.0, 0.8, 0.6]
    lobes = [{"direction": d, "radius_deg": 1.0, "colour": colour, "power": 0.9}]
    ambient = {"sky": [1.0, 1.0, 1.0], "ground": [1.0, 1.0, 1.0], "power": 0.0}
    pixels = hard_lights.lobe_map(lobes, ambient)
    assert _power(pixels) == pytest.approx(0.9 * np.array(colour), rel=1e-5)
    # a disc of 1 degree is a delta to order 4: its SH is power * colour * Y(d) (to 1 - cos(r) ~ 2e-4
    # per band, times l(l+1)/2 <= 10 for l <= 4)
    coeffs = project_equirect(pixels, 4)
    expected = sh.sh_basis(d, 4)[:, None] * (0.9 * np.array(colour))[None]
    assert np.abs(coeffs - expected).max() < 3e-3 * np.abs(expected).max()
    # the ambient alone: sky and ground of the same colour are a constant map of that power
    flat = hard_lights.lobe_map([], {"sky": [0.5, 0.5, 0.5], "ground": [0.5, 0.5, 0.5], "power": 0.2})
    assert _power(flat) == pytest.approx([0.2, 0.2, 0.2], rel=1e-5)
    assert flat.std() < 1e-6


@pytest.mark.parametrize("kind", hard_lights.HARD_KINDS)
def test_hard_lights_are_normalized_recorded_and_point_where_their_key_is(kind):
    rng = np.random.default_rng(11)
    w2c = camera.orientation(5.0, -2.0)
    light = hard_lights.sample_hard_light(rng, 4, w2c, kind)
    assert light.name == f"hard:{kind}" and light.source == "hard"
    assert sh.mean_luminance(light.sh) == pytest.approx(light.reference_luminance, rel=1e-6)
    record = light.record()
    json.dumps(record)
    key = np.array(record["hard"]["lobes"][0]["direction_camera"])
    # exposed for the key: the SH's Lambert shading facing it (order 8: Lambert's bands above 2 are
    # small, and the shadowed half's cut rings by a few per cent) is the drawn key_shading
    from relight.network.prt import lambert_transport

    facing = (lambert_transport(key[None], 8)[0] @ light.sh8) @ np.array([0.2126, 0.7152, 0.0722])
    assert 0.9 <= record["hard"]["key_shading"] <= 1.3
    assert facing == pytest.approx(record["hard"]["key_shading"], rel=0.05)
    assert key == pytest.approx(w2c @ np.array(record["hard"]["lobes"][0]["direction"]))
    # band 1 of the SH (Y_1-1 ~ y, Y_10 ~ z, Y_11 ~ x) points at the key: the ambient and the
    # fill pull it off by at most their share of the light
    lum = light.sh[:, :] @ np.array([0.2126, 0.7152, 0.0722])
    band1 = np.array([lum[3], lum[1], lum[2]])
    angle = math.degrees(math.acos(float(band1 @ key) / np.linalg.norm(band1)))
    assert angle < {"sun": 30.0, "studio": 25.0, "lamp": 5.0}[kind]


def test_hard_light_share_replaces_lights_from_its_own_stream():
    w2c = np.eye(3)
    drawn = ["map0", "map1", "map2", "map3"]
    kept = list(drawn)
    hard_lights.replace_share(kept, 0.0, [1, 2, 3], 4, w2c)
    assert kept == drawn
    everything = list(drawn)
    hard_lights.replace_share(everything, 1.0, [1, 2, 3], 4, w2c)
    assert all(l.source == "hard" for l in everything)
    again = list(drawn)
    hard_lights.replace_share(again, 1.0, [1, 2, 3], 4, w2c)
    assert [l.name for l in again] == [l.name for l in everything]
    assert all(np.array_equal(a.sh, b.sh) for a, b in zip(again, everything))


# ------------------------------------------------------------------ whole scenes (anny)


@pytest.mark.anny
def test_framing_and_hard_lights_leave_the_body_and_the_maps_as_they_were():
    from farm.scene import sample_scene

    base = sample_scene(3, 11, SceneOptions(lights=3))
    same = sample_scene(3, 11, SceneOptions(lights=3, framing="full-body", hard_lights=0.0))
    assert base.camera.as_dict() == same.camera.as_dict()
    for framing in CUT:
        s = sample_scene(3, 11, SceneOptions(lights=3, framing=framing, hard_lights=0.5))
        assert s.geometry_record()["hash"] == base.geometry_record()["hash"]
        assert s.camera.framing == framing and s.look == base.look
        assert [l.name for l in s.lights if l.source != "hard"] == \
            [b.name for b, l in zip(base.lights, s.lights) if l.source != "hard"]
        marks = s.camera.shot["landmarks"]
        head_xy = np.mean([p.vertices for p in s.parts if p.name == "eyes"][0], axis=0)[:2]
        top = s.camera.project(np.array([[*head_xy, marks["head_top"] - 0.01]]))[0]
        hips = s.camera.project(np.array([[*head_xy, marks["hips"] - 0.1]]))[0]
        assert abs(top[0]) < 0.5 and top[1] < 0.5, framing
        if framing in ("head-and-shoulders", "face"):
            assert hips[1] < -0.5, framing  # cut above the hips
    labels = base.head_labels
    assert [len(x) for x in labels] == [len(p.vertices) for p in base.parts]
    by_part = {p.name: x for p, x in zip(base.parts, labels)}
    assert by_part["eyes"].min() == 1.0 and by_part["lips"].min() == 1.0
    assert all(by_part[name].max() == 0.0 for name in by_part if name not in ("body", "eyes", "lips", "brows"))
    # the head's vertices are dense (MakeHuman's face): about a third of the skin's, not all of it
    assert 0.1 < by_part["body"].mean() < 0.45


@needs_bpy
@pytest.mark.anny
def test_a_head_and_shoulders_scene_under_hard_lights_renders_its_head_mask(tmp_path):
    from farm.scene import render_scene
    from relight.files import dataset

    options = SceneOptions(resolution=64, lights=2, samples=8, denoise=False, bake_directions=64,
                           framing="head-and-shoulders", hard_lights=1.0)
    s = dataset.read_scene(render_scene(5, 37, options, tmp_path))  # short hair, the camera 6 deg off the face
    assert s.meta["camera"]["framing"] == "head-and-shoulders"
    assert len(s.meta["channels"]) == options.expected_channels()  # the disk check's count, head included
    assert [l["source"] for l in s.meta["lights"]] == ["hard", "hard"]
    inside = s.alpha[..., 0] > 0.999
    head = s.head[..., 0]
    assert np.all(head[s.alpha[..., 0] == 0.0] == 0.0) and 0.0 <= head.min() and head.max() <= 1.0
    share = (head[inside] > 0.5).mean()
    assert 0.08 < share < 0.8  # the face is a good part of a head-and-shoulders shot
    # the path-traced images and the PRT images see the same light: the person's mean radiance
    # agrees within what interreflection, specular and order 4 leave (farm maps: 1.2-1.6 here)
    for k in range(2):
        assert np.all(np.isfinite(s.images[k]))
        ratio = s.images[k][inside].mean() / s.prt[k][inside].mean()
        assert 0.7 < ratio < 2.0


def test_the_command_line_takes_the_framing_mix_and_the_hard_light_share(tmp_path):
    from farm.cli import parse_args
    from farm.execution.run_config import UsageError

    base = ["--out", str(tmp_path), "--scenes", "2", "--seed", "1"]
    assert (parse_args(base).scene.framing, parse_args(base).scene.hard_lights) == ("full-body", 0.0)
    config = parse_args(base + ["--framing", "all", "--hard-lights", "0.3"])
    assert camera.parse_framings(config.scene.framing) == camera.FRAMINGS and config.scene.hard_lights == 0.3
    assert parse_args(base + ["--framing", "face,waist-up"]).scene.framing == "face,waist-up"
    for bad in (["--framing", "portrait"], ["--hard-lights", "1.5"], ["--hard-lights", "nan"]):
        with pytest.raises(UsageError):
            parse_args(base + bad)


def test_a_cut_framing_is_taken_from_the_persons_front_and_hard_lights_turn_with_the_camera():
    verts, marks = _stick_person()
    rng = np.random.default_rng(2)
    for yaw in (0.0, 150.0, -100.0):
        turned = (verts - [0.0, 0.0, 0.0]) @ camera.z_turn(yaw).T
        m = camera.landmarks(turned, np.array([[0.0, 0.0, 1.52], [0.15, 0, 1.42], [-0.15, 0, 1.42], [0.1, 0, 0.92],
                                               [-0.1, 0, 0.92], [0.1, 0, 0.5], [-0.1, 0, 0.5]]) @ camera.z_turn(yaw).T,
                             ["head", "upperarm01.L", "upperarm01.R", "upperleg01.L", "upperleg01.R",
                              "lowerleg01.L", "lowerleg01.R"], turned[4000:])
        facings = []
        for _ in range(30):
            cam = camera.frame_shot(turned, m, "head-and-shoulders", rng, yaw)
            person_front = camera.z_turn(yaw) @ np.array([0.0, -1.0, 0.0])  # the way the person faces
            to_camera = -cam.world_to_camera[1] * np.array([1.0, 1.0, 0.0])
            to_camera /= np.linalg.norm(to_camera)
            facings.append(math.degrees(math.acos(np.clip(to_camera @ person_front, -1, 1))))
            assert facings[-1] == pytest.approx(abs(cam.shot["facing_deg"]), abs=1e-6)
            assert np.all(np.abs(cam.project(turned[(turned[:, 2] > m.shoulders)])) < 0.5)
        assert max(facings) <= 90.0 + 1e-9 and np.mean(np.array(facings) <= 45.0) > 0.6
        # a hard light's azimuth 0 is the camera's side: a lamp straight in front of the camera
        lobes_rng = np.random.default_rng(0)
        light = hard_lights.sample_hard_light(lobes_rng, 4, cam.world_to_camera, "studio")
        key = np.array(light.hard["lobes"][0]["direction_camera"])
        assert key[1] < 0.0  # the key is on the camera's side of the person (toward -Y in the camera frame)


def test_the_dataset_summary_counts_framings_and_hard_lights():
    from farm.execution import summary

    f = summary.features({"camera": {"framing": "waist-up"}, "lights": [{"source": "bundled"}, {"source": "hard"}]})
    assert f["framing: waist-up"] and not f["framing: full-body"] and f["hard light (any)"]
    old = summary.features({"camera": {}, "lights": [{"source": "sky"}]})  # a sidecar from before issue 37
    assert old["framing: full-body"] and not old["hard light (any)"]
    assert sum(v for k, v in old.items() if k.startswith("framing: ")) == 1
