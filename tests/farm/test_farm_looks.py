"""The look pools (issue 45, farm/synthesis/looks.py): the held-out pool's garments, patterns,
prints, hair, skin, irises and accessories are never drawn by the train pool and the other way
round; the train pool draws what the farm drew before; the pool is an option recorded in the
sidecar; a held-out scene keeps the train scene's body, pose, camera and lights; it renders."""

from __future__ import annotations

import colorsys
import hashlib
import json

import numpy as np
import pytest

try:
    import bpy
except ImportError:
    bpy = None

from farm.cli import parse_args
from farm.execution.run_config import UsageError
from farm.synthesis import appearance, bodies, hair, looks, prints
from farm.synthesis.scene_options import SceneOptions
from relight.imaging.colour import srgb_encode

needs_bpy = pytest.mark.skipif(bpy is None, reason="needs bpy (the farm extra)")
SEEDS = range(80)


@pytest.fixture(scope="module")
def body():
    return bodies.build_body(bodies.BodyParams(0.4, 0.8, 0.5, 0.5, 0.5, 0.5), None)


@pytest.fixture(scope="module")
def drawn(body):
    """Per pool, the appearance records of 80 people (skirts allowed for two in three, a fifth diffuse)."""
    out = {}
    for look in (looks.TRAIN, looks.HELDOUT):
        out[look.name] = [appearance.dress(body, np.random.default_rng([45, seed]), seed % 5 == 0, seed % 3 != 0,
                                           look)[1] for seed in SEEDS]
    return out


def hsv(rgb):
    """sRGB-encoded HSV of a linear colour (the space the pools' colour ranges are drawn in)."""
    return colorsys.rgb_to_hsv(*np.clip(srgb_encode(np.asarray(rgb, np.float64)), 0.0, 1.0))


def categories(record: dict) -> dict[str, set]:
    """What one person drew, per category of the pools' table."""
    garments = record["garments"]
    mats = [g["material"] for g in garments.values()]
    cloth = [m for slot, m in ((s, g["material"]) for s, g in garments.items()) if slot != "shoes"]
    colours = [m["base_color"] for m in mats] + [m["second_color"] for m in cloth if m["pattern"] != "none"]
    colours += [c for m in mats if m.get("print") for c in m["print"]["colours"]]
    colours += [a["material"]["base_color"] for a in record.get("accessories", {}).values()]
    skin = record["skin"]
    out = {
        "top": {garments[s]["kind"] if s == "top" else "dress" for s in garments if s in ("top", "dress")},
        "bottom": {garments["bottom"]["kind"]} if "bottom" in garments else set(),
        "outer": {garments["outer"]["kind"]} if "outer" in garments else set(),
        "hood": {"hood"} if any("hood" in g for g in garments.values()) else set(),
        "shoes": {garments["shoes"]["kind"] if "shoes" in garments else "barefoot"},
        # a pattern with its scale's range: the held-out pool's stripes and checks are finer
        "pattern": {(m["pattern"], "fine" if m["pattern_scale"] > 35 else "coarse") for m in cloth
                    if m["pattern"] != "none"},
        "print": {m["print"]["kind"] for m in mats if m.get("print")},
        "hair style": {record["hair"]["style"]},
        "accessories": set(record.get("accessories", {})),
        # colours as the region of the table they fall in (held-out: muted tints or deep darks)
        "fabric colour": {"heldout" if (0.05 < s < 0.16 and v > 0.29) or (v < 0.18 and s > 0.0) else "train"
                          for _, s, v in map(hsv, colours)},
        "skin tone": {"heldout" if not 0.47 < skin["base_color"][1] / skin["base_color"][0] < 0.79 else "train"},
        "skin mottle": {(skin["mottle"]["amount"] >= 0.12, skin["mottle"]["scale"] >= 110.0)},
        "iris": {"green" if 0.21 < hsv(record["face"]["eyes"]["material"]["iris"]["colour"])[0] < 0.39 else "other"},
    }
    if "material" in record["hair"]:
        _, s, v = hsv(record["hair"]["material"]["base_color"])
        out["hair colour"] = {"pastel or platinum" if v > 0.81 and 0.11 < s < 0.45 else "other"}
        streaks = record["hair"]["material"]["streaks"]
        out["hair streaks"] = {(streaks["amount"] >= 0.32, streaks["scale"] >= 70.0)}
    return out


