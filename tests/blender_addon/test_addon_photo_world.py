"""Relight Photo add-on: Photo Light -> World and Compositing Setup under headless bpy.

The World holds the map of the light the network estimated (the smooth World of
relight.lighting.key_light.split_light of the session's light, packed into the .blend), the compositing setup puts a
render over the photo with a shadow-catcher floor, both survive save and
reopen, and the buttons refuse in the artist's words when nothing was relit or
the photo changed since."""

from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

import bpy

from blender_addon.blender import bl_images
from blender_addon.logic import photo_light
from relight.files import exr
from relight.lighting import sh
from relight.lighting.light import directional_light
from relight.lighting.key_light import split_light
from addon_support import H, W, cube, draft_photo, photo_session, relit_photo, world_map_pixels


def _refusal(operator, name) -> str:
    """The one error message an operator gives (bpy raises it as RuntimeError in background mode)."""
    with pytest.raises(RuntimeError) as caught:
        operator(image_name=name)
    lines = str(caught.value).strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("Error: ")
    status = bpy.context.window_manager.relight_photo_status
    assert status.is_error and status.message == lines[0][len("Error: "):]
    return status.message


def check_world(name: str) -> None:
    """The scene's World is the photo's, made of the map of the session's light."""
    world = bpy.context.scene.world
    assert world is not None and world.name == f"{name}.light"
    nodes = world.node_tree.nodes
    texture = next(n for n in nodes if n.type == "TEX_ENVIRONMENT")
    background = next(n for n in nodes if n.type == "BACKGROUND")
    output = next(n for n in nodes if n.type == "OUTPUT_WORLD")
    assert texture.projection == "EQUIRECTANGULAR" and not texture.inputs["Vector"].is_linked
    assert background.inputs["Strength"].default_value == 1.0
    assert background.inputs["Color"].links[0].from_node == texture
    assert output.inputs["Surface"].links[0].from_node == background
    image = texture.image
    assert image.packed_file is not None and image.name == f"{name}.light"
    assert tuple(image.size) == (photo_light.MAP_WIDTH, photo_light.MAP_WIDTH // 2)
    # the smooth World left after the key light (the key lamp: tests/blender_addon/test_addon_lamps.py)
    expected = split_light(photo_session(name).decomposition.light, photo_light.MAP_WIDTH).pixels
    np.testing.assert_array_equal(world_map_pixels(world), expected)  # a float32 EXR, packed: lossless


def check_compositing(name: str) -> None:
    scene = bpy.context.scene
    camera = scene.camera
    assert camera.name == f"{name}.camera" and camera.type == "CAMERA"
    assert camera.data.lens == photo_light.DEFAULT_LENS_MM  # the test PNG has no EXIF focal length
    assert tuple(camera.rotation_euler) == pytest.approx((math.pi / 2, 0.0, 0.0))
    assert (scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage) == (W, H, 100)
    background = camera.data.background_images[0]
    assert camera.data.show_background_images and background.image == bpy.data.images[name]
    floor = bpy.data.objects[f"{name}.shadow_catcher"]
    assert floor.is_shadow_catcher and scene.objects.get(floor.name) is not None
    assert scene.render.engine == "CYCLES" and scene.render.film_transparent
    assert scene.view_settings.view_transform == "Standard"
    tree = scene.compositing_node_group if hasattr(scene, "compositing_node_group") else scene.node_tree
    over = next(n for n in tree.nodes if n.bl_idname == "CompositorNodeAlphaOver")
    sources = {link.from_node.bl_idname: link.from_node for s in over.inputs for link in s.links}
    scale = sources["CompositorNodeScale"]  # the photo, fitted to the render's size (Resolution %)
    assert scale.inputs["Image"].links[0].from_node.image == bpy.data.images[name]
    assert "CompositorNodeRLayers" in sources
    assert over.outputs["Image"].links  # to the group output (Blender 5) or the Composite node (4)


# ------------------------------------------------------------------ refusals

def test_refuses_when_nothing_was_relit(addon, model):
    name = draft_photo(model, addon)
    for operator in (bpy.ops.relight_photo.light_to_world, bpy.ops.relight_photo.compositing_setup):
        assert _refusal(operator, name) == f"Relight '{name}' first: its light is estimated when it is relit."
    assert bpy.context.scene.world is None and not bpy.data.worlds  # nothing was made


def test_refuses_a_photo_changed_since_it_was_relit(addon, model):
    name = relit_photo(model, addon)
    changed = f"The photo '{name}' changed since it was relit: press Relight."
    from PIL import Image

    codes = np.asarray(Image.open(addon / "person.png")).copy()
    codes[:10] = 255
    Image.fromarray(codes).save(addon / "person.png")  # a new file behind the photo
    bpy.data.images[name].reload()
    assert _refusal(bpy.ops.relight_photo.light_to_world, name) == changed
    assert _refusal(bpy.ops.relight_photo.compositing_setup, name) == changed
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}

    photo = bpy.data.images[name]  # painted on in Blender (not saved)
    flat = np.empty(W * H * 4, np.float32)
    photo.pixels.foreach_get(flat)
    photo.pixels.foreach_set(1.0 - flat)
    assert photo.is_dirty
    assert _refusal(bpy.ops.relight_photo.light_to_world, name) == changed


