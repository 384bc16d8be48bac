"""The scene's World as an equirectangular radiance map for relighting.

An Environment Texture world (optionally through a Mapping node that only
rotates about Z) is read directly: its image, the Background strength and the
Z rotation. Any other world (Sky Texture, gradients, node mixes) is baked by
rendering a small equirectangular panorama of it with Cycles. The scene's lamps
(scene_lamps) join the World's light as relight.lighting.lamps.Lamp values; lamps_changed
tells a depsgraph update that moved, changed, added or removed one.
"""

from __future__ import annotations

import hashlib
import math
import os
import tempfile
from contextlib import contextmanager
from dataclasses import dataclass

import bpy
import numpy as np

from . import bl_images

BAKE_WIDTH = 128   # 128 x 64 texels: ample for order <= 8 SH (band limit ~ 64 texels)
BAKE_SAMPLES = 16  # the camera sees the world directly: samples only anti-alias


@dataclass
class WorldLight:
    equirect: np.ndarray   # [H, W, 3] linear radiance, Blender's equirect mapping
    rotation_deg: float    # extra rotation of the light about +Z (relight.lighting.sh_rotation.z_rotation)
    source: str            # "environment texture 'name'" or "baked procedural world"
    image_path: str | None = None  # the file on disk behind an environment texture


def _linked_node(socket):
    return socket.links[0].from_node if socket.is_linked else None


def _world_output_background(world):
    """The Background node feeding the active World Output, or None."""
    if world.node_tree is None or (bpy.app.version < (5, 0, 0) and not world.use_nodes):
        return None  # no nodes: the flat world colour, which the bake handles
    outputs = [n for n in world.node_tree.nodes if n.type == "OUTPUT_WORLD"]
    active = [n for n in outputs if n.is_active_output] or outputs
    if not active:
        return None
    node = _linked_node(active[0].inputs["Surface"])
    return node if node is not None and node.type == "BACKGROUND" else None


def _mapping_z_rotation(env_node) -> float | None:
    """Light rotation (degrees) implied by the env texture's Vector input; None when not a pure Z rotation."""
    mapping = _linked_node(env_node.inputs["Vector"])
    if mapping is None:
        return 0.0
    if mapping.type != "MAPPING" or mapping.vector_type not in {"POINT", "VECTOR", "TEXTURE"}:
        return None
    # the Mapping input must be the view direction (Generated); unlinked it is a constant
    source = _linked_node(mapping.inputs["Vector"])
    if source is None or source.type != "TEX_COORD" or \
            mapping.inputs["Vector"].links[0].from_socket.name != "Generated":
        return None
    sockets = {s.name: s for s in mapping.inputs}
    if any(sockets[n].is_linked for n in ("Location", "Rotation", "Scale") if n in sockets):
        return None
    rot = tuple(sockets["Rotation"].default_value)
    scale = tuple(sockets["Scale"].default_value)
    location = tuple(sockets["Location"].default_value) if "Location" in sockets else (0, 0, 0)
    if abs(rot[0]) > 1e-6 or abs(rot[1]) > 1e-6 or any(abs(s - 1) > 1e-6 for s in scale):
        return None
    if mapping.vector_type != "VECTOR" and any(abs(v) > 1e-6 for v in location):
        return None  # a translation (POINT/TEXTURE) is no rotation of the light
    # POINT/VECTOR look the texture up at Rz(a) d, which turns the light by -a;
    # TEXTURE applies the inverse transform.
    sign = 1.0 if mapping.vector_type == "TEXTURE" else -1.0
    return sign * math.degrees(rot[2])


def _upstream_nodes(world) -> list:
    """Every node that feeds the active World Output (directly or through others)."""
    tree = world.node_tree
    if tree is None:
        return []
    outputs = [n for n in tree.nodes if n.type == "OUTPUT_WORLD"]
    active = [n for n in outputs if n.is_active_output] or outputs
    seen, todo = {}, list(active[:1])
    while todo:
        node = todo.pop()
        if node.name in seen:
            continue
        seen[node.name] = node
        for socket in node.inputs:
            for link in socket.links:
                if link.is_valid and not link.is_muted:
                    todo.append(link.from_node)
    return list(seen.values())


def check_textures(world) -> None:
    """ValueError naming the first image texture of the World that has no pixels.

    Blender renders a texture node without an image (or with a missing file)
    as magenta; baking it would light the person magenta without a warning.
    """
    for node in _upstream_nodes(world):
        if node.type not in {"TEX_ENVIRONMENT", "TEX_IMAGE"}:
            continue
        label = node.label or node.name
        if node.image is None:
            raise ValueError(f"The World's texture node '{label}' has no image, which Blender shows as "
                             "magenta: open an HDR image in it, or choose another light.")
        if not bl_images.has_pixels(node.image):
            raise ValueError(f"The World's image '{node.image.name}' cannot be read (is its file missing?), "
                             "which Blender shows as magenta: fix its file path, or choose another light.")


