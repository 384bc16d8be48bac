"""Group scenes in the farm (issue 47): two to five people per scene (farm/synthesis/people.py),
placed apart, touching or overlapping, framed together, with one mask per person (person.PK)
that the nearer person wins and that sum to alpha; one-person scenes draw nothing new."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

try:
    import bpy
except ImportError:
    bpy = None

from farm.cli import parse_args
from farm.execution.run_config import UsageError
from farm.synthesis.scene_options import SceneOptions
from farm.synthesis import camera, people
from farm.synthesis.appearance import Part
from relight.files import dataset

REPO = Path(__file__).resolve().parents[2]
needs_bpy = pytest.mark.skipif(bpy is None, reason="needs bpy (the farm extra)")


def test_people_counts_parse_and_bad_ones_are_refused():
    assert people.parse_people("1") == (1, 1)
    assert people.parse_people(" 2-5 ") == (2, 5)
    assert people.parse_people("3") == (3, 3)
    for bad in ("0", "6", "5-2", "1-6", "two", "", "2-", True):
        with pytest.raises(ValueError, match="people"):
            people.parse_people(bad)
    with pytest.raises(ValueError, match="people"):
        SceneOptions(people="0-3").validate()
    base = ["--out", "/tmp/x", "--scenes", "1", "--seed", "1"]
    assert parse_args(base + ["--people", "2-5"]).scene.people == "2-5"
    assert parse_args(base + ["--people", "4-4"]).scene.people == "4"
    with pytest.raises(UsageError, match="people"):
        parse_args(base + ["--people", "9"])
    with pytest.raises(UsageError, match="people must be 1"):
        parse_args(base + ["--people", "2", "--clip-frames", "4"])
    from farm import clips

    with pytest.raises(ValueError, match="people must be '1' for clips"):
        clips.SceneOptions(people="2-3").validate()


def test_one_person_options_are_recorded_as_before_and_groups_round_trip():
    assert "people" not in SceneOptions().to_json()  # the sidecars of before, byte for byte
    assert "people" not in SceneOptions(people="1").to_json()
    group = SceneOptions(people="2-5")
    assert group.to_json()["people"] == "2-5"
    assert SceneOptions.from_json(group.to_json()) == group
    assert SceneOptions.from_json(SceneOptions().to_json()) == SceneOptions()
    # the disk check's channel count: one mask per person of the largest group
    assert group.expected_channels() == SceneOptions().expected_channels() + 5


def test_counts_are_drawn_uniformly_and_one_person_draws_nothing():
    assert people.people_plan("1", 5, 0) == people.GroupPlan(1)
    plans = [people.people_plan("2-5", 7, i) for i in range(400)]
    assert plans == [people.people_plan("2-5", 7, i) for i in range(400)]  # same seed, same plans
    counts = np.bincount([p.count for p in plans], minlength=6)
    # binomial(400, 1/4) per count: mean 100, sd 8.7; 3.5 sd either way
    assert counts[:2].sum() == 0 and np.all(np.abs(counts[2:] - 100) < 31), counts
    for p in plans:
        assert len(p.relations) == len(p.depth_m) == p.count - 1
        assert abs(p.yaw_deg) <= people.GROUP_YAW_DEG
    relations = [r for p in plans for r in p.relations]
    for name, share in zip(people.RELATIONS, people.RELATION_P):
        n = len(relations)  # binomial(n, share): 4 sd either way
        assert abs(relations.count(name) - share * n) < 4 * np.sqrt(n * share * (1 - share)), name


def _cylinder_person(radius: float, height: float, x: float) -> people.Person:
    """A person of points: a capped cylinder's surface, points about 1 cm apart, root at (x, 0)."""
    turns = np.linspace(0.0, 2 * np.pi, int(2 * np.pi * radius / 0.01), endpoint=False)
    rings = np.linspace(0.0, height, int(height / 0.01) + 1)
    t, z = np.meshgrid(turns, rings)
    side = np.stack([x + radius * np.cos(t).ravel(), radius * np.sin(t).ravel(), z.ravel()], axis=1)
    r, t = np.meshgrid(np.linspace(0.0, radius, int(radius / 0.01) + 1), turns)
    cap = np.stack([x + (r * np.cos(t)).ravel(), (r * np.sin(t)).ravel(), np.full(r.size, height)], axis=1)
    vertices = np.concatenate([side, cap])
    body = type("Body", (), {})()
    body.vertices, body.joints = vertices.copy(), np.array([[x, 0.0, 1.0]])
    part = Part("body", vertices, vertices, np.zeros((0, 3), dtype=np.int64), np.zeros_like(vertices), {})
    return people.Person(None, None, 0.0, 0.0, "", body, [part], {}, False)


