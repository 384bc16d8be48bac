"""The add-on's World light under headless bpy: the environment texture equals relight's own
projection of the file, live edits, baked procedural Worlds, one bake per change."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import bpy

from blender_addon.blender import bl_dials, bl_light, bl_world
from blender_addon.worker import state
from relight.lighting import presets, sh_projection, sh_rotation
from relight.files.exr import write_exr
from relight.lighting.light import sh_light

from addon_support import H, W, new_node_world, pixels, write_person_png
from addon_panel_support import addon, settings  # noqa: F401 (the fixtures)
from addon_panel_support import TIGHT, expect_error, relight, session
from tiny_model import ORDER



# ------------------------------------------------------------------ World light

def _env_world(path: Path, mapping_rotation=(0.0, 0.0, 0.0), vector_type="POINT"):
    world = new_node_world("relight_test_world")
    tree = world.node_tree
    if tree is None:  # Blender < 5 needs nodes switched on
        world.use_nodes = True
        tree = world.node_tree
    background = next(n for n in tree.nodes if n.type == "BACKGROUND")
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(str(path), check_existing=True)
    mapping = tree.nodes.new("ShaderNodeMapping")
    mapping.vector_type = vector_type
    mapping.inputs["Rotation"].default_value = mapping_rotation
    coords = tree.nodes.new("ShaderNodeTexCoord")
    tree.links.new(env.outputs["Color"], background.inputs["Color"])
    tree.links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    tree.links.new(coords.outputs["Generated"], mapping.inputs["Vector"])
    return world


def test_world_environment_texture_equals_relights_projection_of_the_file(addon, settings):
    path = presets.preset_path("studio")
    world = _env_world(path, (0.0, 0.0, math.radians(90.0)))
    scene = bpy.context.scene
    old = scene.world
    try:
        scene.world = world
        settings.light_kind = "WORLD"
        world_light, rotation = bl_light.target_light(bpy.context, ORDER, "")
        assert rotation == pytest.approx(-90.0)  # Mapping rotates the lookup: the light turns back
        coeffs = world_light.at(0.0)
        expected = sh_light(str(path), ORDER)
        # the same half-float texels read by Blender and by OpenEXR: equal up to
        # float32 summation order in the projection (~1e-6 relative)
        np.testing.assert_allclose(coeffs, expected, rtol=1e-5, atol=1e-5 * np.abs(expected).max())
    finally:
        scene.world = old
        bpy.data.worlds.remove(world)


def test_editing_the_world_relights_live(addon, settings):
    import types

    path = presets.preset_path("studio")
    world = _env_world(path)
    scene = bpy.context.scene
    old = scene.world
    updated = types.SimpleNamespace(id_type_updated=lambda kind: kind == "WORLD")
    try:
        scene.world = world
        settings.light_kind = "WORLD"
        name = addon["photo"]
        relight(name)
        d = session(name).decomposition
        np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], d.relight(sh_light(str(path), ORDER)), atol=TIGHT)
        # the user turns the Mapping node: Blender sends a depsgraph update
        world.node_tree.nodes["Mapping"].inputs["Rotation"].default_value[2] = math.radians(45.0)
        bl_dials.on_depsgraph_update(scene, updated)
        np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], d.relight(sh_light(str(path), ORDER, rotation_deg=-45.0)),
                                   atol=TIGHT)
    finally:
        scene.world = old
        bpy.data.worlds.remove(world)


def test_float_exr_photo_is_taken_as_linear(addon, settings, tmp_path):
    rng = np.random.default_rng(5)
    linear = rng.uniform(0.0, 3.0, (H, W, 3)).astype(np.float32)  # HDR values above 1 too
    path = tmp_path / "hdr_photo.exr"
    write_exr(path, {c: linear[..., i] for i, c in enumerate("RGB")})
    image = bpy.data.images.load(str(path))
    try:
        assert relight(image.name) == {"FINISHED"}
        np.testing.assert_array_equal(session(image.name).photo, linear)
    finally:
        for n in [i.name for i in bpy.data.images if i.name.startswith("hdr_photo.exr")]:
            bpy.data.images.remove(bpy.data.images[n])


def test_baked_world_agrees_with_the_direct_read_including_the_mapping_sign(addon, settings):
    # the Cycles bake renders what Blender shows, so it checks both the panorama
    # orientation and the sign given to the Mapping node's rotation
    path = presets.preset_path("studio")
    for vector_type in ("POINT", "TEXTURE"):
        world = _env_world(path, (0.0, 0.0, math.radians(60.0)), vector_type)
        try:
            direct = bl_world.read_world(world)
            assert direct.source.startswith("environment texture")
            want = sh_rotation.rotate(sh_projection.project_equirect(direct.equirect, ORDER),
                                      sh_rotation.z_rotation(direct.rotation_deg))
            baked = sh_projection.project_equirect(bl_world.bake_world(world, 128), ORDER)
            # 128 x 64 panorama with a 0.5 px filter vs the 512 x 256 file: measured
            # relative L2 difference 0.018; the opposite sign or no rotation gives 1.4
            err = np.linalg.norm(baked - want) / np.linalg.norm(want)
            assert err < 0.05, (vector_type, err)
        finally:
            bpy.data.worlds.remove(world)


def test_mapping_without_generated_coordinates_is_baked(addon, settings):
    # an unlinked Mapping input is the constant (0, 0, 0): the World is one flat
    # colour, which only the bake sees; reading the image directly would be wrong
    world = _env_world(presets.preset_path("studio"))
    try:
        tree = world.node_tree
        tree.links.remove(tree.nodes["Mapping"].inputs["Vector"].links[0])
        light = bl_world.read_world(world)
        assert light.source == "baked procedural world"
        spread = light.equirect.std(axis=(0, 1)) / light.equirect.mean(axis=(0, 1))
        assert np.all(spread < 1e-3), spread  # flat, up to the EXR's float rounding
    finally:
        bpy.data.worlds.remove(world)


def test_procedural_world_is_baked_and_tracked(addon, settings):
    world = new_node_world("relight_sky")
    tree = world.node_tree
    background = next(n for n in tree.nodes if n.type == "BACKGROUND")
    sky = tree.nodes.new("ShaderNodeTexSky")
    tree.links.new(sky.outputs["Color"], background.inputs["Color"])
    try:
        light = bl_world.read_world(world)
        assert light.source == "baked procedural world"
        assert light.equirect.shape == (64, 128, 3) and np.all(np.isfinite(light.equirect))
        # the sky is above the horizon: the upper half is brighter than the lower
        assert light.equirect[:32].mean() > light.equirect[32:].mean()
        key = bl_world.fingerprint(world)
        assert bl_world.fingerprint(world) == key
        sky.sun_elevation = 0.1
        assert bl_world.fingerprint(world) != key
    finally:
        bpy.data.worlds.remove(world)


def _count_bakes(monkeypatch) -> list:
    """Counts Cycles bakes; each also delivers the depsgraph update the bake's
    render causes in Blender (it must not start a second bake)."""
    import types

    bakes, real = [], bl_world._bake
    updated = types.SimpleNamespace(id_type_updated=lambda kind: kind == "WORLD")

    def counting(world, width):
        bakes.append(world.name)
        bl_dials.on_depsgraph_update(bpy.context.scene, updated)  # sent while the bake renders
        return real(world, width)

    monkeypatch.setattr(bl_world, "_bake", counting)
    return bakes


def test_a_world_texture_without_an_image_is_refused_not_baked_magenta(addon, settings, monkeypatch, tmp_path):
    bakes = _count_bakes(monkeypatch)
    world = _env_world(presets.preset_path("studio"))
    scene = bpy.context.scene
    old = scene.world
    try:
        scene.world = world
        settings.light_kind = "WORLD"
        env = next(n for n in world.node_tree.nodes if n.type == "TEX_ENVIRONMENT")
        env.image = None  # Blender renders this magenta
        expect_error("The World's texture node 'Environment Texture' has no image, which Blender shows as magenta",
               image_name=addon["photo"])
        # an image whose file is gone is magenta too
        write_person_png(tmp_path / "sky.png")
        env.image = bpy.data.images.load(str(tmp_path / "sky.png"))
        (tmp_path / "sky.png").unlink()
        expect_error("The World's image 'sky.png' cannot be read (is its file missing?)", image_name=addon["photo"])
        assert bakes == []
    finally:
        scene.world = old
        bpy.data.worlds.remove(world)
        if "sky.png" in bpy.data.images:
            bpy.data.images.remove(bpy.data.images["sky.png"])


def test_one_bake_per_world_change_cached_by_its_node_state(addon, settings, monkeypatch):
    import types

    bakes = _count_bakes(monkeypatch)
    state.WORLDS.clear()
    world = new_node_world("relight_flat_world")  # the default World: a Background colour, baked
    background = next(n for n in world.node_tree.nodes if n.type == "BACKGROUND")
    background.inputs["Color"].default_value = (0.8, 0.6, 0.4, 1.0)
    scene = bpy.context.scene
    old = scene.world
    updated = types.SimpleNamespace(id_type_updated=lambda kind: kind == "WORLD")
    try:
        scene.world = world
        name = addon["photo"]
        assert relight(name) == {"FINISHED"}  # under a preset
        settings.light_kind = "WORLD"          # a dial: relit live from the World, one bake
        assert len(bakes) == 1
        assert relight(name) == {"FINISHED"}   # the same World: its cached light
        assert len(bakes) == 1
        first = pixels(f"{name}.relit").copy()
        settings.rotation = math.radians(40.0)   # dials move the light, not the World: no bake
        settings.exposure = 0.5
        assert len(bakes) == 1
        assert np.abs(pixels(f"{name}.relit") - first).max() > 1e-3
        background.inputs["Color"].default_value = (0.2, 0.4, 0.9, 1.0)  # an edit of the World: one bake
        bl_dials.on_depsgraph_update(scene, updated)
        assert len(bakes) == 2
        bl_dials.on_depsgraph_update(scene, updated)  # more updates, same node state: none
        world.name = "relight_flat_world_renamed"   # the name is not part of the light
        settings.rotation = math.radians(10.0)
        assert len(bakes) == 2
        background.inputs["Color"].default_value = (0.8, 0.6, 0.4, 1.0)  # back to a state seen before
        bl_dials.on_depsgraph_update(scene, updated)
        assert len(bakes) == 2
    finally:
        scene.world = old
        bpy.data.worlds.remove(world)

