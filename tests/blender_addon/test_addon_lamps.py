"""Relight Photo add-on: the key lamp of Photo Light -> World, and the scene's lamps in the World light.

Photo Light -> World splits the session's light (relight.lighting.key_light) into a Sun (an area lamp when
it is wide) with the key's direction, colour, strength and angle, and a smooth World; pressing again
updates the same lamp; it survives save and reopen; `lamp_free` keeps the single map. The World
light source adds the scene's lamps projected to SH at the person (light_sources.with_lamps), and a
lamp moved, changed, added or removed relights through the depsgraph handler, as a World edit does.
Cycles checks the lamps' units (relight.lighting.lamps) on a Lambertian sphere."""

from __future__ import annotations

import math
import types

import numpy as np
import pytest

import bpy

from blender_addon.blender import bl_dials, bl_world
from blender_addon.logic import light_sources, photo_light
from cycles_support import SPHERE_CENTRE, lambert_sphere, photo_camera, render_with_normals, sphere_pixels
from relight.lighting import key_light as kl
from relight.lighting import lamps as rl
from relight.network import prt
from relight.lighting import sh_projection
from relight.files.exr import write_exr
from relight.lighting.light import SHLight
from relight.lighting.light_map import light_map
from addon_support import new_node_world, photo_session, pixels, relit_photo, world_map_pixels

ORDER = 4
TIGHT = 1e-5   # float32 relighting of values <= ~4 (as test_addon_blender)
FLOAT32 = 2e-6  # a lamp's settings are float32 in Blender


def sun_and_ambient(direction, rgb, half_angle, ambient):
    L = kl.lobe_coeffs(direction, half_angle, ORDER)[:, None] * np.asarray(rgb, float)[None, :]
    L[0] += 2.0 * math.sqrt(math.pi) * np.asarray(ambient, float)
    return L


def key_object(name):
    return bpy.data.objects.get(f"{name}.key")


def shines_along(obj) -> np.ndarray:
    """The lamp's -Z axis in world axes: where its light goes."""
    return -np.array(obj.matrix_world.to_3x3().col[2])


def scene_light(order=ORDER):
    return rl.lamps_coeffs(bl_world.scene_lamps(bpy.context.scene), photo_light.PERSON_POSITION, order)


# ------------------------------------------------------------------ Photo Light -> World: the key lamp

def test_photo_light_makes_a_sun_with_the_key_lights_direction_colour_strength_and_angle(addon, model):
    name = relit_photo(model, addon)
    direction = kl.direction_from_angles(60.0, 35.0)
    light = sun_and_ambient(direction, (3.0, 2.5, 2.0), math.radians(5.0), (0.1, 0.1, 0.12))
    photo_session(name).decomposition.light = light  # as if the network had estimated it
    assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}
    split = kl.split_light(light, photo_light.MAP_WIDTH)
    lamp = key_object(name)
    assert lamp is not None and lamp.type == "LIGHT" and lamp.data.type == "SUN"
    assert bpy.context.scene.objects.get(lamp.name) is not None and lamp.data.use_shadow
    np.testing.assert_allclose(shines_along(lamp), -direction, atol=1e-6)
    np.testing.assert_allclose(tuple(lamp.data.color), np.array([3.0, 2.5, 2.0]) / 3.0, rtol=FLOAT32)
    assert lamp.data.energy == pytest.approx(split.key.blender_strength, rel=FLOAT32)
    assert lamp.data.energy == pytest.approx(3.0 * (1 + math.cos(math.radians(5.0))) / 2, rel=1e-5)
    assert lamp.data.angle == pytest.approx(math.radians(10.0), rel=1e-5)
    np.testing.assert_array_equal(world_map_pixels(bpy.context.scene.world), split.pixels)
    # the lamp, read back as the add-on's World light reads lamps, is the key light at the person
    np.testing.assert_allclose(scene_light(), kl.key_coeffs(split.key, ORDER), rtol=1e-5, atol=1e-6)

    # a new estimate, a wide key: the same lamp becomes a disk area lamp aimed at the person
    wide = sun_and_ambient(kl.direction_from_angles(-30.0, 50.0), (2.0, 2.0, 2.0), math.radians(60.0),
                           (0.05, 0.05, 0.05))
    photo_session(name).decomposition.light = wide
    assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}
    assert key_object(name) == lamp and lamp.data.type == "AREA" and lamp.data.shape == "DISK"
    assert len([o for o in bpy.data.objects if o.type == "LIGHT"]) == 1 and len(bpy.data.lights) == 1
    toward = kl.direction_from_angles(-30.0, 50.0)
    np.testing.assert_allclose(np.array(lamp.location),
                               np.array(photo_light.PERSON_POSITION) + photo_light.AREA_DISTANCE * toward, atol=1e-5)
    np.testing.assert_allclose(shines_along(lamp), -toward, atol=1e-6)
    key = kl.fit_key(wide)
    # the disk seen from the person is the key's cone (half-angle 60 <= 75): the same SH
    np.testing.assert_allclose(scene_light(), kl.key_coeffs(key, ORDER), rtol=1e-5, atol=1e-6)
    status = bpy.context.window_manager.relight_photo_status
    assert status.message.startswith(f"The area lamp '{name}.key' and the World '{name}.light'")

    # no key lamp: the single map, and the lamp made before is gone
    assert bpy.ops.relight_photo.light_to_world(image_name=name, lamp_free=True) == {"FINISHED"}
    assert key_object(name) is None and not bpy.data.lights
    np.testing.assert_array_equal(world_map_pixels(bpy.context.scene.world), light_map(wide, photo_light.MAP_WIDTH).pixels)


