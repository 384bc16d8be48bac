"""Photo Light -> World: the light the network estimated in the photo as a key lamp and the World.

The light is split (relight.lighting.key_light) into a key light, made a Sun lamp (an area
lamp when it is wide; photo_light.lamp_setup) with its shadow on, and a smooth
World for the rest; with `lamp_free` the whole light is one map (relight.lighting.light_map)
and a key lamp made before is removed. The map (photo_light.write_light_map, >= 0,
Blender's equirect mapping) is written as a float32 EXR, loaded and packed into the
.blend, so it survives save and reopen with no file beside it, and feeds an
Environment Texture (default mapping: the photo camera's frame) into a
Background of strength 1. The World and its map are tagged with the photo's id
like the add-on's outputs (bl_images.OUTPUT_OF), so pressing again after a new
Relight updates them in place and a renamed photo keeps them. Nothing here
reads the photo's pixels: the light is already in the session.
"""

from __future__ import annotations

import os
import tempfile
import time

import bpy
from bpy.props import BoolProperty, StringProperty

from . import bl_images
from ..logic import photo_light, pixel_buffers
from ..worker import state
from .bl_session import set_status, source_image, tell

WORLD = "light"   # the World's and its map image's tag (bl_images.OUTPUT_LAYER)
KEY = "key"       # the key lamp's tag (its object and its light datablock)


def photo_and_session(context, image_name: str = ""):
    """(photo, session) whose light the World takes; ValueError in the artist's words when the
    photo was not relit, is still being restored, or changed since it was relit."""
    photo = source_image(context, image_name)
    session = state.SESSIONS.get(bl_images.photo_id(photo))
    if session is None:
        raise ValueError(f"Relight '{photo.name}' first: its light is estimated when it is relit.")
    if session.photo_missing:  # reopened without its photo, or with another one: waiting will not help
        raise ValueError(f"{session.photo_missing} To use its light, {session.advice}")
    if session.provisional:
        raise ValueError(f"'{photo.name}' is still being read after opening the file: try again in a moment.")
    now = bl_images.photo_stamp(photo)
    # a session restored from a saved file had its pixels checked by the restore: its stamp starts now
    relit = session.extras.setdefault("stamp", now)
    height, width = pixel_buffers.stored_size(session.photo.shape[:2], session.orientation)  # as Blender shows it
    if now != relit or (photo.has_data and tuple(photo.size) != (width, height)):
        raise ValueError(f"The photo '{photo.name}' changed since it was relit: press Relight.")
    return photo, session


def tagged(collection, photo_id: str, what: str):
    """The datablock of `collection` made for photo `photo_id` as `what`, or None."""
    for block in collection:
        if block.get(bl_images.OUTPUT_OF) == photo_id and block.get(bl_images.OUTPUT_LAYER) == what:
            return block
    return None


def tag(block, collection, photo, what: str) -> None:
    """Mark `block` as photo's `what` and give it the name '<photo>.<what>' when that is free."""
    block[bl_images.OUTPUT_OF] = bl_images.photo_id(photo)
    block[bl_images.OUTPUT_LAYER] = what
    name = photo_light.datablock_name(photo.name, what)
    if block.name != name and collection.get(name) is None:
        block.name = name


def _map_image(photo, session, lamp_free: bool = False):
    """(The World map as a packed float image, replacing the one made before for this photo; the
    key light or None)."""
    old = bl_images.output_by_tag(session.photo_id, WORLD)
    with tempfile.TemporaryDirectory(prefix="relight_light_") as folder:
        path = os.path.join(folder, "light.exr")
        _, key = photo_light.write_light_map(session.decomposition.light, path, lamp_free=lamp_free)
        image = bpy.data.images.load(path, check_existing=False)
        image.pack()  # the EXR's bytes go into the .blend: lossless float32
    if old is not None:
        bpy.data.images.remove(old)
    tag(image, bpy.data.images, photo, WORLD)
    # where Image > Unpack writes it: beside the .blend, named after the photo
    image.filepath_raw = "//" + bpy.path.clean_name(image.name) + ".exr"
    image.colorspace_settings.name = bl_images.LINEAR
    return image, key


def make_world(scene, photo, session, lamp_free: bool = False):
    """Create or update the photo's World (its map, strength 1) and make it the scene's; with the key
    light, create or update its lamp (make_key_lamp), else remove the one made before. Returns the World."""
    image, key = _map_image(photo, session, lamp_free)
    if key is None or not key.strength > 0:  # no key (lamp_free), or a light without a lobe: the World alone
        remove_key_lamp(session.photo_id)
    else:
        make_key_lamp(scene, photo, session, key)
    world = tagged(bpy.data.worlds, session.photo_id, WORLD)
    if world is None:
        world = bpy.data.worlds.new(photo_light.datablock_name(photo.name, WORLD))
    tag(world, bpy.data.worlds, photo, WORLD)
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True  # always on from 5.0 (and deprecated there)
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    texture = nodes.new("ShaderNodeTexEnvironment")  # default mapping: no Vector input
    texture.image = image
    texture.interpolation = "Linear"  # between texels >= 0: still >= 0
    texture.projection = "EQUIRECTANGULAR"
    texture.location = (-300.0, 0.0)
    background = nodes.new("ShaderNodeBackground")
    background.inputs["Strength"].default_value = 1.0
    output = nodes.new("ShaderNodeOutputWorld")
    output.location = (250.0, 0.0)
    links.new(texture.outputs["Color"], background.inputs["Color"])
    links.new(background.outputs["Background"], output.inputs["Surface"])
    cycles = getattr(world, "cycles", None)  # absent when the Cycles add-on is disabled
    if cycles is not None:
        # the map is smooth: an importance map of twice its width (Cycles' automatic one is 4096 wide
        # and takes seconds to build, docs/benchmarks/farm_render.md)
        cycles.sampling_method = "MANUAL"
        cycles.sample_map_resolution = 2 * image.size[0]
    scene.world = world
    return world


