"""How right is the photo's light as a World? A white sphere under it against the true map.

    .venv/bin/python benchmarks/eval_photo_light.py --data DATA/heldout_light128 \
        --model relight/models/geometry.onnx --quality balanced [--size 64 --samples 64] [--json OUT.json]

For every path-traced image of every held-out farm scene (the true HDR map is
known: docs/EVALUATION.md, "Photo light as a World"), the runtime decomposes the
image (the scene's own alpha as the mask) and a diffuse white sphere (albedo
0.8) is rendered by Cycles, seen by the photo camera (orthographic, looking
along +Y), under three Worlds:

  (a) the map made from the photo's estimated light (relight.lighting.light_map: what
      `relight light` and Photo Light -> World make);
  (b) the true HDR map in the photo-camera frame (the bundled map scaled and
      turned as the sidecar says, resampled bilinearly; its order-8 SH is
      checked against the sidecar's `sh8`);
  (c) a constant World of the photo's mean colour (all its pixels) scaled to
      the mean luminance of (a): the baseline an artist could make by hand;
  (o) the true light's order-4 SH (the sidecar's) through relight.lighting.light_map:
      the best an order-4 estimate can do, for scale.

PSNR of (a), (c) and (o) against (b) over the sphere's pixels (model.scoring.metrics.psnr,
peak the 99th percentile of (b) there, as benchmarks/bench_farm_render.py),
also after scaling (a) and (c) by one factor to the true light's mean
luminance (level-matched: the direction and colour alone), and the light's
colour error: the angle between the mean RGB of (a) (its L_00) and of the true
light, and between the photo's mean colour and the true light's.
"""

from __future__ import annotations

import argparse
import math
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ALBEDO = 0.8
MAP_WIDTH = 512


# ------------------------------------------------------------------ maps (numpy)

