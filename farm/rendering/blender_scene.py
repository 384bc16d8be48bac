"""The farm's Blender scene, built for Cycles: meshes with per-vertex attributes routed
to AOVs, the camera and the light's World.

Everything here needs bpy; the render calls that read the scene back are in
farm/rendering/passes.py.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

VIEW_LAYER = "ViewLayer"
# Vector attributes carrying per-vertex data; each holds 3 scalars.
ATTR_PREFIX = "relight_"


def reset_scene() -> bpy.types.Scene:
    """Factory settings, empty scene, Cycles on the CPU."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.view_layers[0].name = VIEW_LAYER
    return scene


def mesh_object(
    name: str,
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    attributes: dict[str, np.ndarray] | None = None,
    uvs: np.ndarray | None = None,
    *,
    scene: bpy.types.Scene,
) -> bpy.types.Object:
    """A smooth-shaded triangle mesh with our own vertex normals and float3 point attributes.

    Linked into `scene` explicitly: after a temporary scene was rendered and
    removed (render_sky_equirect), bpy.context.scene must not be trusted.
    """
    vertices = np.ascontiguousarray(vertices, dtype=np.float32)
    faces = np.ascontiguousarray(faces, dtype=np.int32)
    mesh = bpy.data.meshes.new(name)
    mesh.vertices.add(len(vertices))
    mesh.vertices.foreach_set("co", vertices.ravel())
    mesh.loops.add(faces.size)
    mesh.loops.foreach_set("vertex_index", faces.ravel())
    mesh.polygons.add(len(faces))
    mesh.polygons.foreach_set("loop_start", np.arange(0, faces.size, 3, dtype=np.int32))
    mesh.polygons.foreach_set("loop_total", np.full(len(faces), 3, dtype=np.int32))
    mesh.polygons.foreach_set("use_smooth", np.ones(len(faces), dtype=bool))
    mesh.update(calc_edges=True)
    mesh.validate(clean_customdata=False)
    if len(mesh.vertices) != len(vertices):
        raise ValueError(f"mesh {name!r}: Blender dropped vertices while validating")
    # Shading in Cycles then uses exactly the normals the bake used.
    mesh.normals_split_custom_set_from_vertices([tuple(n) for n in np.asarray(normals, dtype=np.float64)])
    for key, values in (attributes or {}).items():
        values = np.ascontiguousarray(values, dtype=np.float32)
        if values.shape != (len(vertices), 3):
            raise ValueError(f"attribute {key!r} must have shape [{len(vertices)}, 3], got {values.shape}")
        attr = mesh.attributes.new(ATTR_PREFIX + key, "FLOAT_VECTOR", "POINT")
        attr.data.foreach_set("vector", values.ravel())
    if uvs is not None:
        layer = mesh.uv_layers.new(name="UVMap")
        loop_uv = np.asarray(uvs, dtype=np.float32)[faces.ravel()]
        layer.data.foreach_set("uv", loop_uv.ravel())
    obj = bpy.data.objects.new(name, mesh)
    scene.collection.objects.link(obj)
    return obj


def pack_vectors(values: np.ndarray) -> list[np.ndarray]:
    """Split [V, C] scalars into ceil(C/3) [V, 3] blocks (zero padded)."""
    values = np.asarray(values, dtype=np.float32)
    count = values.shape[1]
    blocks = []
    for start in range(0, count, 3):
        block = np.zeros((values.shape[0], 3), dtype=np.float32)
        part = values[:, start : start + 3]
        block[:, : part.shape[1]] = part
        blocks.append(block)
    return blocks


@dataclass
class AovSpec:
    """Which AOVs exist: vector attributes and shader sockets routed to AOVs."""

    attribute_aovs: list[str]  # attribute key == AOV name
    socket_aovs: list[str]  # "albedo", "material"


def register_aovs(view_layer: bpy.types.ViewLayer, spec: AovSpec) -> None:
    for name in list(spec.attribute_aovs) + list(spec.socket_aovs):
        aov = view_layer.aovs.add()
        aov.name = name
        aov.type = "COLOR"


def add_attribute_aovs(material: bpy.types.Material, names: list[str], x: float = -600.0) -> None:
    """Route each point attribute `relight_<name>` to the AOV `<name>`."""
    nodes, links = material.node_tree.nodes, material.node_tree.links
    for i, name in enumerate(names):
        attr = nodes.new("ShaderNodeAttribute")
        attr.attribute_type = "GEOMETRY"
        attr.attribute_name = ATTR_PREFIX + name
        attr.location = (x, -200.0 * i)
        out = nodes.new("ShaderNodeOutputAOV")
        out.aov_name = name
        out.location = (x + 250.0, -200.0 * i)
        links.new(attr.outputs["Vector"], out.inputs["Color"])