def test_a_light_without_a_lobe_gets_no_lamp(addon, model):
    name = relit_photo(model, addon)
    photo_session(name).decomposition.light = sun_and_ambient([0.0, 0.0, 1.0], (1.0, 1.0, 1.0), 0.0, (0.2, 0.2, 0.2))
    assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}
    assert key_object(name) is not None
    uniform = np.zeros((25, 3))
    uniform[0] = 1.0  # the same radiance from everywhere: nothing to make a key of
    photo_session(name).decomposition.light = uniform
    assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}
    assert key_object(name) is None and not bpy.data.lights
    np.testing.assert_allclose(world_map_pixels(bpy.context.scene.world), 0.5 / math.sqrt(math.pi), rtol=1e-5)


def test_the_key_lamp_survives_save_and_reopen_and_is_updated_in_place(addon, model):
    name = relit_photo(model, addon)
    photo_session(name).decomposition.light = sun_and_ambient(kl.direction_from_angles(100.0, 20.0), (2.0, 1.0, 1.0),
                                                         0.0, (0.1, 0.1, 0.1))
    assert bpy.ops.relight_photo.compositing_setup(image_name=name) == {"FINISHED"}  # makes the World too
    lamp = key_object(name)
    energy, along = lamp.data.energy, shines_along(lamp)
    blend = addon / "lamp.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(blend)) == {"FINISHED"}
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    lamp = key_object(name)
    assert lamp is not None and lamp.data.type == "SUN" and lamp.data.energy == energy
    np.testing.assert_allclose(shines_along(lamp), along, atol=1e-6)
    assert bpy.context.scene.objects.get(lamp.name) is not None
    # pressed again after reopening (Relight first: the session comes back from the saved file)
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    photo_session(name).decomposition.light = sun_and_ambient(kl.direction_from_angles(-100.0, 40.0), (1.0, 1.0, 2.0),
                                                         0.0, (0.1, 0.1, 0.1))
    assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}
    assert len([o for o in bpy.data.objects if o.type == "LIGHT"]) == 1
    np.testing.assert_allclose(shines_along(key_object(name)), -kl.direction_from_angles(-100.0, 40.0), atol=1e-6)


# ------------------------------------------------------------------ lamps in: the World light source

def _flat_world(folder, value=0.3):
    """An Environment Texture World of a constant map (read directly, no bake)."""
    path = folder / "flat.exr"
    write_exr(path, {c: np.full((32, 64), value, np.float32) for c in "RGB"})
    world = new_node_world("flat")
    nodes, links = world.node_tree.nodes, world.node_tree.links
    texture = nodes.new("ShaderNodeTexEnvironment")
    texture.image = bpy.data.images.load(str(path))
    texture.image.colorspace_settings.name = "Linear Rec.709" if bpy.app.version >= (4, 0, 0) else "Linear"
    links.new(texture.outputs["Color"], nodes["Background"].inputs["Color"])
    bpy.context.scene.world = world
    return world, path