def _nearest(a: np.ndarray, b: np.ndarray) -> float:
    from scipy.spatial import cKDTree

    return float(cKDTree(a).query(b, k=1)[0].min())


@pytest.mark.parametrize("yaw", [0.0, 20.0])
def test_people_are_placed_touching_overlapping_or_apart_and_never_through_each_other(yaw):
    persons = [_cylinder_person(0.2, 1.7, 3.0), _cylinder_person(0.15, 1.5, -2.0), _cylinder_person(0.25, 1.8, 0.0),
               _cylinder_person(0.2, 1.6, 1.0)]
    plan = people.GroupPlan(4, yaw, ("touching", "overlap", "apart"), (0.05, 0.6, 0.0), (0.3, 0.4, 0.3),
                            (0.1, 0.1, 0.15))
    people.place_people(persons, plan)
    points = [p.vertices() for p in persons]
    right = np.array([np.cos(np.radians(yaw)), np.sin(np.radians(yaw)), 0.0])
    for i in range(4):
        for j in range(i + 1, 4):
            assert _nearest(points[i], points[j]) >= people.CLEARANCE_M  # nobody passes through anybody
    # touching: stopped within one halved-thrice step of the first position that came too close
    assert _nearest(points[0], points[1]) <= people.CLEARANCE_M + people.SLIDE_STEP_M / 8 + 1e-9
    # overlap: 0.6 m behind (wider than the two radii): slid until 40 % of its 0.5 m width is
    # behind its neighbour's right edge, to the slide's step
    overlap = (points[1] @ right).max() - (points[2] @ right).min()
    assert abs(overlap - 0.4 * 0.5) <= people.SLIDE_STEP_M + 1e-9
    assert persons[2].placement["touched"] is False
    # apart: first clear of its neighbour, then 0.15 m further along the row
    assert _nearest(points[2], points[3]) >= 0.15 - 1e-9
    assert [p.placement["relation"] for p in persons] == ["first", "touching", "overlap", "apart"]


def _stick(x: float, scale: float):
    """A standing stick person at x (points), and its landmarks, `scale` times an adult's size."""
    rng = np.random.default_rng(int(100 * x + 10 * scale) % 2**32)
    z = rng.uniform(0.0, 1.5, 3000) * scale
    trunk = np.stack([x + rng.uniform(-0.15, 0.15, z.size), rng.uniform(-0.1, 0.1, z.size), z], axis=1)
    d = rng.normal(size=(800, 3))
    head = 0.11 * d / np.linalg.norm(d, axis=1, keepdims=True) + [x, 0.0, 1.62 * scale]
    joints = np.array([[0.0, 0.0, 1.52], [0.15, 0, 1.42], [-0.15, 0, 1.42], [0.1, 0, 0.92], [-0.1, 0, 0.92],
                       [0.1, 0, 0.5], [-0.1, 0, 0.5], [0.03, -0.08, 1.65], [-0.03, -0.08, 1.65]]) * [1, 1, scale] + [x, 0, 0]
    labels = ["head", "upperarm01.L", "upperarm01.R", "upperleg01.L", "upperleg01.R", "lowerleg01.L",
              "lowerleg01.R", "eye.L", "eye.R"]
    verts = np.concatenate([trunk, head])
    return verts, head, camera.landmarks(verts, joints, labels, head)


@pytest.mark.parametrize("framing", ["three-quarter", "waist-up", "head-and-shoulders", "face"])
def test_a_cut_framing_keeps_every_persons_head_in_the_frame(framing):
    sticks = [_stick(-0.7, 1.0), _stick(0.0, 0.8), _stick(0.65, 1.05)]
    vertices = np.concatenate([s[0] for s in sticks])
    bands = [(*camera.band(framing, s[2]), s[2].head) for s in sticks]
    for seed in range(6):
        cam = camera.frame_shot(vertices, sticks[0][2], framing, np.random.default_rng(seed), 0.0, bands=bands,
                                facing_scale=camera.GROUP_FACING_SCALE)
        assert abs(cam.shot["facing_deg"]) <= 90.0 * camera.GROUP_FACING_SCALE
        assert len(cam.shot["people_band_z"]) == 3
        for _, head, _ in sticks:  # every head wholly inside, the shorter person's too
            assert np.abs(cam.project(head)).max() < 0.5, (framing, seed)


def _channels(rng, shares):
    """Geometry channels of a 6 x 5 scene and one mask per share map (coverage = share * alpha)."""
    alpha = rng.uniform(0.0, 1.0, (6, 5)).astype(np.float32)
    alpha[0, 0] = 0.0
    out = {"alpha": alpha, "albedo": np.zeros((6, 5, 3), np.float32), "normal": np.zeros((6, 5, 3), np.float32),
           "material": np.zeros((6, 5, 3), np.float32), "depth": np.zeros((6, 5), np.float32)}
    out.update({f"person.P{k}": (share * alpha).astype(np.float32) for k, share in enumerate(shares)})
    return out


