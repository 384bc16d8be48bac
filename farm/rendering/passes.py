"""Cycles render calls: per-vertex data to pixels through AOVs, and path-traced images.

Everything here needs bpy; the scene it renders is built by farm/rendering/blender_scene.py.
Geometry buffers do not depend on the light, so they come from one render (box
filter one pixel wide, AOVs averaged over the samples that hit the person;
dividing by alpha gives the person's own mean), and each light gets its own
path-traced render with the HDR map visible. Blender 5 writes one EXR part per
pass; relight.files.exr reads every part.
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

from farm.rendering.blender_scene import VIEW_LAYER, AovSpec
from relight.files.exr import read_exr


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
    # written by relight.files.dataset.
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


def work_directory(out_dir: Path) -> tempfile.TemporaryDirectory:
    """A private scratch folder for Cycles' intermediate EXRs, in the system temp dir.

    Kept out of `out_dir` so a killed worker leaves nothing in the dataset
    folder but what relight.files.dataset's atomic writes may leave; `out_dir` is
    created here so a bad output path fails before any rendering.
    """
    Path(out_dir).mkdir(parents=True, exist_ok=True)
    return tempfile.TemporaryDirectory(prefix="relight_render_")


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
        cycles.denoising_prefilter = prefilter.upper()  # farm.synthesis.scene_options.DENOISE_PREFILTERS
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