def remove_key_lamp(photo_id: str) -> None:
    """Remove the key lamp made for the photo (object and light), if any."""
    obj = tagged(bpy.data.objects, photo_id, KEY)
    if obj is not None:
        data = obj.data
        bpy.data.objects.remove(obj)
        if data is not None and data.users == 0:
            bpy.data.lights.remove(data)


def make_key_lamp(scene, photo, session, key):
    """Create or update, in place, the photo's key lamp (photo_light.lamp_setup of `key`): a Sun, or
    a disk area lamp aimed at the person, its shadow on, linked into the scene."""
    import mathutils

    setup = photo_light.lamp_setup(key)
    obj = tagged(bpy.data.objects, session.photo_id, KEY)
    if obj is None or obj.type != "LIGHT":
        data = bpy.data.lights.new(photo_light.datablock_name(photo.name, KEY), setup.kind)
        obj = bpy.data.objects.new(data.name, data)
    data = obj.data
    if data.type != setup.kind:
        data.type = setup.kind  # Sun <-> area in place: the same datablocks
        data = obj.data
    tag(obj, bpy.data.objects, photo, KEY)
    tag(data, bpy.data.lights, photo, KEY)
    if scene.objects.get(obj.name) is None:
        scene.collection.objects.link(obj)
    obj.location = setup.location
    obj.rotation_mode = "QUATERNION"
    obj.rotation_quaternion = mathutils.Vector(setup.direction).to_track_quat("Z", "Y")  # shines along -Z
    obj.scale = (1.0, 1.0, 1.0)
    data.color = setup.colour
    data.energy = setup.energy
    data.use_shadow = True
    for name, value in (("exposure", 0.0), ("normalize", True)):  # Blender 4.3+: the plain units
        if hasattr(data, name):
            setattr(data, name, value)
    if setup.kind == "SUN":
        data.angle = setup.angle
    else:
        data.shape, data.size = "DISK", setup.size
        if hasattr(data, "spread"):
            data.spread = 3.141592653589793  # a Lambertian emitter, as photo_light assumes
    return obj


class RelitPhotoOperator:
    """What the operators on a relit photo share (Photo Light -> World, Compositing Setup): the
    photo they take, and running their step(context, photo, session) -> message with its outcome
    or refusal reported (on the panel's status line too)."""

    image_name: StringProperty(name="Image", default="", options={"SKIP_SAVE"},
                               description="Relit photo (default: the Image Editor's image)")

    def step(self, context, photo, session) -> str:
        raise NotImplementedError

    def execute(self, context):
        start = time.perf_counter()
        try:
            photo, session = photo_and_session(context, self.image_name)
            message = self.step(context, photo, session)
        except ValueError as exc:
            return tell(self, context, str(exc))
        except OSError as exc:  # the temporary map file (a full disk)
            return tell(self, context, f"Cannot write the light map: {exc.strerror or exc}.")
        message = f"{message} ({time.perf_counter() - start:.2f} s)"
        self.report({"INFO"}, message)
        set_status(context, message)
        return {"FINISHED"}


class RELIGHT_PHOTO_OT_light_to_world(bpy.types.Operator, RelitPhotoOperator):
    """Make the light estimated in the relit photo the scene's World (an Environment Texture kept in the
    .blend), so that CG objects are lit like the person"""

    bl_idname = "relight_photo.light_to_world"
    bl_label = "Photo Light -> World"
    bl_options = {"REGISTER", "UNDO"}

    lamp_free: BoolProperty(name="No Key Lamp", default=False, options={"SKIP_SAVE"},
                            description="The whole light as one World map, without a key lamp")

    def step(self, context, photo, session) -> str:
        world = make_world(context.scene, photo, session, self.lamp_free)
        lamp = tagged(bpy.data.objects, session.photo_id, KEY)
        if lamp is None:
            return f"The World '{world.name}' is now the light of '{photo.name}', strength 1"
        kind = "Sun" if lamp.data.type == "SUN" else "area lamp"
        return (f"The {kind} '{lamp.name}' and the World '{world.name}' are now the light of '{photo.name}'")


CLASSES = (RELIGHT_PHOTO_OT_light_to_world,)


register, unregister = bpy.utils.register_classes_factory(CLASSES)