def test_scene_files_keep_the_masks_and_refuse_ones_that_do_not_partition_alpha(tmp_path):
    from relight.files.exr import write_exr

    rng = np.random.default_rng(0)
    meta = {"index": 1, "sh_order": 1, "lights": [], "people": {"count": 3}}
    cut = np.sort(rng.uniform(0.0, 1.0, (2, 6, 5)), axis=0)
    shares = [cut[0], cut[1] - cut[0], 1.0 - cut[1]]
    dataset.write_scene(tmp_path / "scene_000001", _channels(rng, shares), meta)
    scene = dataset.read_scene(tmp_path / "scene_000001")
    assert len(scene.people) == 3 and scene.people[0].shape == (6, 5, 1)
    assert np.abs(np.sum(scene.people, axis=0) - scene.alpha).max() <= dataset.PERSON_SUM_TOLERANCE
    alone = _channels(rng, [])
    dataset.write_scene(tmp_path / "scene_000002", alone, {"index": 2, "sh_order": 1, "lights": []})
    assert dataset.read_scene(tmp_path / "scene_000002").people is None
    bad = {
        "sum to alpha": _channels(rng, [np.full((6, 5), 0.5), np.full((6, 5), 0.51), np.zeros((6, 5))]),
        "not P0..P2": {k.replace("P2", "P3"): v for k, v in _channels(rng, shares).items()},
        "3 people": _channels(rng, shares[:1] + [shares[1] + shares[2]]),
    }
    for message, channels in bad.items():
        with pytest.raises(ValueError, match=message):
            dataset.write_scene(tmp_path / "scene_000003", channels, {**meta, "index": 3})
        assert not (tmp_path / "scene_000003.json").exists()
    # a file whose masks were changed after it was written: refused on reading too
    planes = {f"{k}.A": v for k, v in bad["sum to alpha"].items() if k.startswith("person")}
    planes.update({"alpha.A": bad["sum to alpha"]["alpha"], "depth.Z": np.zeros((6, 5), np.float32)})
    planes.update({f"{g}.{c}": np.zeros((6, 5), np.float32) for g, cs in (("albedo", "RGB"), ("normal", "XYZ"),
                                                                           ("material", "RGB")) for c in cs})
    write_exr(tmp_path / "scene_000001.exr", planes, compression="zip")
    with pytest.raises(ValueError, match="scene EXR scene_000001.exr: person masks do not sum to alpha"):
        dataset.read_scene(tmp_path / "scene_000001", verify_hash=False)


# ------------------------------------------------------------------ a group rendered end to end

OPTIONS = {"resolution": 40, "lights": 1, "samples": 2, "bake_directions": 32, "people": "2"}


def _overlap_seed() -> int:
    """The first seed whose scene 0 puts its second person partly in front of or behind the first."""
    return next(s for s in range(1, 200) if people.people_plan("2", s, 0).relations == ("overlap",))


@pytest.fixture(scope="module")
def group_render(tmp_path_factory):
    """One two-person scene rendered by `python -m farm` (its own process), read back."""
    out = tmp_path_factory.mktemp("group")
    seed = _overlap_seed()
    env = {**os.environ, "RELIGHT_CYCLES_THREADS": "1"}
    run = subprocess.run([sys.executable, "-m", "farm", "--out", str(out), "--scenes", "1", "--seed", str(seed),
                          "--res", "40", "--lights", "1", "--samples", "2", "--directions", "32", "--no-denoise",
                          "--people", "2", "--workers", "1", "--no-pin", "--no-progress"],
                         cwd=REPO, env=env, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    return seed, dataset.read_scene(out / "scene_000000")


def _rays(sample, part_ids, resolution, s=2):
    """Per pixel sub-ray [R, R, s*s]: the hit distance of the parts `part_ids` alone (inf: none)."""
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    from farm.rendering.body_pass import film_directions

    cam_vertices, _ = sample.camera_mesh()
    offsets = sample.offsets
    verts = np.concatenate([cam_vertices[offsets[i]:offsets[i + 1]] for i in part_ids])
    starts = np.cumsum([0] + [offsets[i + 1] - offsets[i] for i in part_ids])
    faces = np.concatenate([sample.parts[i].faces + starts[n] for n, i in enumerate(part_ids)])
    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, np.ascontiguousarray(verts, np.float32), np.ascontiguousarray(faces, np.int32))
    dirs = film_directions(resolution, sample.camera.focal_mm, s).reshape(-1, 3)
    hit = scene.run(np.zeros_like(dirs), dirs, output=1)
    t = np.where(np.asarray(hit["primID"]) >= 0, np.asarray(hit["tfar"], np.float64), np.inf)
    return t.reshape(resolution, resolution, s * s)


