"""Cycles passes: per-vertex data to pixels through AOVs, and path-traced images.

Everything here needs bpy. Geometry buffers do not depend on the light, so
they come from one render (box filter one pixel wide, AOVs averaged over the
samples that hit the person; dividing by alpha gives the person's own mean),
and each light gets its own path-traced render with the HDR map visible.
Blender 5 writes one EXR part per pass; relight.exr reads every part.
"""

from __future__ import annotations

import math
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import bpy
import numpy as np

from relight.exr import read_exr

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


def configure_film(scene: bpy.types.Scene, resolution: tuple[int, int]) -> None:
    height, width = resolution
    scene.render.resolution_x = width
    scene.render.resolution_y = height
    scene.render.resolution_percentage = 100
    scene.render.pixel_aspect_x = scene.render.pixel_aspect_y = 1.0
    # One-pixel box filter: each pixel averages the samples inside it, so
    # alpha is the pixel's coverage and AOVs are not blurred across pixels.
    scene.cycles.pixel_filter_type = "BOX"
    scene.cycles.filter_width = 1.0
    # Keep Cycles' synced scene and BVH between the geometry render and the K
    # light renders: only the world changes, so later renders skip the rebuild
    # (about 4x less per-render overhead measured here).
    scene.render.use_persistent_data = True
    scene.render.use_compositing = False
    scene.render.use_sequencer = False
    scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.image_settings.color_depth = "32"
    # Scratch files, read back at once and deleted: compressing them cost ~10% of a
    # 128 px render call (docs/benchmarks/farm_render.md); the dataset's own EXR is
    # written by relight.dataset.
    scene.render.image_settings.exr_codec = "NONE"
    scene.view_settings.view_transform = "Standard"
    scene.view_settings.look = "None"
    scene.view_settings.exposure = 0.0
    scene.view_settings.gamma = 1.0
    scene.cycles.seed = 0
    scene.cycles.use_animated_seed = False
    scene.cycles.use_adaptive_sampling = False
    threads = thread_count()
    scene.render.threads_mode = "FIXED" if threads else "AUTO"
    if threads:
        scene.render.threads = threads


def render_to_channels(scene: bpy.types.Scene, work_dir: Path, tag: str) -> dict[str, np.ndarray]:
    """Render the current settings to a multilayer EXR and read every part.

    Returned arrays are flipped to image row order (row 0 at the top).
    """
    path = Path(work_dir) / f"{tag}.exr"
    scene.render.filepath = str(path)
    bpy.ops.render.render(write_still=True)
    if not path.is_file():
        raise RuntimeError(f"Cycles wrote no image for pass {tag!r} at {path}")
    channels = read_exr(path)
    path.unlink()
    return channels


def _plane(channels: dict[str, np.ndarray], *names: str) -> np.ndarray:
    for name in names:
        if name in channels:
            return channels[name]
    raise RuntimeError(f"render output lacks channel {names[0]!r}; has {sorted(channels)[:12]}...")


def read_rgb(channels: dict[str, np.ndarray], pass_name: str) -> np.ndarray:
    base = f"{VIEW_LAYER}.{pass_name}"
    return np.stack([_plane(channels, f"{base}.{c}") for c in "RGB"], axis=-1)


def read_alpha(channels: dict[str, np.ndarray]) -> np.ndarray:
    return _plane(channels, f"{VIEW_LAYER}.Combined.A")


@dataclass
class GeometryPass:
    alpha: np.ndarray  # [H, W]
    aovs: dict[str, np.ndarray]  # name -> [H, W, 3], divided by alpha (0 outside)
    seconds: float


def render_geometry(
    scene: bpy.types.Scene, spec: AovSpec, work_dir: Path, samples: int = 16
) -> GeometryPass:
    """One render of coverage and every AOV; the world is black and nothing bounces."""
    t0 = time.perf_counter()
    cycles = scene.cycles
    cycles.samples = samples
    cycles.use_denoising = False
    cycles.max_bounces = 0
    cycles.diffuse_bounces = cycles.glossy_bounces = cycles.transmission_bounces = 0
    cycles.transparent_max_bounces = 0
    scene.render.film_transparent = True
    world = scene.world
    strength_socket = _world_strength(world)
    old_strength = strength_socket.default_value if strength_socket is not None else None
    if strength_socket is not None:
        strength_socket.default_value = 0.0
    try:
        channels = render_to_channels(scene, work_dir, "geometry")
    finally:
        if strength_socket is not None:
            strength_socket.default_value = old_strength
    alpha = read_alpha(channels)
    safe = np.where(alpha > 1e-6, alpha, 1.0)
    aovs = {}
    for name in list(spec.attribute_aovs) + list(spec.socket_aovs):
        value = read_rgb(channels, name)
        aovs[name] = np.where(alpha[..., None] > 1e-6, value / safe[..., None], 0.0).astype(np.float32)
    return GeometryPass(alpha=alpha.astype(np.float32), aovs=aovs, seconds=time.perf_counter() - t0)