def _lamp(kind, location, energy, **settings):
    data = bpy.data.lights.new(f"user {kind}", kind)
    data.energy = energy
    for key, value in settings.items():
        setattr(data, key, value)
    obj = bpy.data.objects.new(data.name, data)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)
    return obj


def _update(*blocks):
    """The depsgraph update Blender sends after `blocks` changed (headless bpy sends none), once the
    depsgraph is evaluated (matrix_world follows location)."""
    bpy.context.view_layer.update()
    kinds = {"OBJECT" if isinstance(b, bpy.types.Object) else "LIGHT" for b in blocks}
    return types.SimpleNamespace(id_type_updated=lambda kind: kind in kinds,
                                 updates=[types.SimpleNamespace(id=b) for b in blocks])


def test_the_world_light_takes_the_scenes_lamps_and_a_moved_lamp_relights(addon, model, monkeypatch):
    name = relit_photo(model, addon)
    scene = bpy.context.scene
    settings = scene.relight_photo
    _, path = _flat_world(addon)
    world_sh = sh_projection.project_equirect(np.full((32, 64, 3), 0.3, np.float32), ORDER)
    lamp = _lamp("POINT", (2.0, 1.0, 2.5), 300.0, shadow_soft_size=0.25)
    settings.light_kind = "WORLD"
    d = photo_session(name).decomposition

    def expected(rotation_deg=0.0):
        return d.relight(SHLight(world_sh + scene_light(), 0.8).at(rotation_deg))

    def relit():
        return pixels(f"{name}.relit")[..., :3]

    np.testing.assert_allclose(relit(), expected(), atol=TIGHT)
    before = relit().copy()
    # the artist moves the lamp to the other side: Blender sends a depsgraph update
    lamp.location = (-2.0, 1.0, 2.5)
    bl_dials.on_depsgraph_update(scene, _update(lamp))
    np.testing.assert_allclose(relit(), expected(), atol=TIGHT)
    assert np.abs(relit() - before).max() > 0.01
    # the dial turns World and lamps together
    settings.rotation = math.radians(90.0)
    np.testing.assert_allclose(relit(), expected(90.0), atol=TIGHT)
    settings.rotation = 0.0

    calls = []
    monkeypatch.setattr(bl_dials, "schedule_refresh", lambda context: calls.append(1))
    cube = bpy.data.objects.new("cube", bpy.data.meshes.new("cube"))
    scene.collection.objects.link(cube)
    cube.location = (0.0, 5.0, 0.0)
    bl_dials.on_depsgraph_update(scene, _update(cube))    # not a lamp: nothing to do
    bl_dials.on_depsgraph_update(scene, _update(lamp))    # a lamp update that changed nothing
    assert calls == []
    lamp.data.energy = 600.0                              # the lamp's power: one relight
    bl_dials.on_depsgraph_update(scene, _update(lamp.data))
    lamp.hide_render = True                               # hidden from the render: one more
    bl_dials.on_depsgraph_update(scene, _update(lamp))
    assert calls == [1, 1]
    monkeypatch.undo()

    # lamps alone light the person when there is no World, and no light at all is refused
    lamp.hide_render = False
    scene.world = None
    bl_dials.on_depsgraph_update(scene, _update(lamp))
    np.testing.assert_allclose(relit(), d.relight(SHLight(scene_light(), 0.8).at(0.0)), atol=TIGHT)
    lamp.data.energy = 0.0
    with pytest.raises(RuntimeError, match="The scene has no World to take the light from"):
        bpy.ops.relight_photo.relight(image_name=name, synchronous=True)