@pytest.mark.anny
def test_no_category_draws_a_look_of_the_other_pool(drawn):
    seen = {}
    for name, records in drawn.items():
        for record in records:
            for category, values in categories(record).items():
                seen.setdefault(category, {}).setdefault(name, set()).update(values)
    one_sided = {"hood": "train", "accessories": "heldout"}  # drawn by one pool only
    for category, pools in seen.items():
        for name in ("train", "heldout"):
            assert pools.get(name) or one_sided.get(category) not in (None, name), (category, name)
        assert not pools.get("train", set()) & pools.get("heldout", set()), (category, pools)
    # each pool draws only its own table, and over 80 people every entry of the held-out tables
    assert seen["top"]["heldout"] == set(looks.HELDOUT.top_kinds)
    assert seen["bottom"]["heldout"] == {"bermuda", "cropped", "maxi_skirt"}
    assert seen["outer"]["heldout"] == {"vest"} and seen["shoes"]["heldout"] == {"knee_boots", "slip_ons"}
    assert seen["hair style"]["heldout"] == set(hair.HELDOUT_STYLES)
    assert seen["hair style"]["train"] <= set(hair.STYLES)
    assert seen["print"]["heldout"] == set(prints.HELDOUT_KINDS) and seen["print"]["train"] <= set(prints.PRINT_KINDS)
    assert seen["pattern"]["heldout"] == {("dots", "coarse"), ("plaid", "coarse"), ("stripes", "fine"), ("checks", "fine")}
    assert seen["accessories"]["heldout"] == {"scarf", "belt"} and not seen["accessories"].get("train")
    assert seen["hood"]["train"] == {"hood"} and not seen["hood"].get("heldout")
    for category in ("fabric colour", "skin tone", "iris", "hair colour"):
        assert seen[category]["heldout"] == ({"heldout"} if category in ("fabric colour", "skin tone") else
                                             {"green"} if category == "iris" else {"pastel or platinum"}), category
    assert seen["skin mottle"]["heldout"] == {(True, True)} and seen["hair streaks"]["heldout"] == {(True, True)}
    assert all(r["look_pool"] == "heldout" for r in drawn["heldout"])
    assert all("look_pool" not in r for r in drawn["train"])


@pytest.mark.anny
def test_held_out_garments_and_accessories_are_closed_meshes(body):
    for seed in range(12):
        parts, record = appearance.dress(body, np.random.default_rng([46, seed]), False, True, looks.HELDOUT)
        for p in parts:
            assert np.all(np.isfinite(p.vertices)) and p.faces.min() >= 0 and p.faces.max() < len(p.vertices)
            assert p.hidden.shape == (len(p.vertices),)
        by_name = {p.name: p for p in parts}
        for slot in record.get("accessories", {}):
            from farm.synthesis import garments

            assert garments.is_closed(by_name[slot].faces), slot
            assert garments.signed_volume(by_name[slot].vertices, by_name[slot].faces) > 0, slot


@pytest.mark.anny
def test_the_train_pool_draws_what_the_farm_drew_before(body):
    """The digest of 40 people's draws (kinds, patterns, colours, and the stream's state after
    dressing, which counts the draws), recorded with the tree before the pools (1bd7bd2)."""
    def r6(values):
        return [round(float(v), 6) for v in values]

    out = []
    for seed in range(40):
        rng = np.random.default_rng([45, seed])
        _, rec = appearance.dress(body, rng, diffuse_only=seed % 5 == 0, skirt_allowed=seed % 3 != 0)
        mats = {slot: g["material"] for slot, g in rec["garments"].items()}
        out.append({
            "kinds": {slot: g["kind"] for slot, g in rec["garments"].items()},
            "patterns": {slot: [m["pattern"], round(m["pattern_scale"], 6), r6(m["base_color"]), r6(m["second_color"])]
                         for slot, m in mats.items()},
            "prints": {slot: m["print"]["kind"] for slot, m in mats.items() if m.get("print")},
            "hair": [rec["hair"]["style"], r6(rec["hair"].get("material", {}).get("base_color", []))],
            "skin": [r6(rec["skin"]["base_color"]), rec["skin"]["mottle"]["amount"], rec["skin"]["mottle"]["scale"]],
            "iris": r6(rec["face"]["eyes"]["material"]["iris"]["colour"]),
            "accessories": sorted(rec.get("accessories", {})),
            "draws": rng.bit_generator.state["state"]["state"],
        })
    digest = hashlib.sha256(json.dumps(out, sort_keys=True).encode()).hexdigest()
    assert digest == "23978c6a0171cca90e68790937252f3409e0c3aa5496828ddcf5e8f5cae77970"