def true_map(light: dict, world_to_camera, width: int = MAP_WIDTH) -> np.ndarray:
    """The farm light `light` (sidecar record) as an equirect map in the photo-camera frame."""
    from relight.lighting import presets, sh_projection, sh_rotation
    from relight.lighting.envmap import load_equirect

    source = load_equirect(presets.preset_path(light["name"])).pixels.astype(np.float64)
    sh_, sw = source.shape[:2]
    dirs, _ = sh_projection.equirect_directions(width // 2, width)
    # camera -> world (world_to_camera is a rotation), then undo the light's turn about Z
    world = dirs @ np.asarray(world_to_camera, np.float64)
    in_map = world @ sh_rotation.z_rotation(float(light["rotation_deg"]))  # R_z(rot)^T d as a row vector
    x, y, z = in_map[..., 0], in_map[..., 1], np.clip(in_map[..., 2], -1.0, 1.0)
    u = 0.5 - np.arctan2(y, x) / (2 * math.pi)
    v = 0.5 + np.arcsin(z) / math.pi
    col = u * sw - 0.5
    row = np.clip((1.0 - v) * sh_ - 0.5, 0.0, sh_ - 1.0)
    c0, r0 = np.floor(col).astype(int), np.floor(row).astype(int)
    fc, fr = (col - c0)[..., None], (row - r0)[..., None]
    c0, c1 = c0 % sw, (c0 + 1) % sw
    r1 = np.minimum(r0 + 1, sh_ - 1)
    top = source[r0, c0] * (1 - fc) + source[r0, c1] * fc
    bottom = source[r1, c0] * (1 - fc) + source[r1, c1] * fc
    return (float(light["scale"]) * (top * (1 - fr) + bottom * fr)).astype(np.float32)


def constant_colour(photo: np.ndarray, target_luminance: float) -> np.ndarray:
    """The photo's mean colour scaled to mean luminance `target_luminance`."""
    from relight.imaging.colour import luminance

    mean = photo.reshape(-1, 3).astype(np.float64).mean(axis=0)
    return mean * (target_luminance / float(luminance(mean)))


def angle_deg(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    cos = float(a @ b / (np.linalg.norm(a) * np.linalg.norm(b)))
    return math.degrees(math.acos(max(-1.0, min(1.0, cos))))


# ------------------------------------------------------------------ Cycles

class SphereRenderer:
    """One Blender scene: a Lambertian sphere and the photo camera; render(world) -> (rgb, coverage)."""

    def __init__(self, size: int, samples: int, work: Path):
        import sys

        import bpy

        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))
        from cycles_support import lambert_sphere, photo_camera  # the sphere and camera the tests render

        self.bpy, self.work, self.count = bpy, work, 0
        bpy.ops.wm.read_factory_settings(use_empty=True)
        scene = self.scene = bpy.context.scene
        scene.render.engine = "CYCLES"
        scene.cycles.device = "CPU"
        scene.cycles.samples = samples
        scene.cycles.use_denoising = True
        scene.render.resolution_x = scene.render.resolution_y = size
        scene.render.resolution_percentage = 100
        scene.render.film_transparent = True
        scene.view_settings.view_transform = "Standard"
        scene.render.image_settings.file_format = "OPEN_EXR"
        scene.render.image_settings.color_depth = "32"
        lambert_sphere(scene, ALBEDO)
        photo_camera(scene)

    def _world(self, pixels: np.ndarray | None, colour) -> None:
        bpy = self.bpy
        previous = self.scene.world
        world = bpy.data.worlds.new("light")  # a fresh World: Cycles reads its sampling settings once
        world.cycles.sampling_method = "MANUAL"
        world.cycles.sample_map_resolution = 2 * MAP_WIDTH
        nodes, links = world.node_tree.nodes, world.node_tree.links
        background = next(n for n in nodes if n.type == "BACKGROUND")
        background.inputs["Strength"].default_value = 1.0
        if pixels is None:
            background.inputs["Color"].default_value = (*map(float, colour), 1.0)
        else:
            h, w = pixels.shape[:2]
            image = bpy.data.images.new("light", w, h, float_buffer=True)
            image.colorspace_settings.name = "Linear Rec.709"  # first: it regenerates a generated image
            rgba = np.ones((h, w, 4), np.float32)
            rgba[..., :3] = pixels
            image.pixels.foreach_set(rgba[::-1].reshape(-1))
            image.update()
            texture = nodes.new("ShaderNodeTexEnvironment")
            texture.image = image
            links.new(texture.outputs["Color"], background.inputs["Color"])
        self.scene.world = world
        if previous is not None:
            bpy.data.worlds.remove(previous)

    def render(self, pixels: np.ndarray | None = None, colour=None):
        from relight.files.exr import read_exr

        self._world(pixels, colour)
        self.count += 1
        path = self.work / f"sphere_{self.count}.exr"
        self.scene.render.filepath = str(path)
        self.bpy.ops.render.render(write_still=True)
        planes = read_exr(path)
        path.unlink()
        return np.stack([planes[c] for c in "RGB"], -1).astype(np.float64), planes["A"]


# ------------------------------------------------------------------ the evaluation

def psnr(image, reference, mask) -> float:
    from model.scoring import metrics

    peak = float(np.percentile(reference[mask], 99))
    return metrics.psnr(image, reference, mask.astype(np.float64), peak=peak)