def add_socket_aov(material: bpy.types.Material, name: str, socket) -> None:
    """Route an existing output socket (e.g. the base colour source) to AOV `name`."""
    nodes, links = material.node_tree.nodes, material.node_tree.links
    out = nodes.new("ShaderNodeOutputAOV")
    out.aov_name = name
    links.new(socket, out.inputs["Color"])


def camera_object(
    location: np.ndarray, rotation: np.ndarray, focal_mm: float, sensor_mm: float = 36.0,
    *, scene: bpy.types.Scene,
) -> bpy.types.Object:
    """A perspective camera with world matrix [rotation | location] (Blender camera axes)."""
    import mathutils

    data = bpy.data.cameras.new("camera")
    data.lens = float(focal_mm)
    data.sensor_fit = "HORIZONTAL"
    data.sensor_width = float(sensor_mm)
    data.clip_start = 0.05
    data.clip_end = 100.0
    obj = bpy.data.objects.new("camera", data)
    scene.collection.objects.link(obj)
    m = np.eye(4)
    m[:3, :3] = rotation
    m[:3, 3] = location
    obj.matrix_world = mathutils.Matrix(m.tolist())
    scene.camera = obj
    return obj


def set_environment_world(
    scene: bpy.types.Scene, image_path: Path | None, rotation_deg: float, strength: float,
    pixels: np.ndarray | None = None, name: str = "relight_light",
) -> None:
    """World = an equirect map (Blender's default mapping) turned by rotation_deg about Z.

    The light is rotated by +rotation_deg (relight.lighting.sh.z_rotation): the lookup
    vector is rotated by -rotation_deg. Give either a file path or float pixels
    [H, W, 3] (row 0 at the top).
    """
    image = _load_image(image_path, pixels, name)
    # A fresh World per light: Cycles reads the importance-map settings only
    # when it first syncs a World, and the automatic setting of Blender 5.0
    # builds a 4096 x 2048 map for any map without a sun (1.2-1.5 s per
    # light change on one core, docs/benchmarks/farm_render.md); ours is sized
    # from the map (importance_map_resolution).
    previous = scene.world
    world = bpy.data.worlds.new(name)
    world.cycles.sampling_method = "MANUAL"
    world.cycles.sample_map_resolution = importance_map_resolution(image.size[0])
    scene.world = world
    if previous is not None and previous.users == 0:
        bpy.data.worlds.remove(previous)
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    coord = nodes.new("ShaderNodeTexCoord")
    mapping = nodes.new("ShaderNodeMapping")
    mapping.vector_type = "POINT"
    mapping.inputs["Rotation"].default_value = (0.0, 0.0, -math.radians(rotation_deg))
    env = nodes.new("ShaderNodeTexEnvironment")
    env.interpolation = "Linear"
    env.image = image
    background = nodes.new("ShaderNodeBackground")
    background.inputs["Strength"].default_value = float(strength)
    output = nodes.new("ShaderNodeOutputWorld")
    links.new(coord.outputs["Generated"], mapping.inputs["Vector"])
    links.new(mapping.outputs["Vector"], env.inputs["Vector"])
    links.new(env.outputs["Color"], background.inputs["Color"])
    links.new(background.outputs["Background"], output.inputs["Surface"])


# Importance-map texels per map texel along each axis. The map is looked up with
# bilinear interpolation, so a one-texel sun spreads over its neighbours; a map
# only as fine as the texels gives those neighbours too little probability (2.7 dB
# more noise at 16 spp + OIDN than Cycles' 4096-wide map), see
# docs/benchmarks/farm_render.md for the measured choice.
IMPORTANCE_MAP_OVERSAMPLING = 2


def importance_map_resolution(map_width: int) -> int:
    """Width of the World importance map for an equirect map `map_width` texels wide,
    within Cycles' own bounds for the setting."""
    return int(min(max(int(map_width) * IMPORTANCE_MAP_OVERSAMPLING, 64), 8192))


def _load_image(path: Path | None, pixels: np.ndarray | None, name: str):
    if (path is None) == (pixels is None):
        raise ValueError("give an image path or pixels, not both or neither")
    if path is not None:
        image = bpy.data.images.load(str(path), check_existing=True)
    else:
        pixels = np.asarray(pixels, dtype=np.float32)
        height, width = pixels.shape[:2]
        image = bpy.data.images.new(name, width, height, alpha=True, float_buffer=True)
        rgba = np.ones((height, width, 4), dtype=np.float32)
        rgba[..., :3] = pixels
        # Blender's pixel rows start at the bottom.
        image.pixels.foreach_set(rgba[::-1].ravel())
        image.pack()
    image.colorspace_settings.name = "Linear Rec.709"
    return image