# ------------------------------------------------------------------ the World

def test_the_world_holds_the_map_of_the_estimated_light(addon, model):
    name = relit_photo(model, addon)
    assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}
    check_world(name)
    status = bpy.context.window_manager.relight_photo_status
    key = split_light(photo_session(name).decomposition.light, photo_light.MAP_WIDTH).key
    # the random-weight model's light may have no lobe: then no key lamp (tests/blender_addon/test_addon_lamps.py)
    assert not status.is_error and status.message.startswith(
        f"The Sun '{name}.key' and the World '{name}.light' are now the light of '{name}'" if key.strength > 0 else
        f"The World '{name}.light' is now the light of '{name}'")

    # a new Relight, a new light: pressing again updates the same World and replaces its map
    world = bpy.context.scene.world
    photo_session(name).decomposition.light = directional_light(-90.0, 4)  # as a relight with another estimate
    assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}
    assert bpy.context.scene.world == world and len(bpy.data.worlds) == 1
    check_world(name)
    maps = [i for i in bpy.data.images if i.get(bl_images.OUTPUT_OF) == photo_session(name).photo_id
            and i.get(bl_images.OUTPUT_LAYER) == "light"]
    assert len(maps) == 1


def test_extreme_lights_make_a_finite_non_negative_world(addon, model):
    name = relit_photo(model, addon)
    direction = np.array([0.3, -0.5, 0.8]) / np.linalg.norm([0.3, -0.5, 0.8])
    lights = {
        "all energy in one direction": np.outer(sh.sh_basis(direction, 4), [1.0, 1.0, 1.0]),
        "black": np.zeros((25, 3)),
        "very bright": 1e30 * directional_light(-90.0, 4),
    }
    for what, light in lights.items():
        photo_session(name).decomposition.light = light
        assert bpy.ops.relight_photo.light_to_world(image_name=name) == {"FINISHED"}, what
        world_map = world_map_pixels(bpy.context.scene.world)
        assert np.all(np.isfinite(world_map)) and world_map.min() >= 0.0, what
        np.testing.assert_array_equal(world_map, split_light(light, photo_light.MAP_WIDTH).pixels)
    assert world_map.max() > 1e29  # the bright light stayed bright


def test_the_buttons_never_read_the_photos_pixels(addon, model, monkeypatch):
    # what keeps them under a second on a 24 MP photo: the light is in the session already
    name = relit_photo(model, addon)

    def forbidden(*_args, **_kwargs):
        raise AssertionError("the photo's pixels were read")

    monkeypatch.setattr(bl_images, "rgba_pixels", forbidden)
    monkeypatch.setattr(bl_images, "linear_rgb_and_alpha", forbidden)
    monkeypatch.setattr(bl_images, "photo_reader", forbidden)
    assert bpy.ops.relight_photo.compositing_setup(image_name=name) == {"FINISHED"}


def test_compositing_setup_and_world_survive_save_and_reopen(addon, model):
    name = relit_photo(model, addon)
    assert bpy.ops.relight_photo.compositing_setup(image_name=name) == {"FINISHED"}
    check_world(name)
    check_compositing(name)
    expected = world_map_pixels(bpy.context.scene.world).copy()
    blend = addon / "shot.blend"
    assert bpy.ops.wm.save_as_mainfile(filepath=str(blend)) == {"FINISHED"}
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    check_compositing(name)
    world = bpy.context.scene.world
    assert world.name == f"{name}.light"
    np.testing.assert_array_equal(world_map_pixels(world), expected)  # from the .blend itself: packed
    # and pressed again after reopening, the setup is updated, not duplicated
    assert bpy.ops.relight_photo.compositing_setup(image_name=name) == {"FINISHED"}
    check_world(name)
    check_compositing(name)
    assert len(bpy.data.worlds) == 1 and len([o for o in bpy.data.objects if o.type == "CAMERA"]) == 1