@needs_bpy
@pytest.mark.anny
def test_a_rendered_group_has_a_mask_per_person_that_sums_to_alpha(group_render):
    _, scene = group_render
    meta = scene.meta
    assert meta["options"]["people"] == "2" and meta["people"]["count"] == 2
    assert len(scene.people) == 2 and all(m.shape == (40, 40, 1) for m in scene.people)
    masks = np.concatenate(scene.people, axis=-1)
    assert masks.min() >= 0.0 and masks.max() <= 1.0
    gap = np.abs(masks.sum(axis=-1, dtype=np.float64) - scene.alpha[..., 0])
    assert gap.max() <= dataset.PERSON_SUM_TOLERANCE
    for k, person in enumerate(meta["people"]["persons"]):
        rows, cols = np.nonzero(scene.people[k][..., 0] > 0)
        assert person["pixels"] > 10 and person["box"] == [cols.min(), rows.min(), cols.max() + 1, rows.max() + 1]
        assert person["body"] and person["pose"]["family"] and person["appearance"]["garments"]
    # every pass sees both people: transport, the body pass, the head mask
    for k in range(2):
        inside = scene.people[k][..., 0] > 0.999
        assert np.all(scene.body_alpha[..., 0][inside] >= 0.0) and scene.body_alpha[..., 0][inside].mean() > 0.5
        assert np.abs(scene.transport[inside]).sum(axis=-1).min() > 0.0
    assert scene.head.max() > 0.5 and scene.images[0].shape == (40, 40, 3)
    assert sorted(meta["geometry"]["parts"])[0].startswith("p0.") and any(p.startswith("p1.") for p in meta["geometry"]["parts"])


@needs_bpy
@pytest.mark.anny
def test_a_group_is_the_same_bytes_in_another_process_and_its_nearer_person_wins(group_render):
    from farm.scene import sample_scene

    seed, scene = group_render
    options = SceneOptions(**OPTIONS)
    sample = sample_scene(0, seed, options)
    again = sample_scene(0, seed, options)
    assert sample.geometry_record()["hash"] == scene.meta["geometry"]["hash"] == again.geometry_record()["hash"]
    assert json.dumps(sample.record()["people"]) == json.dumps(again.record()["people"])
    owner = np.asarray(sample.part_people)
    t0 = _rays(sample, np.nonzero(owner == 0)[0], 40)
    t1 = _rays(sample, np.nonzero(owner == 1)[0], 40)
    # each person's mask lies where that person projects (one pixel of slack: the render samples
    # the pixel at random, these rays at 2 x 2 points)
    for k, t in enumerate((t0, t1)):
        seen = np.isfinite(t).any(axis=-1)
        grown = np.zeros_like(seen)
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                grown |= np.roll(np.roll(seen, dy, 0), dx, 1)
        assert np.all(scene.people[k][..., 0][~grown] == 0.0)
    # overlap: pixels whose every ray, and every ray of the 8 pixels round, meets both people
    # with the same one nearer; there the nearer person holds the pixel
    both = np.isfinite(t0).all(-1) & np.isfinite(t1).all(-1)
    first_nearer = both & (t0 < t1).all(-1)
    second_nearer = both & (t1 < t0).all(-1)
    for nearer, k in ((first_nearer, 0), (second_nearer, 1)):
        interior = nearer.copy()
        for dy in (-1, 0, 1):
            for dx in (-1, 0, 1):
                interior &= np.roll(np.roll(nearer, dy, 0), dx, 1)
        interior[[0, -1], :] = interior[:, [0, -1]] = False
        share = scene.people[k][..., 0][interior] / scene.alpha[..., 0][interior]
        assert np.all(share > 0.5), share.min()
    assert (first_nearer | second_nearer).sum() >= 4  # the seeded draw overlaps


def test_the_dataset_summary_counts_people_and_overlaps():
    from farm.execution.summary import features

    alone = features({})
    assert alone["people: 1"] and not alone["people: 3"] and not alone["people placed overlapping (any)"]
    persons = [{"placement": {"relation": r}} for r in ("first", "touching", "overlap")]
    group = features({"people": {"count": 3, "persons": persons}})
    assert group["people: 3"] and not group["people: 1"] and group["people placed overlapping (any)"]
    assert not features({"people": {"count": 2, "persons": persons[:2]}})["people placed overlapping (any)"]