def read_world(world) -> WorldLight:
    """The world's light as an equirect map; ValueError when there is no world or a
    texture of it has no pixels."""
    if world is None:
        raise ValueError("The scene has no World to take the light from.")
    check_textures(world)
    background = _world_output_background(world)
    if background is not None and not background.inputs["Strength"].is_linked:
        env = _linked_node(background.inputs["Color"])
        if env is not None and env.type == "TEX_ENVIRONMENT" and env.image is not None \
                and env.projection == "EQUIRECTANGULAR":
            rotation = _mapping_z_rotation(env)
            if rotation is not None:
                rgb, _ = bl_images.linear_rgb_and_alpha(env.image)
                strength = float(background.inputs["Strength"].default_value)
                path = None
                if env.image.source == "FILE" and env.image.packed_file is None:
                    path = bpy.path.abspath(env.image.filepath, library=env.image.library)
                return WorldLight(rgb * strength, rotation,
                                  f"environment texture '{env.image.name}'", path)
    return WorldLight(bake_world(world), 0.0, "baked procedural world")


_baking = 0  # > 0 while bake_world renders: the depsgraph updates it causes are our own


def baking() -> bool:
    return _baking > 0


@contextmanager
def _bake_guard():
    global _baking
    _baking += 1
    try:
        yield
    finally:
        _baking -= 1


def bake_world(world, width: int = BAKE_WIDTH) -> np.ndarray:
    """Render `world` as a width x width/2 equirect map with Cycles; [H, W, 3] linear."""
    with _bake_guard():
        return _bake(world, width)


def _bake(world, width: int) -> np.ndarray:
    # a copy, so the user's world is never touched: importance sampling off
    # (the camera sees the world directly; building its map costs seconds)
    world = world.copy()
    world.cycles.sampling_method = "NONE"
    scene = bpy.data.scenes.new("relight_photo_world_bake")
    camera_data = bpy.data.cameras.new("relight_photo_world_bake")
    camera = bpy.data.objects.new("relight_photo_world_bake", camera_data)
    out_dir = tempfile.mkdtemp(prefix="relight_world_")
    out_path = os.path.join(out_dir, "world.exr")
    try:
        scene.world = world
        scene.collection.objects.link(camera)
        scene.camera = camera
        camera_data.type = "PANO"
        camera_data.panorama_type = "EQUIRECTANGULAR"
        # look along +X with +Z up: the centre of the panorama is +X, as in
        # Blender's Environment Texture mapping
        camera.rotation_euler = (math.pi / 2, 0.0, -math.pi / 2)
        render = scene.render
        render.engine = "CYCLES"
        render.resolution_x, render.resolution_y = width, width // 2
        render.resolution_percentage = 100
        render.film_transparent = False
        render.filter_size = 0.5  # keep texels close to point samples of the world
        render.image_settings.file_format = "OPEN_EXR"
        render.image_settings.color_depth = "32"
        render.filepath = out_path
        scene.cycles.samples = BAKE_SAMPLES
        scene.cycles.use_denoising = False
        scene.cycles.device = "CPU"
        bpy.ops.render.render(write_still=True, scene=scene.name)
        image = bpy.data.images.load(out_path, check_existing=False)
        try:
            image.colorspace_settings.name = bl_images.LINEAR
            rgb, _ = bl_images.linear_rgb_and_alpha(image)
        finally:
            bpy.data.images.remove(image)
        return rgb
    finally:
        bpy.data.objects.remove(camera)
        bpy.data.cameras.remove(camera_data)
        bpy.data.scenes.remove(scene)
        bpy.data.worlds.remove(world)
        for name in os.listdir(out_dir):
            os.remove(os.path.join(out_dir, name))
        os.rmdir(out_dir)


def _value(v):
    if isinstance(v, (int, float, str, bool)) or v is None:
        return v
    if isinstance(v, bpy.types.Image):
        return ("IMAGE", v.name, v.filepath, v.source, tuple(v.size))
    if isinstance(v, bpy.types.ID):
        return ("ID", v.name)
    try:
        return tuple(_value(x) for x in v)
    except TypeError:
        return repr(v)