def _world_strength(world):
    if world is None or world.node_tree is None:
        return None
    for node in world.node_tree.nodes:
        if node.type == "BACKGROUND":
            return node.inputs["Strength"]
    return None


@dataclass
class PathTracedPass:
    image: np.ndarray  # [H, W, 3] linear radiance, HDR background included
    seconds: float  # wall time of the render call and reading its EXR back (Cycles' setup + path tracing + I/O)


def render_path_traced(
    scene: bpy.types.Scene, work_dir: Path, tag: str, samples: int, denoise: bool, bounces: int = 8,
    prefilter: str = "fast",
) -> PathTracedPass:
    cycles = scene.cycles
    cycles.samples = samples
    cycles.use_denoising = denoise
    if denoise:
        cycles.denoiser = "OPENIMAGEDENOISE"
        cycles.denoising_input_passes = "RGB_ALBEDO_NORMAL"
        cycles.denoising_prefilter = prefilter.upper()  # farm.options.DENOISE_PREFILTERS
    cycles.max_bounces = bounces
    cycles.diffuse_bounces = min(4, bounces)
    cycles.glossy_bounces = min(4, bounces)
    cycles.transmission_bounces = bounces
    cycles.transparent_max_bounces = bounces
    scene.render.film_transparent = False
    t_render = time.perf_counter()
    channels = render_to_channels(scene, work_dir, tag)
    render_seconds = time.perf_counter() - t_render
    image = read_rgb(channels, "Combined")
    return PathTracedPass(image=image.astype(np.float32), seconds=render_seconds)