def test_a_black_world_with_lamps_is_lit_by_the_lamps(addon, model):
    name = relit_photo(model, addon)
    scene = bpy.context.scene
    world, _ = _flat_world(addon, value=0.0)
    scene.relight_photo.light_kind = "WORLD"
    with pytest.raises(RuntimeError, match="The World is black"):
        bpy.ops.relight_photo.relight(image_name=name, synchronous=True)
    _lamp("SUN", (0.0, 0.0, 5.0), 3.0, angle=math.radians(20.0))
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    d = photo_session(name).decomposition
    np.testing.assert_allclose(pixels(f"{name}.relit")[..., :3], d.relight(SHLight(scene_light(), 0.8).at(0.0)),
                               atol=TIGHT)
    with pytest.raises(ValueError, match="give no light"):
        light_sources.with_lamps(None, 0.0, (), ORDER)


# ------------------------------------------------------------------ the lamps' units, in Cycles

ALBEDO = 0.8
C = np.array(SPHERE_CENTRE)
LAMPS = {  # kind, location, energy, settings; each lights the camera's half of the sphere
    "sun": ("SUN", (0.0, 0.0, 0.0), 2.0, dict(angle=math.radians(30.0))),
    "point": ("POINT", tuple(C + [-3.0, -4.0, 2.0]), 400.0, dict(shadow_soft_size=0.5)),
    "spot": ("SPOT", tuple(C + [3.0, -4.0, 1.0]), 400.0, dict(spot_size=math.radians(50.0), spot_blend=0.2,
                                                                 shadow_soft_size=0.1)),
    "area": ("AREA", tuple(C + [0.0, -4.0, 3.0]), 300.0, dict(size=1.0, shape="DISK")),
}


@pytest.fixture(scope="module")
def lamp_renders(tmp_path_factory):
    import mathutils

    folder = tmp_path_factory.mktemp("lamps_cycles")
    out = {}
    try:
        for name, (kind, location, energy, settings) in LAMPS.items():
            bpy.ops.wm.read_homefile(use_empty=True)
            scene = bpy.context.scene
            scene.world = new_node_world("black")
            scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0
            lambert_sphere(scene, ALBEDO)
            photo_camera(scene)
            obj = _lamp(kind, location, energy, **settings)
            target = C + [0.3, 0.0, -0.2] if kind == "SPOT" else C  # the spot's blend crosses the sphere
            aim = mathutils.Vector(tuple(target - np.array(location))) if kind != "SUN" else \
                mathutils.Vector((0.4, 1.0, -0.6))
            obj.rotation_euler = aim.to_track_quat("-Z", "Y").to_euler()
            bpy.context.view_layer.update()
            lamp = bl_world.scene_lamps(scene)[0]
            passes = [render_with_normals(scene, folder / f"{name}{seed}.exr", 32, 64, seed) for seed in (0, 1)]
            out[name] = (lamp, sphere_pixels(*passes))
    finally:
        bpy.ops.wm.read_homefile()
    return out


@pytest.mark.parametrize("name", list(LAMPS))
def test_a_lamp_projected_to_sh_lights_a_sphere_as_cycles_does(lamp_renders, name):
    """Each sphere pixel against the lamp's SH at that pixel's own point (relight.lighting.lamps.lamp_coeffs at
    C + n), to order 16, through the unoccluded Lambert transport (a convex sphere occludes exactly
    its tangent plane, which the clamped cosine is)."""
    lamp, px = lamp_renders[name]
    n = px["n"]
    order = 16
    predicted = np.array([prt.shading(prt.lambert_transport(normal[None], order),
                                      rl.lamp_coeffs(lamp, C + normal, order))[0] for normal in n]) * ALBEDO
    mean = 0.5 * (px["r0"] + px["r1"])
    noise = 0.5 * (px["r0"] - px["r1"])
    scale = np.sqrt(np.mean(predicted ** 2))
    error = float(np.sqrt(np.mean((mean - predicted) ** 2)) / scale)
    noise_rms = float(np.sqrt(np.mean(noise ** 2)) / scale)
    print(f"{name}: relative RMS {error:.4f}, noise {noise_rms:.4f}")
    # what is left beyond the noise: a spot's blend (Cycles' smoothstep on its own scaled axes) and
    # the cone model of a sphere or disk lamp near the horizon; measured 0.9 - 2.6 %
    assert error < math.hypot(1.5 * noise_rms, 0.03), (error, noise_rms)
    # teeth: twice the power, or the lamp on the other side, is far off
    assert float(np.sqrt(np.mean((mean - 2 * predicted) ** 2)) / scale) > 0.5
