"""Cycles scenes that tests and benchmarks build to check the conventions against a renderer
(bpy needed, Blender 4.2 to 5.x): a Lambertian sphere seen by the photo camera of
docs/conventions.md, its render with Cycles' Normal pass, the sphere's pixels read back, and
a World whose radiance is one SH basis function."""

from __future__ import annotations

import math
from pathlib import Path

import bpy
import numpy as np

from relight.files.exr import read_exr

SPHERE_CENTRE = (0.0, 5.0, 0.0)  # a unit sphere 5 m along the camera's view
ORTHO_SCALE = 2.2  # the orthographic view's width: the sphere and a margin


def smooth_object(scene: bpy.types.Scene, name: str, build, location) -> bpy.types.Object:
    """A mesh object `name` at `location`, linked to `scene`: build(bmesh, bm) fills an empty bmesh,
    whose faces are then shaded smooth."""
    import bmesh

    mesh = bpy.data.meshes.new(name)
    bm = bmesh.new()
    build(bmesh, bm)
    for face in bm.faces:
        face.smooth = True
    bm.to_mesh(mesh)
    bm.free()
    obj = bpy.data.objects.new(name, mesh)
    obj.location = location
    scene.collection.objects.link(obj)
    return obj


def lambert_sphere(scene: bpy.types.Scene, albedo: float) -> bpy.types.Object:
    """A smooth unit sphere (128 x 64 segments) at SPHERE_CENTRE, pure Lambert of grey `albedo`."""
    sphere = smooth_object(scene, "sphere", lambda bmesh, bm: bmesh.ops.create_uvsphere(
        bm, u_segments=128, v_segments=64, radius=1.0), SPHERE_CENTRE)
    material = bpy.data.materials.new("lambert")
    if bpy.app.version < (5, 0, 0):
        material.use_nodes = True  # always on from 5.0 (deprecated there)
    nodes = material.node_tree.nodes
    for node in list(nodes):
        if node.type != "OUTPUT_MATERIAL":
            nodes.remove(node)
    diffuse = nodes.new("ShaderNodeBsdfDiffuse")
    diffuse.inputs["Color"].default_value = (albedo, albedo, albedo, 1.0)
    diffuse.inputs["Roughness"].default_value = 0.0  # pure Lambert
    material.node_tree.links.new(diffuse.outputs[0], nodes["Material Output"].inputs["Surface"])
    sphere.data.materials.append(material)
    return sphere


def photo_camera(scene: bpy.types.Scene) -> bpy.types.Object:
    """The photo camera: at the origin, looking along +Y (X right, Z up), orthographic."""
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    camera.data.type = "ORTHO"
    camera.data.ortho_scale = ORTHO_SCALE
    camera.rotation_euler = (math.pi / 2, 0.0, 0.0)
    scene.collection.objects.link(camera)
    scene.camera = camera
    return camera


def cycles_on_cpu(scene: bpy.types.Scene, samples: int, seed: int) -> None:
    """Cycles on the CPU, `samples` per pixel without adaptive sampling or denoising, noise seed `seed`."""
    scene.render.engine = "CYCLES"
    scene.cycles.device = "CPU"
    scene.cycles.samples = samples
    scene.cycles.use_adaptive_sampling = False
    scene.cycles.use_denoising = False
    scene.cycles.seed = seed


def render_with_normals(scene: bpy.types.Scene, out_path: Path, size: int, samples: int, seed: int) -> dict:
    """Cycles on the CPU, `samples` per pixel without adaptive sampling or denoising, a box
    filter one pixel wide, `size` x `size`; the render's passes (Combined, Normal) as read
    back from its multilayer EXR."""
    cycles_on_cpu(scene, samples, seed)
    scene.cycles.pixel_filter_type = "BOX"
    scene.render.filter_size = 1.0
    scene.render.resolution_x = scene.render.resolution_y = size
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = "Standard"
    scene.view_layers[0].use_pass_normal = True
    if hasattr(scene.render.image_settings, "media_type"):  # Blender 5
        scene.render.image_settings.media_type = "MULTI_LAYER_IMAGE"
    else:
        scene.render.image_settings.file_format = "OPEN_EXR_MULTILAYER"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = str(out_path)
    bpy.ops.render.render(write_still=True)
    return read_exr(out_path)  # Blender 5 writes one part per pass


def sphere_pixels(first: dict, second: dict) -> dict:
    """The sphere's pixels in two renders of it: fully covered, facing the camera (grazing
    silhouette pixels, partly covered, left out). `n` unit normals [P, 3] from the first's
    Normal pass, `rows`/`cols` their pixels, `r0`/`r1` each render's RGB there (float64)."""
    rgb = [np.stack([p[f"ViewLayer.Combined.{c}"] for c in "RGB"], -1).astype(np.float64) for p in (first, second)]
    normal = np.stack([first[f"ViewLayer.Normal.{c}"] for c in "XYZ"], -1).astype(np.float64)
    length = np.linalg.norm(normal, axis=-1)
    inside = (first["ViewLayer.Combined.A"] > 0.999) & (length > 0.5)
    n = normal[inside] / length[inside][:, None]
    keep = n[:, 1] < -0.2
    rows, cols = np.nonzero(inside)
    return {"rows": rows[keep], "cols": cols[keep], "n": n[keep],
            "r0": rgb[0][inside][keep], "r1": rgb[1][inside][keep]}


def sh_world(scene: bpy.types.Scene, index: int) -> None:
    """World radiance = the real SH basis function Y_k(w) (negative emission allowed).

    Built from the world's direction vector with math nodes, exactly the
    polynomial form of relight.lighting.sh for l <= 2, which is what the transport
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
