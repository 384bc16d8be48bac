"""The key lamp + smooth World against today's single map and a constant World, rendered by Cycles.

    .venv/bin/python benchmarks/bench_key_light.py [--size 64] [--samples 64] [--photos] [--lights venice,sun]
    .venv/bin/python benchmarks/bench_key_light.py --estimates DATA [--limit 8]   # held-out farm renders

For each light (the held-out maps venice, esplanade, workshop, lobby; a synthetic
sun-like light: a 2-degree sun over a blue sky and a grey ground; a synthetic studio
key: a warm 25-degree disk, a cool fill, a dark room), the true map is scaled to the
reference mean luminance 0.8 and projected to order-4 SH, L: the light a perfect
estimate would give (the ceiling). From L:

    (a) key   the key lamp (photo_light.lamp_setup of relight.lighting.key_light) + the smooth World
    (b) map   today's single map (relight.lighting.light_map, `--lamp-free`)
    (c) const a constant World of L's mean colour

and, as the reference, (t) the true map. Cycles renders a diffuse (albedo 0.8) and a
glossy (GGX, roughness 0.3) sphere of radius 0.3 m at the person (photo_light.PERSON_POSITION),
seen by an orthographic camera along +Y, and a 0.5 m cube on a diffuse floor from above.
Printed: each setup's sphere error against (t) as SNR = -20 log10(RMS error / RMS truth) in
dB (higher is better; the truth's own render noise caps it, printed as 'noise'), the key's
direction error against the true map's brightest 8 x 8-texel block and that block's share of
the irradiance of a surface facing it (dominant: >= 0.3), the cube's shadow direction error
against (t)'s (the darkness-weighted centroid of the floor around the cube), the World's
chroma spread (relight.lighting.key_light.chroma_spread) against the true map's, and the irradiance
error of key + World and of today's map against L. --estimates DATA takes L from the shipped
model's estimates (Balanced) on the first image of each held-out farm scene in DATA, against
that scene's true map in the photo-camera frame (benchmarks/eval_photo_light.true_map). --photos
adds the bundled photos' estimated lights: chroma spread of the two Worlds and the key.
Results: docs/EVALUATION.md, "A key lamp and a smooth World".
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
HELD_OUT = ("venice", "esplanade", "workshop", "lobby")
SETUPS = ("key", "map", "const")
RADIUS = 0.3


def synthetic(name: str, height: int = 256) -> np.ndarray:
    from relight.lighting import sh_projection
    from relight.lighting.key_light import direction_from_angles

    dirs, _ = sh_projection.equirect_directions(height, 2 * height)
    z = dirs[..., 2:]
    if name == "sun":
        sky = np.where(z > 0, np.array([0.35, 0.55, 1.0]) * (0.6 + 0.4 * (1 - z)), [0.25, 0.23, 0.2])
        disk = dirs @ direction_from_angles(120.0, 40.0) > math.cos(math.radians(1.0))
        solid = 2 * math.pi * (1 - math.cos(math.radians(1.0)))
        return sky + disk[..., None] * (np.array([1.0, 0.92, 0.8]) * 4.0 * math.pi / solid)
    room = np.full(dirs.shape, 0.05)
    key = dirs @ direction_from_angles(-40.0, 30.0) > math.cos(math.radians(12.5))
    fill = dirs @ direction_from_angles(60.0, 10.0) > math.cos(math.radians(20.0))
    return room + key[..., None] * [6.0, 5.0, 4.0] + fill[..., None] * [0.5, 0.6, 0.8]


def brightest(pixels):
    """(direction of the brightest 8 x 8 block, the share of a facing surface's irradiance within 20 deg)."""
    from relight.lighting import sh_projection
    from relight.imaging.colour import luminance

    pixels = np.asarray(pixels, np.float64)
    h, w = pixels.shape[:2]
    blocks = luminance(pixels.reshape(h // 8, 8, w // 8, 8, 3).mean(axis=(1, 3)))
    r, c = np.unravel_index(np.argmax(blocks), blocks.shape)
    dirs, omega = sh_projection.equirect_directions(h, w)
    d = dirs[r * 8 + 4, c * 8 + 4]
    cos = dirs @ d
    e = luminance(pixels) * np.maximum(cos, 0) * omega[:, None]
    return d, float(e[cos > math.cos(math.radians(20))].sum() / e.sum())


def angle(a, b) -> float:
    return math.degrees(math.acos(max(-1.0, min(1.0, float(np.dot(a, b) / np.linalg.norm(a) / np.linalg.norm(b))))))


# ------------------------------------------------------------------ Cycles scenes

def _material(bpy, name, glossy):
    material = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        material.use_nodes = True
    nodes = material.node_tree.nodes
    for node in list(nodes):
        if node.type != "OUTPUT_MATERIAL":
            nodes.remove(node)
    if glossy:
        bsdf = nodes.new("ShaderNodeBsdfGlossy")
        bsdf.distribution = "GGX"
        bsdf.inputs["Roughness"].default_value = 0.3
    else:
        bsdf = nodes.new("ShaderNodeBsdfDiffuse")
        bsdf.inputs["Roughness"].default_value = 0.0
    bsdf.inputs["Color"].default_value = (0.8, 0.8, 0.8, 1.0)
    material.node_tree.links.new(bsdf.outputs[0], nodes["Material Output"].inputs["Surface"])
    return material


def _cycles_support():
    """tests/support/cycles_support.py: the Cycles scenes the tests build (imports bpy)."""
    import sys

    if str(REPO / "tests") not in sys.path:
        sys.path.insert(0, str(REPO / "tests"))
    import cycles_support

    return cycles_support


def _object(bpy, mesh_maker, location, material):
    obj = _cycles_support().smooth_object(bpy.context.scene, "o", mesh_maker, location)
    obj.data.materials.append(material)
    return obj


def build(bpy, kind):
    """A fresh scene: 'spheres' (diffuse left, glossy right, at the person) or 'cube' (on a floor, seen
    from above)."""
    from blender_addon.logic.photo_light import PERSON_POSITION

    bpy.ops.wm.read_homefile(use_empty=True)
    scene = bpy.context.scene
    camera = bpy.data.objects.new("camera", bpy.data.cameras.new("camera"))
    camera.data.type = "ORTHO"
    scene.collection.objects.link(camera)
    scene.camera = camera
    px, py, pz = PERSON_POSITION
    if kind == "spheres":
        for dx, glossy in ((-1.1 * RADIUS, False), (1.1 * RADIUS, True)):
            _object(bpy, lambda bmesh, bm: bmesh.ops.create_uvsphere(bm, u_segments=64, v_segments=32, radius=RADIUS),
                    (px + dx, py, pz), _material(bpy, "g" if glossy else "d", glossy))
        camera.data.ortho_scale = 4.6 * RADIUS
        camera.location = (px, py - 3.0, pz)
        camera.rotation_euler = (math.pi / 2, 0.0, 0.0)
    else:
        floor = _material(bpy, "floor", False)
        _object(bpy, lambda bmesh, bm: bmesh.ops.create_grid(bm, x_segments=1, y_segments=1, size=3.0),
                (px, py, 0.0), floor)
        _object(bpy, lambda bmesh, bm: bmesh.ops.create_cube(bm, size=0.5), (px, py, 0.25), floor)
        camera.data.ortho_scale = 4.0
        camera.location = (px, py, 5.0)
        camera.rotation_euler = (0.0, 0.0, 0.0)
    return scene


def light_scene(bpy, scene, world_pixels, folder, lamp_setup=None, constant=None, truth=False):
    from relight.files.exr import write_exr

    world = bpy.data.worlds.new("w")
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True
    nodes, links = world.node_tree.nodes, world.node_tree.links
    if constant is not None:
        nodes["Background"].inputs["Color"].default_value = (*constant, 1.0)
        world.cycles.sampling_method = "NONE"
    else:
        path = os.path.join(folder, f"world{time.perf_counter_ns()}.exr")
        write_exr(path, {c: np.ascontiguousarray(world_pixels[..., i], np.float32) for i, c in enumerate("RGB")})
        texture = nodes.new("ShaderNodeTexEnvironment")
        texture.image = bpy.data.images.load(path)
        texture.image.colorspace_settings.name = "Linear Rec.709"
        links.new(texture.outputs["Color"], nodes["Background"].inputs["Color"])
        if truth:  # Cycles' automatic importance map (4096 wide, seconds to build): a MANUAL one as wide as
            # the map left the true maps' suns unsampled here (the truth's own two-seed SNR 1.7 dB on
            # esplanade, 24 dB automatic)
            world.cycles.sampling_method = "AUTOMATIC"
        else:  # the smooth maps: a map twice their width, as Photo Light -> World sets
            world.cycles.sampling_method = "MANUAL"
            world.cycles.sample_map_resolution = 2 * world_pixels.shape[1]
    scene.world = world
    if lamp_setup is not None:
        import mathutils

        data = bpy.data.lights.new("key", lamp_setup.kind)
        obj = bpy.data.objects.new("key", data)
        scene.collection.objects.link(obj)
        obj.location = lamp_setup.location
        obj.rotation_mode = "QUATERNION"
        obj.rotation_quaternion = mathutils.Vector(lamp_setup.direction).to_track_quat("Z", "Y")
        data.color, data.energy, data.use_shadow = lamp_setup.colour, lamp_setup.energy, True
        if lamp_setup.kind == "SUN":
            data.angle = lamp_setup.angle
        else:
            data.shape, data.size = "DISK", lamp_setup.size


def render(bpy, scene, folder, width, height, samples, seed=0) -> np.ndarray:
    from relight.files.exr import read_exr

    _cycles_support().cycles_on_cpu(scene, samples, seed)
    scene.cycles.max_bounces = 2
    scene.render.resolution_x, scene.render.resolution_y = width, height
    scene.render.resolution_percentage = 100
    scene.render.film_transparent = True
    scene.view_settings.view_transform = "Standard"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    scene.render.filepath = os.path.join(folder, f"r{time.perf_counter_ns()}.exr")
    bpy.ops.render.render(write_still=True)
    planes = read_exr(scene.render.filepath)
    return np.stack([planes[c] for c in "RGBA"], axis=-1).astype(np.float64)


def snr(image, truth, mask) -> float:
    err = image[mask][:, :3] - truth[mask][:, :3]
    return float(-20.0 * math.log10(math.sqrt(np.mean(err ** 2)) / math.sqrt(np.mean(truth[mask][:, :3] ** 2))))


def shadow_direction(image, size):
    """The direction (x, y on the floor, camera axes = world axes from above) of the cube's shadow:
    the darkness-weighted centroid of the floor outside the cube; None without a clear shadow."""
    lum = image[..., :3].mean(-1)[::-1]  # row 0 at the bottom: +y up
    ys, xs = np.mgrid[0:size, 0:size]
    x = (xs + 0.5) / size * 4.0 - 2.0
    y = (ys + 0.5) / size * 4.0 - 2.0
    floor = (np.maximum(abs(x), abs(y)) > 0.3) & (np.maximum(abs(x), abs(y)) < 1.8)
    reference = np.percentile(lum[floor], 90)
    dark = np.where(floor, np.maximum(0.0, 1.0 - lum / max(reference, 1e-12)), 0.0)
    total = dark.sum()
    c = np.array([(dark * x).sum(), (dark * y).sum()]) / max(total, 1e-12)
    if total < 1e-6 or np.linalg.norm(c) < 0.05:
        return None
    return c


def lights(args):
    """(name, true map [H, W, 3] at the reference luminance, the SH light the setups are made from):
    the true maps' own SH (the ceiling), or with --estimates the shipped model's estimates from
    held-out farm renders against their true maps in the photo-camera frame."""
    from relight.lighting import sh, sh_projection
    from relight.lighting.envmap import load_equirect
    from relight.lighting.presets import preset_path

    if args.estimates is None:
        for name in args.lights.split(","):
            pixels = (load_equirect(preset_path(name)).pixels[..., :3].astype(np.float64) if name in HELD_OUT
                      else synthetic("sun" if name == "sun" else "studio"))
            L, scale = sh.normalize_reference(sh_projection.project_equirect(pixels, 4, precision="float64"))
            yield name, pixels * scale, L
        return
    import sys

    sys.path.insert(0, str(Path(__file__).resolve().parent))
    from eval_photo_light import true_map

    from relight.files import dataset
    from relight.network import quality
    from relight.network.runtime import Relighter

    relighter = Relighter(str(quality.model_path("balanced")), working_size=quality.preset("balanced").working_size)
    for path in dataset.list_finished_scenes(Path(args.estimates))[:args.limit]:
        scene = dataset.read_scene(path)
        alpha = scene.alpha[..., 0] if scene.alpha.ndim == 3 else scene.alpha
        light = scene.lights[0]
        # one network run at Balanced's size, as benchmarks/eval_photo_light.py
        L = relighter.decompose(scene.images[0], alpha).light.astype(np.float64)
        yield f"{path.stem} ({light['name']})", true_map(light, scene.meta["camera"]["world_to_camera"]), L


def measure(bpy, name, pixels, L, args, folder) -> dict:
    """One light: the renders and numbers of the module docstring."""
    from blender_addon.logic.photo_light import lamp_setup
    from relight.lighting.key_light import chroma_spread, split_irradiance_error, split_light
    from relight.lighting.light_map import irradiance_error, light_map

    t0 = time.perf_counter()
    split = split_light(L, 512)
    split_ms = 1000 * (time.perf_counter() - t0)
    today = light_map(L, 512)
    d, dominance = brightest(pixels)
    worlds = {"key": dict(world_pixels=split.pixels, lamp_setup=lamp_setup(split.key)),
              "map": dict(world_pixels=today.pixels),
              "const": dict(world_pixels=None, constant=tuple(np.maximum(L[0], 0) * 0.5 / math.sqrt(math.pi)))}
    results = {}
    for kind in ("spheres", "cube"):
        images = {}
        for setup in ("truth", *SETUPS):
            scene = build(bpy, kind)
            light_scene(bpy, scene, pixels if setup == "truth" else worlds[setup]["world_pixels"], folder,
                        truth=setup == "truth",
                        **{k: v for k, v in worlds.get(setup, {}).items() if k != "world_pixels"})
            w, h = (2 * args.size, args.size) if kind == "spheres" else (args.size, args.size)
            images[setup] = render(bpy, scene, folder, w, h, args.samples)
            if setup == "truth" and kind == "spheres":
                images["truth2"] = render(bpy, scene, folder, w, h, args.samples, seed=1)
        results[kind] = images
    sph = results["spheres"]
    alpha = sph["truth"][..., 3] > 0.999
    left = np.zeros_like(alpha)
    left[:, :args.size] = True
    masks = {"diffuse": alpha & left, "glossy": alpha & ~left}
    truth_shadow = shadow_direction(results["cube"]["truth"], args.size)
    row = {"light": name, "dominance": dominance, "key_error": angle(split.key.direction, d),
           "angle": split.key.angle_deg, "lamp": "AREA" if split.key.wide else "SUN", "split_ms": split_ms,
           "spread": {"true": chroma_spread(pixels), "key": chroma_spread(split.pixels),
                      "map": chroma_spread(today.pixels)},
           "irradiance": {"key": split_irradiance_error(split, 4), "map": irradiance_error(L, today.pixels)},
           "noise": {m: snr(sph["truth2"], sph["truth"], masks[m]) + 3.0103 for m in masks}}
    for setup in SETUPS:
        for m in masks:
            row.setdefault(m, {})[setup] = snr(sph[setup], sph["truth"], masks[m])
        s = shadow_direction(results["cube"][setup], args.size)
        row.setdefault("shadow", {})[setup] = (None if s is None or truth_shadow is None
                                               else angle(np.append(s, 0), np.append(truth_shadow, 0)))
    return row


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--size", type=int, default=64,
                        help="sphere render height (width twice that); cube render side")
    parser.add_argument("--samples", type=int, default=64)
    parser.add_argument("--photos", action="store_true", help="also the bundled photos' estimated lights")
    parser.add_argument("--estimates", metavar="DATA",
                        help="instead of the maps' own SH: the shipped model's (Balanced) estimates from the first "
                             "image of each held-out farm scene in DATA against its true map (docs/EVALUATION.md)")
    parser.add_argument("--limit", type=int, default=12, help="scenes read with --estimates")
    parser.add_argument("--lights", default=",".join((*HELD_OUT, "sun", "studio-key")),
                        help="comma-separated lights (default: all six)")
    args = parser.parse_args(argv)

    import bpy

    print(f"bpy {bpy.app.version_string}; {args.size * 2} x {args.size} spheres, {args.size}^2 cube, "
          f"{args.samples} spp; load average {os.getloadavg()[0]:.2f}")
    rows, summary = [], {s: {"diffuse": [], "glossy": [], "shadow": []} for s in SETUPS}
    directions = []
    with tempfile.TemporaryDirectory(prefix="bench_key_light_") as folder:
        for name, pixels, L in lights(args):
            row = measure(bpy, name, pixels, L, args, folder)
            if row["dominance"] >= 0.3:
                directions.append(row["key_error"])
            for setup in SETUPS:
                for m in ("diffuse", "glossy", "shadow"):
                    summary[setup][m].append(row[m][setup])
            rows.append(row)
            print(f"  {name}: done", flush=True)

    print("\n| light | setup | diffuse SNR (dB) | glossy SNR (dB) | shadow dir. error (deg) |")
    print("|---|---|---|---|---|")
    for row in rows:
        for setup in SETUPS:
            shadow = row["shadow"][setup]
            print(f"| {row['light']} | {setup} | {row['diffuse'][setup]:.1f} | {row['glossy'][setup]:.1f} | "
                  f"{'no shadow' if shadow is None else f'{shadow:.0f}'} |")
        print(f"| {row['light']} | (truth's noise) | {row['noise']['diffuse']:.1f} | {row['noise']['glossy']:.1f} | |")
    print("\n| light | dominance | key direction error (deg) | key angle (deg) | lamp | "
          "chroma spread true / key World / "
          "map | irradiance error key+World / map | split (ms) |")
    print("|---|---|---|---|---|---|---|---|")
    for row in rows:
        sp, ir = row["spread"], row["irradiance"]
        print(f"| {row['light']} | {row['dominance']:.2f} | {row['key_error']:.1f} | {row['angle']:.0f} | "
              f"{row['lamp']} | {sp['true']:.3f} / {sp['key']:.3f} / {sp['map']:.3f} | "
              f"{100 * ir['key']:.2f}% / {100 * ir['map']:.2f}% | "
              f"{row['split_ms']:.0f} |")
    print("\n| setup | diffuse SNR median (dB) | glossy SNR median (dB) | shadow error median (deg) |")
    print("|---|---|---|---|")
    for setup in SETUPS:
        shadows = [v for v in summary[setup]["shadow"] if v is not None]
        print(f"| {setup} | {statistics.median(summary[setup]['diffuse']):.1f} | "
              f"{statistics.median(summary[setup]['glossy']):.1f} | "
              f"{f'{statistics.median(shadows):.0f}' if shadows else 'no shadow'} "
              f"({len(summary[setup]['shadow']) - len(shadows)} without) |")
    if directions:
        print(f"\nkey direction error, lights with a dominant source ({len(directions)}): median "
              f"{statistics.median(directions):.1f} deg")
    if args.photos:
        photo_rows()
    return 0


def photo_rows() -> None:
    from relight.network import quality
    from relight.lighting.key_light import angles_from_direction, chroma_spread, split_irradiance_error, split_light
    from relight.lighting.light_map import irradiance_error, light_map
    from relight.files.photo import read_photo
    from relight.network.runtime import Relighter

    relighter = Relighter(str(quality.model_path("balanced")), working_size=quality.preset("balanced").working_size)
    print("\n| photo (estimated light) | chroma spread key World / map | key az, el (deg) | key angle | "
          "irradiance error key+World / map |")
    print("|---|---|---|---|---|")
    for path in sorted((REPO / "evaluation/data/matte_eval").glob("*.jpg")):
        image, _ = read_photo(path)
        L = relighter.decompose(image, **quality.preset("balanced").decompose_options()).light
        split, today = split_light(L, 512), light_map(L, 512)
        az, el = angles_from_direction(split.key.direction)
        print(f"| {path.name} | {chroma_spread(split.pixels):.3f} / {chroma_spread(today.pixels):.3f} | "
              f"{az:.0f}, {el:.0f} | {split.key.angle_deg:.0f} | {100 * split_irradiance_error(split, 4):.2f}% / "
              f"{100 * irradiance_error(L, today.pixels):.2f}% |")


if __name__ == "__main__":
    raise SystemExit(main())