def test_compositing_setup_pressed_again_keeps_the_resolution_percentage(addon, model):
    """Issue 48: pressed again it reset Resolution % from 50 to 100 (the artist's quick render)."""
    name = relit_photo(model, addon)
    render = bpy.context.scene.render
    render.resolution_percentage = 30  # before the first press: the setup renders the photo at 100 %
    assert bpy.ops.relight_photo.compositing_setup(image_name=name) == {"FINISHED"}
    assert render.resolution_percentage == 100
    render.resolution_percentage = 50
    render.resolution_x = 7  # the size is the photo's: set again
    assert bpy.ops.relight_photo.compositing_setup(image_name=name) == {"FINISHED"}
    assert (render.resolution_x, render.resolution_y, render.resolution_percentage) == (W, H, 50)


# ------------------------------------------------------------------ a render over the photo



def test_a_cg_object_renders_over_the_photo_and_casts_its_shadow_on_the_floor(addon, model):
    name = relit_photo(model, addon)
    # a light from behind the object (+Y), 35 degrees up, little ambient: the shadow falls toward
    # the camera, on the floor in front of the object
    photo_session(name).decomposition.light = directional_light(180.0, 4, elevation_deg=35.0, ambient=0.1)
    assert bpy.ops.relight_photo.compositing_setup(image_name=name) == {"FINISHED"}
    for what in ("person", "person_shadow"):  # the random network's person is the whole photo, its relief
        bpy.data.objects[f"{name}.{what}"].hide_render = True  # metres deep (tests/blender_addon/test_addon_proxy.py)
    scene = bpy.context.scene
    camera = scene.camera.data
    # a 1 m cube on the floor, 8 m ahead: in the photo camera (f = W * lens / sensor pixels, the
    # horizon on the middle row) its base is at row H/2 + f * 1.5 / 7.5, its sides at W/2 -+ f * 0.5 / 7.5
    cube((0.0, 8.0, 0.5), 1.0)
    f = W * camera.lens / camera.sensor_width
    base = H / 2 + f * photo_light.CAMERA_HEIGHT / 7.5
    half = f * 0.5 / 7.5
    scene.cycles.samples = 32
    scene.cycles.use_denoising = False
    scene.cycles.device = "CPU"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    out = addon / "composite.exr"
    scene.render.filepath = str(out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        bpy.ops.render.render(write_still=True)
    planes = exr.read_exr(out)
    composite = np.stack([planes[c] for c in "RGB"], -1)  # one part: R, G, B, A
    photo = photo_session(name).photo  # the photo, linear, as the add-on decoded it
    rows, cols = np.mgrid[0:H, 0:W] + 0.5
    sky = rows < H / 2 - 2                      # above the horizon: nothing rendered there
    object_ = (np.abs(cols - W / 2) < half - 1) & (rows > base - f / 7.5 + 1) & (rows < base - 1)
    shadow = (np.abs(cols - W / 2) < half - 1) & (rows > base + 1)
    far_floor = (rows > H / 2 + 2) & (np.abs(cols - W / 2) > 3 * half)
    # sRGB decoded by Blender's colour management and by relight.imaging.colour agree to ~1e-4
    np.testing.assert_allclose(composite[sky], photo[sky], atol=2e-3)
    ratio = composite.sum(-1) / photo.sum(-1)
    print(f"composite / photo: shadow {ratio[shadow].mean():.3f} ({shadow.sum()} px), open floor "
          f"{ratio[far_floor].mean():.3f}; sky max |diff| {np.abs(composite[sky] - photo[sky]).max():.2e}")
    assert ratio[shadow].mean() < 0.8, ratio[shadow].mean()          # the cube's shadow darkens the photo
    assert ratio[far_floor].mean() > 0.95, ratio[far_floor].mean()   # the open floor barely does
    assert np.abs(composite[object_] - photo[object_]).mean() > 0.05  # the cube covers the photo
    assert math.isfinite(float(composite.sum()))