def fingerprint(world) -> str:
    """A hash of everything in the world's node tree that can change its light (node
    settings, socket values, links, the images used), so a cached light is reused
    exactly while it is equal. The World's name is not part of it: renaming or
    duplicating a World does not bake again."""
    return hashlib.sha256(repr(_node_state(world)).encode()).hexdigest()


def _node_state(world) -> tuple:
    if world is None:
        return ()
    tree = world.node_tree
    if tree is None or (bpy.app.version < (5, 0, 0) and not world.use_nodes):
        return (_value(world.color),)
    nodes = []
    for node in tree.nodes:
        settings = []
        for prop in node.bl_rna.properties:
            if prop.is_readonly or prop.identifier in {"name", "label", "location", "width", "height",
                                                      "select", "show_options", "show_preview",
                                                      "hide", "mute_preview", "color", "use_custom_color",
                                                      "location_absolute", "warning_propagation"}:
                if prop.identifier != "image":
                    continue
            if prop.type in {"BOOLEAN", "INT", "FLOAT", "STRING", "ENUM", "POINTER"}:
                settings.append((prop.identifier, _value(getattr(node, prop.identifier))))
        inputs = tuple((s.identifier, _value(getattr(s, "default_value", None))) for s in node.inputs)
        nodes.append((node.name, node.bl_idname, tuple(settings), inputs))
    links = tuple(sorted((l.from_node.name, l.from_socket.identifier, l.to_node.name, l.to_socket.identifier)
                         for l in tree.links if l.is_valid and not l.is_muted))
    return tuple(sorted(nodes, key=lambda n: n[0])), links


# ------------------------------------------------------------------ lamps

LAMP_TYPES = {"SUN", "POINT", "SPOT", "AREA"}


def _lamp(obj):
    """The lamp object `obj` as a relight.lighting.lamps.Lamp in world axes (its -Z is where it points)."""
    from relight.lighting.lamps import Lamp

    data = obj.data
    matrix = obj.matrix_world
    axis = matrix.to_3x3() @ _vector((0.0, 0.0, -1.0))
    energy = float(data.energy) * 2.0 ** float(getattr(data, "exposure", 0.0))
    kwargs = {}
    if data.type == "SUN":
        kwargs["angle"] = float(data.angle)
    elif data.type in ("POINT", "SPOT"):
        kwargs["radius"] = float(data.shadow_soft_size)
        if data.type == "SPOT":
            kwargs["spot_size"], kwargs["spot_blend"] = float(data.spot_size), float(data.spot_blend)
    else:
        scale = matrix.to_scale()
        size = (float(data.size) * abs(scale[0]), float(data.size_y if data.shape in {"RECTANGLE", "ELLIPSE"}
                                                         else data.size) * abs(scale[1]))
        kwargs["size"], kwargs["shape"] = size, data.shape
        if not getattr(data, "normalize", True):  # Blender 4.3+: Power per square metre of the lamp
            energy *= size[0] * size[1] * (3.141592653589793 / 4.0 if data.shape in {"DISK", "ELLIPSE"} else 1.0)
    rgb = tuple(max(0.0, float(c)) * max(0.0, energy) for c in data.color)
    return Lamp(data.type, rgb, location=tuple(matrix.translation), axis=tuple(axis), **kwargs)


def _vector(v):
    import mathutils

    return mathutils.Vector(v)


def scene_lamps(scene) -> tuple:
    """The lamps that light the scene's render (Sun, point, spot, area; not hidden from the render,
    energy > 0), as relight.lighting.lamps.Lamp values, in a stable order."""
    if scene is None:
        return ()
    out = []
    for obj in sorted(scene.objects, key=lambda o: o.name):
        if obj.type != "LIGHT" or obj.data is None or obj.data.type not in LAMP_TYPES or obj.hide_render:
            continue
        if float(obj.data.energy) <= 0:
            continue
        out.append(_lamp(obj))
    return tuple(out)


_seen_lamps: dict = {}  # scene name -> the lamps the last check saw


def lamps_changed(scene, depsgraph) -> bool:
    """True when this depsgraph update moved, changed, added or removed one of the scene's lamps
    since the last call (cheap for updates that touch no lamp, an object or the scene's collections)."""
    touched = False
    for update in getattr(depsgraph, "updates", ()):
        block = update.id
        if isinstance(block, bpy.types.Light) or isinstance(block, (bpy.types.Scene, bpy.types.Collection)) \
                or (isinstance(block, bpy.types.Object) and block.type == "LIGHT"):
            touched = True
            break
    if not touched:
        return False
    lamps = scene_lamps(scene)
    if _seen_lamps.get(scene.name) == lamps:
        return False
    _seen_lamps[scene.name] = lamps
    return True