def evaluate(data: Path, model: str, quality: str, size: int, samples: int, limit: int | None) -> list[dict]:
    from relight.files import dataset
    from relight.lighting import sh, sh_projection
    from relight.lighting.light_map import irradiance_error, light_map
    from relight.network.quality import preset
    from relight.network.runtime import Relighter

    relighter = Relighter(model, working_size=preset(quality).working_size)
    rows = []
    with tempfile.TemporaryDirectory(prefix="eval_photo_light_") as work:
        renderer = SphereRenderer(size, samples, Path(work))
        for path in dataset.list_finished_scenes(data)[:limit]:
            scene = dataset.read_scene(path)
            w2c = scene.meta["camera"]["world_to_camera"]
            alpha = scene.alpha[..., 0] if scene.alpha.ndim == 3 else scene.alpha
            for k, photo in enumerate(scene.images):
                light = scene.lights[k]
                estimated = relighter.decompose(photo, alpha).light.astype(np.float64)
                truth = true_map(light, w2c)
                check = sh_projection.project_equirect(truth, 8, precision="float64")
                resample_error = float(np.linalg.norm(check - light["sh8"]) / np.linalg.norm(light["sh8"]))
                est_map = light_map(estimated, MAP_WIDTH)
                level = sh.mean_luminance(estimated)
                colour = constant_colour(photo, level)
                true_level = sh.mean_luminance(light["sh"])
                ours, coverage = renderer.render(est_map.pixels)
                reference, _ = renderer.render(truth)
                baseline, _ = renderer.render(None, colour)
                oracle, _ = renderer.render(light_map(light["sh"], MAP_WIDTH).pixels)
                mask = coverage > 0.999
                match = true_level / level if level > 0 else 1.0  # one factor for both: the level alone
                rows.append({
                    "scene": path.stem, "light": k, "map": light["name"],
                    "psnr_ours": psnr(ours, reference, mask), "psnr_constant": psnr(baseline, reference, mask),
                    "psnr_true_sh": psnr(oracle, reference, mask),
                    "psnr_ours_level_matched": psnr(ours * match, reference, mask),
                    "psnr_constant_level_matched": psnr(baseline * match, reference, mask),
                    "colour_error_ours_deg": angle_deg(estimated[0], light["sh"][0]),
                    "colour_error_constant_deg": angle_deg(colour, light["sh"][0]),
                    "level_ratio": level / true_level,
                    "map_irradiance_error": irradiance_error(estimated, est_map.pixels),
                    "truth_resample_error": resample_error,
                })
                r = rows[-1]
                print(f"{r['scene']} L{k} {r['map']:10s} ours {r['psnr_ours']:6.2f} dB  constant "
                      f"{r['psnr_constant']:6.2f} dB  colour {r['colour_error_ours_deg']:5.1f} / "
                      f"{r['colour_error_constant_deg']:5.1f} deg  level x{r['level_ratio']:.2f}", flush=True)
    return rows


def summary(rows: list[dict]) -> str:
    def mean(key):
        return statistics.fmean(r[key] for r in rows)

    def median(key):
        return statistics.median(r[key] for r in rows)

    better = sum(r["psnr_ours"] > r["psnr_constant"] for r in rows)
    lines = [
        "| World | sphere PSNR vs true map (dB) | level-matched (dB) | light colour error (deg, mean / median) |",
        "|---|---|---|---|",
        f"| (a) photo's estimated light | **{mean('psnr_ours'):.2f}** | {mean('psnr_ours_level_matched'):.2f} | "
        f"{mean('colour_error_ours_deg'):.1f} / {median('colour_error_ours_deg'):.1f} |",
        f"| (c) constant, photo's mean colour | {mean('psnr_constant'):.2f} | "
        f"{mean('psnr_constant_level_matched'):.2f} | {mean('colour_error_constant_deg'):.1f} / "
        f"{median('colour_error_constant_deg'):.1f} |",
        f"| (o) the true light's order-4 SH | {mean('psnr_true_sh'):.2f} | | 0 |",
        "",
        f"{len(rows)} images; (a) - (c): {mean('psnr_ours') - mean('psnr_constant'):+.2f} dB "
        f"({mean('psnr_ours_level_matched') - mean('psnr_constant_level_matched'):+.2f} level-matched), "
        f"(a) ahead on {better} of {len(rows)}; estimated / true mean luminance "
        f"{median('level_ratio'):.2f} (median); map irradiance error {mean('map_irradiance_error'):.2%} mean, "
        f"{max(r['map_irradiance_error'] for r in rows):.2%} max; true-map resampling vs sidecar sh8 "
        f"{max(r['truth_resample_error'] for r in rows):.2%} max.",
    ]
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", required=True, type=Path, help="held-out farm scenes (path-traced)")
    parser.add_argument("--model", default="relight/models/geometry.onnx")
    parser.add_argument("--quality", default="balanced", help="working size preset (relight/network/quality.py)")
    parser.add_argument("--size", type=int, default=64, help="sphere render side in pixels")
    parser.add_argument("--samples", type=int, default=64, help="Cycles samples (OIDN on)")
    parser.add_argument("--limit", type=int, default=None, help="first N scenes only")
    parser.add_argument("--json", type=Path, default=None, help="write the per-image rows here")
    args = parser.parse_args(argv)
    start = time.perf_counter()
    rows = evaluate(args.data, args.model, args.quality, args.size, args.samples, args.limit)
    if not rows:
        parser.error(f"{args.data}: no finished scenes with path-traced images")
    if args.json is not None:
        from relight.files.fileio import atomic_write_json

        atomic_write_json(args.json, rows, indent=1)
    print()
    print(summary(rows))
    print(f"\n{time.perf_counter() - start:.0f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
