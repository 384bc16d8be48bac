"""farm.scene.render_scene end to end (in-process bpy) and its building blocks; the numpy-only
ones (lights, camera, option checks) run without bpy.

The first anny model build on a fresh machine takes minutes and writes a
~790 MB cache to $ANNY_CACHE_DIR (default ~/.cache/relight/anny); later
loads take seconds. The module fixture pays that once.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest

try:
    import bpy
except ImportError:  # the Blender layer's tests skip; the numpy-only ones below still run
    bpy = None

from farm.synthesis import bodies, camera, lights, poses
from farm.scene import SceneOptions, render_scene
from relight.files import dataset
from relight.lighting import presets, sh, sh_projection, sh_rotation

SMALL = {"resolution": 64, "lights": 2, "samples": 4, "denoise": False, "bake_directions": 64}
needs_bpy = pytest.mark.skipif(bpy is None, reason="needs bpy (the farm extra)")


@pytest.fixture(scope="module")
def model():
    return bodies.body_model()


@pytest.fixture(scope="module")
def scene_pair(model, tmp_path_factory):
    """The same scene rendered twice into two folders."""
    out = []
    for name in ("a", "b"):
        folder = tmp_path_factory.mktemp(name)
        out.append(render_scene(3, 11, SceneOptions(**SMALL), folder))
    return out


def _without_timings(meta):
    meta = dict(meta)
    meta.pop("timings")
    return meta


@needs_bpy
@pytest.mark.anny
def test_scene_files_hold_every_channel_with_sane_values(scene_pair):
    s = dataset.read_scene(scene_pair[0])
    n = sh.num_coeffs(4)
    assert s.resolution == (64, 64)
    assert s.transport.shape == (64, 64, n)
    assert len(s.images) == 2 and len(s.prt) == 2 and len(s.shading) == 2
    alpha = s.alpha[..., 0]
    assert 0.0 <= alpha.min() and alpha.max() <= 1.0
    inside = alpha > 0.999
    assert 0.05 < inside.mean() < 0.7  # a person, not an empty or filled frame
    # Normals: unit inside (renormalized mean of unit normals), zero outside.
    length = np.linalg.norm(s.normal, axis=-1)
    assert np.allclose(length[inside], 1.0, atol=1e-4)
    assert np.all(s.normal[alpha == 0.0] == 0.0)
    # Camera-frame normals seen by the camera mostly point back at it (-Y).
    assert np.median(s.normal[inside][:, 1]) < -0.3
    # Depth: along the view axis, positive inside, plausible for a framed person.
    assert np.all(s.depth[inside] > 0.5) and np.all(s.depth[inside] < 30.0)
    # Only vertices that can be seen are baked (farm.scene.visible_vertices);
    # every visible pixel must still have received light transport.
    assert (s.transport[inside][:, 0] > 0.0).mean() > 0.995
    assert s.meta["bake"]["baked_vertices"] < s.meta["geometry"]["vertices"]
    # Albedo and material parameters are in range.
    assert np.all((s.albedo >= 0) & (s.albedo <= 1.0))
    assert np.all((s.material >= 0) & (s.material <= 1.0))
    for k in range(2):
        assert np.all(np.isfinite(s.images[k]))
        # PRT image is albedo * shading exactly (both computed from the same buffers).
        assert np.allclose(s.prt[k], s.albedo * s.shading[k], atol=1e-6)
        # Shading of a white surface under a light of mean luminance <= 0.9
        # stays in a physical range; a mean far from 0 proves T and L line up.
        mean_shade = s.shading[k][inside].mean()
        assert 0.05 < mean_shade < 1.5
    meta = s.meta
    assert meta["seed"] == 11 and meta["index"] == 3
    assert meta["passes"] == {"asked": ["body", "prt", "pt"], "skipped": []}
    for key in ("body", "pose", "appearance", "camera", "lights", "versions", "timings", "geometry", "bake"):
        assert key in meta
    for light in meta["lights"]:
        assert 0.7 <= light["reference_luminance"] <= 0.9
        assert light["name"] not in presets.HELD_OUT
        assert sh.mean_luminance(np.array(light["sh"])) == pytest.approx(light["reference_luminance"], rel=1e-6)


@needs_bpy
@pytest.mark.anny
def test_same_seed_gives_identical_geometry_and_sidecar(scene_pair):
    a, b = (json.loads(p.read_text()) for p in scene_pair)
    assert a["geometry"]["hash"] == b["geometry"]["hash"]
    assert _without_timings(a) == _without_timings(b)


@needs_bpy
@pytest.mark.anny
def test_different_index_gives_different_scene_and_specular_off_is_recorded(model, tmp_path, scene_pair):
    other = render_scene(4, 11, SceneOptions(**dict(SMALL, lights=1, specular="off")), tmp_path)
    a = json.loads(scene_pair[0].read_text())
    b = json.loads(other.read_text())
    assert a["geometry"]["hash"] != b["geometry"]["hash"]
    assert b["bake"]["specular"] == "off"


@pytest.mark.anny
def test_posed_body_bytes_do_not_depend_on_the_processs_torch_threads(model):
    # a farm worker's torch thread count follows its core share (--workers): with anny posing on
    # that many threads, one seed gave different vertex bytes under --workers 1 and 2
    import torch

    rest = bodies.build_body(bodies.BodyParams(0.3, 0.6, 0.7, 0.4, 0.55, 0.5), None)
    axes = poses.RestAxes.from_joints(rest.joints, rest.bone_labels)
    pose = poses.pose_deltas(poses.sample_pose(np.random.default_rng(5), axes), rest.bone_labels)
    before = torch.get_num_threads()
    built = []
    try:
        for threads in (1, 2, 3):
            torch.set_num_threads(threads)
            built.append(bodies.build_body(bodies.BodyParams(0.3, 0.6, 0.7, 0.4, 0.55, 0.5), pose))
            assert torch.get_num_threads() == threads  # the caller's count is given back
    finally:
        torch.set_num_threads(before)
    for body in built[1:]:
        assert body.vertices.tobytes() == built[0].vertices.tobytes()
        assert body.joints.tobytes() == built[0].joints.tobytes()


@pytest.mark.anny
def test_diffuse_only_outfits_are_pure_lambert_and_others_are_not(model):
    from farm.synthesis import appearance, material_specs

    body = bodies.build_body(bodies.BodyParams(0.3, 0.8, 0.5, 0.5, 0.5, 0.5), None)
    parts, record = appearance.dress(body, np.random.default_rng(0), diffuse_only=True)
    assert record["diffuse_only"] and all(material_specs.is_diffuse(p.material) for p in parts)
    parts, _ = appearance.dress(body, np.random.default_rng(0), diffuse_only=False)
    assert not any(material_specs.is_diffuse(p.material) for p in parts)
    names = [p.name for p in parts]
    assert names[0] == "body" and "top" in names and "bottom" in names
    for p in parts:
        assert np.all(np.isfinite(p.vertices)) and p.faces.max() < len(p.vertices)
        assert np.allclose(np.linalg.norm(p.normals, axis=1), 1.0, atol=1e-6)
    # Hidden body vertices lie under garments: fewer than the body has, more than none.
    hidden = parts[0].hidden
    assert 0 < hidden.sum() < len(hidden)


@needs_bpy
@pytest.mark.anny
def test_body_pass_is_the_unclothed_body_where_cycles_sees_it(scene_pair):
    """The ray-cast body (farm/rendering/body_pass.py) against Cycles' own buffers of the dressed person:
    the body lies inside the person's silhouette, and where Cycles' visible surface is the body
    itself (its depth within 2 mm of the body's) the two normals are the same smooth normal, up
    to the pixel filters (Cycles: 16 samples through a 1.5 px Blackman-Harris; the pass: 4 rays
    through a box), which mix neighbouring normals only at silhouettes."""
    s = dataset.read_scene(scene_pair[0])
    alpha, body = s.alpha[..., 0], s.body_alpha[..., 0]
    assert 0.0 < body.mean() <= alpha.mean()
    assert np.all(alpha[body == 1.0] > 0.5)  # a pixel all body is at least half person
    length = np.linalg.norm(s.body_normal, axis=-1)
    assert np.allclose(length[body > 0], 1.0, atol=1e-5) and np.all(length[body == 0] == 0)
    same = (body == 1.0) & (alpha > 0.999) & (np.abs(s.body_depth[..., 0] - s.depth[..., 0]) < 0.002)
    assert same.sum() >= 10  # face and hands at least
    cos = (s.body_normal[same] * s.normal[same]).sum(axis=-1)
    assert np.median(cos) > 0.999 and np.percentile(cos, 5) > 0.99


@needs_bpy
@pytest.mark.anny
def test_only_asked_passes_are_rendered(model, tmp_path):
    prt_only = render_scene(5, 1, SceneOptions(**dict(SMALL, lights=1, passes=frozenset({"prt"}))), tmp_path)
    s = dataset.read_scene(prt_only)
    assert s.images is None and s.transport is not None and s.body_normal is None
    assert s.meta["passes"]["skipped"] == ["pt", "body"]
    assert "path_trace" not in s.meta["timings"]
    pt_only = render_scene(6, 1, SceneOptions(**dict(SMALL, lights=1, passes=frozenset({"pt"}))), tmp_path)
    s = dataset.read_scene(pt_only)
    assert s.transport is None and s.prt is None and len(s.images) == 1
    assert s.meta["passes"]["skipped"] == ["prt", "body"]
    assert "bake" not in s.meta["timings"]


def test_heldout_pool_uses_only_heldout_maps():
    assert set(lights.light_pool("heldout")) == set(presets.HELD_OUT)
    train = lights.light_pool("train")
    assert not set(train) & presets.HELD_OUT
    assert lights.SKY in train


@needs_bpy
def test_training_pool_takes_blenders_bundled_maps():
    """Blender's own studio-light maps (found through the bpy wheel) join the training pool."""
    assert any(n.startswith(presets.BLENDER_PREFIX) for n in lights.light_pool("train"))


def test_light_sh_is_rotated_scaled_and_in_camera_frame():
    rng = np.random.default_rng(0)
    cam_rows = camera.orientation(6.0, -2.0)
    light = lights.sample_light(rng, ["bridge"], 4, cam_rows)
    raw = sh_projection.project_equirect(light.pixels, 8)
    turned = sh_rotation.rotate(raw, sh_rotation.z_rotation(light.rotation_deg))
    expected = sh_rotation.rotate(turned * light.scale, cam_rows)
    assert np.allclose(light.sh8, expected, atol=1e-9)
    assert np.allclose(light.sh, expected[:25], atol=1e-9)


@pytest.mark.parametrize(
    "change, message",
    [
        ({"resolution": 4}, "resolution"),
        ({"lights": 0}, "lights"),
        ({"passes": frozenset({"pt", "albedo"})}, "passes"),
        ({"specular": "maybe"}, "specular"),
        ({"light_pool": "test"}, "light_pool"),
        ({"sh_order": -1}, "sh_order"),
    ],
)
def test_bad_options_raise_value_error(tmp_path, change, message):
    with pytest.raises(ValueError, match=message):
        render_scene(0, 0, SceneOptions(**dict(SMALL, **change)), tmp_path)
    assert not list(tmp_path.glob("scene_*"))


@pytest.mark.anny
def test_pose_sampler_respects_limits_and_rejects_intersections(model):
    rest = bodies.build_body(bodies.BodyParams(0.5, 0.8, 0.5, 0.5, 0.5, 0.5), None)
    axes = poses.RestAxes.from_joints(rest.joints, rest.bone_labels)
    rng = np.random.default_rng(0)
    for family in poses.FAMILIES:
        p = poses.sample_pose(rng, axes, family)
        deltas = poses.pose_deltas(p, rest.bone_labels)
        # Every delta is a proper rotation with no translation.
        r = deltas[:, :3, :3]
        assert np.allclose(r @ r.transpose(0, 2, 1), np.eye(3), atol=1e-9)
        assert np.allclose(np.linalg.det(r), 1.0) and np.all(deltas[:, :3, 3] == 0)
    # Swinging the left arm 80 degrees past its rest angle drives it through the
    # torso: flagged as a gross intersection.
    bad = poses.Pose("test")
    bad.add("upperarm01.L", poses.Y, 80.0)
    body = bodies.build_body(bodies.BodyParams(0.5, 0.8, 0.5, 0.5, 0.5, 0.5), poses.pose_deltas(bad, rest.bone_labels))
    overlap, pair = poses.worst_penetration(body.vertices, body.joints, body.bone_labels, body.bone_weights)
    assert overlap > 0.3 and "forearm.L" in pair
    ok, _ = poses.worst_penetration(rest.vertices, rest.joints, rest.bone_labels, rest.bone_weights)
    assert ok == 0.0


def test_camera_frames_every_vertex():
    rng = np.random.default_rng(4)
    verts = np.random.default_rng(1).uniform([-0.3, -0.2, 0.0], [0.3, 0.2, 1.8], size=(500, 3))
    for _ in range(20):
        cam = camera.frame_person(verts, rng)
        uv = cam.project(verts)
        assert np.abs(uv).max() < 0.5
        rows = cam.world_to_camera
        assert np.allclose(rows @ rows.T, np.eye(3), atol=1e-12) and np.linalg.det(rows) == pytest.approx(1.0)
        assert 35.0 <= cam.focal_mm <= 85.0
        assert math.degrees(math.asin(rows[1, 2])) == pytest.approx(cam.pitch_deg, abs=1e-9)


@needs_bpy
def test_sky_light_is_rendered_from_blender_sky_texture(tmp_path):
    """The procedural sky: finite, the sun above the horizon (L_1,0 > 0 with an upright camera)."""
    from farm.rendering import blender_scene, passes

    blender_scene.reset_scene()
    rng = np.random.default_rng(2)
    light = lights.sample_light(
        rng, [lights.SKY], 4, np.eye(3), lambda p: passes.render_sky_equirect(p, lights.SKY_SIZE, tmp_path)
    )
    assert light.source == "sky" and light.pixels.shape == (*lights.SKY_SIZE, 3)
    assert np.all(np.isfinite(light.pixels)) and light.pixels.min() >= 0.0
    # Up is +Z in world and camera frames here: a sky above the horizon lights from above.
    assert light.sh[2].mean() > 0.0
    top, bottom = light.pixels[: lights.SKY_SIZE[0] // 2], light.pixels[lights.SKY_SIZE[0] // 2 :]
    assert top.mean() > 5.0 * bottom.mean()
    assert sh.mean_luminance(light.sh) == pytest.approx(light.reference_luminance, rel=1e-6)


@needs_bpy
def test_bad_thread_count_in_environment_is_a_clear_error(tmp_path, monkeypatch):
    monkeypatch.setenv("RELIGHT_CYCLES_THREADS", "two")
    with pytest.raises(ValueError, match="RELIGHT_CYCLES_THREADS"):
        render_scene(0, 0, SceneOptions(**SMALL), tmp_path)


@needs_bpy
@pytest.mark.anny
def test_diffuse_scene_image_matches_albedo_times_shading_end_to_end(model, tmp_path, monkeypatch):
    """All frames line up: Cycles' image vs albedo * (T . L) from the stored T and camera-frame L.

    With every material pure Lambert, the path-traced person differs from
    albedo * (T . L) only by interreflection (adds light: a few %), the
    S = 128 bake quadrature (~1.5 % mean, see docs/benchmarks/farm_scene.md)
    and denoised 16 spp noise. So the mean ratio must be within 15 % of 1,
    the per-pixel correlation high, and turning the stored light upside
    down (a frame error) must visibly lower the correlation.
    """
    from farm import scene as farm_scene
    from relight.network import prt

    monkeypatch.setattr(farm_scene, "DIFFUSE_ONLY_SHARE", 1.0)
    opts = SceneOptions(resolution=64, lights=2, samples=16, denoise=True, bake_directions=128)
    s = dataset.read_scene(render_scene(1, 2, opts, tmp_path))
    assert s.meta["appearance"]["diffuse_only"] and s.meta["bake"]["specular"] == "skipped (all diffuse)"
    inside = s.alpha[..., 0] > 0.999
    upside_down = np.diag([1.0, -1.0, -1.0])
    for k in range(2):
        image = s.images[k][inside].mean(axis=-1)
        predicted = s.prt[k][inside].mean(axis=-1)
        assert 0.85 < image.mean() / predicted.mean() < 1.15
        good = np.corrcoef(image, predicted)[0, 1]
        light = np.array(s.meta["lights"][k]["sh"])
        wrong = (s.albedo * prt.shading(s.transport, sh_rotation.rotate(light, upside_down)))[inside].mean(axis=-1)
        assert good > 0.9
        assert np.corrcoef(image, wrong)[0, 1] < good - 0.1


def test_light_pool_names_are_unique_and_resolve():
    """Every pool entry is one light: the procedural sky does not shadow the bundled 'sky' map."""
    for kind in ("train", "heldout"):
        pool = lights.light_pool(kind)
        assert len(pool) == len(set(pool))
        for name in pool:
            if name != lights.SKY:
                assert presets.preset_path(name).is_file()
    assert "sky" in lights.light_pool("train") and lights.SKY in lights.light_pool("train")