def set_environment_world(
    scene: bpy.types.Scene, image_path: Path | None, rotation_deg: float, strength: float,
    pixels: np.ndarray | None = None, name: str = "relight_light",
) -> None:
    """World = an equirect map (Blender's default mapping) turned by rotation_deg about Z.

    The light is rotated by +rotation_deg (relight.sh.z_rotation): the lookup
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


def sh_world(scene: bpy.types.Scene, index: int) -> None:
    """World radiance = the real SH basis function Y_k(w) (negative emission allowed).

    Built from the world's direction vector with math nodes, exactly the
    polynomial form of relight.sh for l <= 2, which is what the transport
    check needs.
    """
    world = scene.world or bpy.data.worlds.new("World")
    scene.world = world
    nodes, links = world.node_tree.nodes, world.node_tree.links
    nodes.clear()
    coord = nodes.new("ShaderNodeTexCoord")
    split = nodes.new("ShaderNodeSeparateXYZ")
    links.new(coord.outputs["Generated"], split.inputs["Vector"])
    x, y, z = split.outputs["X"], split.outputs["Y"], split.outputs["Z"]

    def math_node(op, a, b):
        node = nodes.new("ShaderNodeMath")
        node.operation = op
        node.use_clamp = False
        for i, operand in enumerate((a, b)):
            if isinstance(operand, float):
                node.inputs[i].default_value = operand
            else:
                links.new(operand, node.inputs[i])
        return node.outputs[0]

    c0 = 0.5 * math.sqrt(1.0 / math.pi)
    c1 = math.sqrt(3.0 / (4.0 * math.pi))
    c2 = 0.5 * math.sqrt(15.0 / math.pi)
    c20 = 0.25 * math.sqrt(5.0 / math.pi)
    c22 = 0.25 * math.sqrt(15.0 / math.pi)
    if index == 0:
        value = math_node("ADD", math_node("MULTIPLY", x, 0.0), c0)
    elif index == 1:
        value = math_node("MULTIPLY", y, c1)
    elif index == 2:
        value = math_node("MULTIPLY", z, c1)
    elif index == 3:
        value = math_node("MULTIPLY", x, c1)
    elif index == 4:
        value = math_node("MULTIPLY", math_node("MULTIPLY", x, y), c2)
    elif index == 5:
        value = math_node("MULTIPLY", math_node("MULTIPLY", y, z), c2)
    elif index == 6:
        value = math_node("MULTIPLY", math_node("SUBTRACT", math_node("MULTIPLY", math_node("MULTIPLY", z, z), 3.0), 1.0), c20)
    elif index == 7:
        value = math_node("MULTIPLY", math_node("MULTIPLY", x, z), c2)
    elif index == 8:
        value = math_node("MULTIPLY", math_node("SUBTRACT", math_node("MULTIPLY", x, x), math_node("MULTIPLY", y, y)), c22)
    else:
        raise ValueError(f"sh_world supports SH indices 0..8, got {index}")
    combine = nodes.new("ShaderNodeCombineXYZ")
    for axis in ("X", "Y", "Z"):
        links.new(value, combine.inputs[axis])
    background = nodes.new("ShaderNodeBackground")
    background.inputs["Strength"].default_value = 1.0
    output = nodes.new("ShaderNodeOutputWorld")
    links.new(combine.outputs["Vector"], background.inputs["Color"])
    links.new(background.outputs["Background"], output.inputs["Surface"])


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


def work_directory(out_dir: Path) -> tempfile.TemporaryDirectory:
    """A private scratch folder for Cycles' intermediate EXRs, in the system temp dir.

    Kept out of `out_dir` so a killed worker leaves nothing in the dataset
    folder but what relight.dataset's atomic writes may leave; `out_dir` is
    created here so a bad output path fails before any rendering.
    """
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    return tempfile.TemporaryDirectory(prefix="relight_render_")


def thread_count() -> int:
    """Threads a scene may use: $RELIGHT_CYCLES_THREADS when set (a farm worker's share), else 0 = all cores."""
    value = os.environ.get("RELIGHT_CYCLES_THREADS", "").strip()
    if not value:
        return 0
    try:
        count = int(value)
    except ValueError:
        raise ValueError(f"RELIGHT_CYCLES_THREADS must be a non-negative integer, got {value!r}") from None
    if count < 0:
        raise ValueError(f"RELIGHT_CYCLES_THREADS must be a non-negative integer, got {value!r}")
    return count


def render_sky_equirect(params: dict, size: tuple[int, int], work_dir: Path, samples: int = 4) -> np.ndarray:
    """Blender's Sky Texture rendered to an equirect image [H, W, 3] (row 0 at the top).

    A separate scene with a panoramic camera at the origin (up = +Z) sees only
    the world; a box filter one pixel wide makes each texel the mean radiance
    over its own footprint, so the sun disc keeps its energy.
    """
    main = bpy.context.window.scene if bpy.context.window else bpy.context.scene
    sky_scene = bpy.data.scenes.new("relight_sky")
    try:
        sky_scene.render.engine = "CYCLES"
        sky_scene.cycles.device = "CPU"
        configure_film(sky_scene, size)
        # No persistent Cycles session for a scene removed right after its one
        # render: a session left holding the freed scene crashed the next
        # depsgraph update (SIGSEGV linking the person's meshes).
        sky_scene.render.use_persistent_data = False
        sky_scene.view_layers[0].name = VIEW_LAYER
        sky_scene.cycles.samples = samples
        sky_scene.cycles.use_denoising = False
        sky_scene.render.film_transparent = False
        world = bpy.data.worlds.new("relight_sky")
        sky_scene.world = world
        nodes, links = world.node_tree.nodes, world.node_tree.links
        nodes.clear()
        tex = nodes.new("ShaderNodeTexSky")
        tex.sky_type = params["sky_type"]
        tex.sun_disc = True
        tex.sun_size = math.radians(params["sun_size_deg"])
        tex.sun_elevation = math.radians(params["sun_elevation_deg"])
        tex.sun_rotation = math.radians(params["sun_rotation_deg"])
        tex.altitude = params["altitude_m"]
        tex.air_density = params["air_density"]
        tex.aerosol_density = params["aerosol_density"]
        tex.ozone_density = params["ozone_density"]
        background = nodes.new("ShaderNodeBackground")
        output = nodes.new("ShaderNodeOutputWorld")
        links.new(tex.outputs["Color"], background.inputs["Color"])
        links.new(background.outputs["Background"], output.inputs["Surface"])
        data = bpy.data.cameras.new("relight_sky_camera")
        data.type = "PANO"
        data.panorama_type = "EQUIRECTANGULAR"
        cam = bpy.data.objects.new("relight_sky_camera", data)
        sky_scene.collection.objects.link(cam)
        cam.rotation_euler = (math.pi / 2.0, 0.0, 0.0)
        sky_scene.camera = cam
        path = Path(work_dir) / "sky.exr"
        sky_scene.render.filepath = str(path)
        bpy.ops.render.render(write_still=True, scene=sky_scene.name)
        channels = read_exr(path)
        path.unlink()
        pixels = read_rgb(channels, "Combined")
    finally:
        bpy.data.scenes.remove(sky_scene)
        if bpy.context.window:
            bpy.context.window.scene = main
    return np.maximum(pixels, 0.0).astype(np.float32)