def test_the_pool_is_an_option_recorded_in_the_sidecar_and_on_the_command_line(tmp_path):
    assert "look_pool" not in SceneOptions().to_json()  # the train pool: the sidecars of before
    held = SceneOptions(look_pool="heldout")
    assert held.to_json()["look_pool"] == "heldout"
    assert SceneOptions.from_json(held.to_json()) == held
    assert SceneOptions.from_json(SceneOptions().to_json()).look_pool == "train"
    with pytest.raises(ValueError, match="look_pool"):
        SceneOptions(look_pool="test").validate()
    with pytest.raises(ValueError, match="look_pool"):
        looks.look_rng("test", 1, 2, 0)
    assert looks.look_rng("train", 1, 2, 0) is None
    base = ["--out", str(tmp_path), "--scenes", "1", "--seed", "1"]
    assert parse_args(base).scene.look_pool == "train"
    assert parse_args(base + ["--look-pool", "heldout"]).scene.look_pool == "heldout"
    from farm import clips

    assert parse_args(base + ["--look-pool", "heldout", "--clip-frames", "4"]).scene.look_pool == "heldout"
    assert isinstance(parse_args(base + ["--clip-frames", "4"]).scene, clips.SceneOptions)
    with pytest.raises(UsageError, match="look-pool"):
        parse_args(base + ["--look-pool", "familiar"])


@pytest.mark.anny
def test_a_held_out_scene_keeps_the_body_pose_camera_and_lights_of_its_train_scene():
    from farm.scene import sample_scene

    for people in ("1", "2-3"):
        train = sample_scene(2, 4545, SceneOptions(lights=3, light_pool="heldout", people=people, hard_lights=0.5))
        held = sample_scene(2, 4545, SceneOptions(lights=3, light_pool="heldout", people=people, hard_lights=0.5,
                                                  look_pool="heldout"))
        assert held.body == train.body and held.pose.as_dict() == train.pose.as_dict()
        assert held.yaw_deg == train.yaw_deg
        assert [(l.name, l.rotation_deg, l.reference_luminance) for l in held.lights] == \
            [(l.name, l.rotation_deg, l.reference_luminance) for l in train.lights]
        assert held.camera.framing == train.camera.framing
        assert held.look["look_pool"] == "heldout" and "look_pool" not in train.look
        assert held.look["garments"]["top"]["kind"] in looks.HELDOUT.top_kinds
        if people != "1":
            assert all(p["appearance"]["look_pool"] == "heldout" for p in held.people["persons"])
            assert [p["placement"]["relation"] for p in held.people["persons"]] == \
                [p["placement"]["relation"] for p in train.people["persons"]]


@needs_bpy
@pytest.mark.anny
def test_a_tiny_held_out_scene_renders_and_records_its_pool(tmp_path):
    from farm.scene import render_scene
    from relight.files import dataset

    options = SceneOptions(resolution=40, lights=1, samples=4, denoise=False, bake_directions=64,
                           light_pool="heldout", look_pool="heldout", framing="waist-up")
    s = dataset.read_scene(render_scene(1, 4545, options, tmp_path))
    assert s.meta["options"]["look_pool"] == "heldout" and s.meta["seed"] == 4545
    look = s.meta["appearance"]
    assert look["look_pool"] == "heldout"
    patterns = {g["material"]["pattern"] for g in look["garments"].values()}
    assert {"dots", "plaid"} <= patterns  # both of the renderer's new patterns are built
    inside = s.alpha[..., 0] > 0.999
    assert inside.mean() > 0.1
    assert np.all(np.isfinite(s.images[0])) and s.images[0][inside].mean() > 0.0
    # the albedo AOV is the garments' colours: a held-out fabric colour shows on the person
    albedo = s.albedo[inside]
    wanted = np.array([g["material"]["base_color"] for g in look["garments"].values()])
    nearest = np.min(np.abs(albedo[:, None, :] - wanted[None]).max(axis=2), axis=1)
    assert (nearest < 0.01).mean() > 0.05
