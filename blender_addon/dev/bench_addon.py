"""Benchmark of the add-on's interactive paths under headless bpy; prints tables.

    python -m blender_addon.dev.bench_addon [--model MODEL.onnx] [--size 1536x1024] [--repeat 5]

Without --model it exports a RelightNet of the default architecture with
seeded random weights (export.random_model, in a child process): the cost of
a network run depends on the architecture, not on the weights' values.
Measures: the network per quality preset; one dial change (relight from the
cached decomposition + strength blend + writing the Blender image), split
into its parts; reading the World (environment texture) and baking a
procedural one. Not shipped in the extension zip (only top-level modules are).
"""

from __future__ import annotations

import argparse
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]


def _timed(fn, repeat: int) -> tuple[float, float]:
    times = []
    for _ in range(repeat):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return statistics.median(times), min(times)


def _export_default_model(folder: Path) -> Path:
    out = folder / "random_default.onnx"
    code = f"from export.random_model import export_random_model; export_random_model({str(out)!r}, seed=0)"
    subprocess.run([sys.executable, "-c", code], cwd=REPO, check=True, capture_output=True)
    return out


def _person_photo(h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """(photo, mask of the figure): an ellipse 40% of the width, 83% of the height."""
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    inside = ((x - w / 2) / (w / 5)) ** 2 + ((y - h / 2) / (h / 2.4)) ** 2 <= 1
    photo = np.stack([0.05 + 0.1 * (x / w), 0.08 + 0.05 * (y / h), np.full_like(x, 0.12)], axis=2)
    photo[inside] = (0.6, 0.4, 0.3)
    return photo.astype(np.float32), inside.astype(np.float32)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default=None)
    parser.add_argument("--size", default="1536x1024", help="photo HxW")
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--qualities", default="DRAFT,BALANCED,BEST",
                        help="presets to time the network for (BALANCED is always run: the dial table uses it)")
    args = parser.parse_args(argv)
    h, w = (int(v) for v in args.size.lower().split("x"))

    import bpy  # imported before the add-on modules that need it

    from blender_addon.blender import bl_images, bl_world
    from blender_addon.worker import engine
    from blender_addon.logic import light_sources, pixel_buffers, quality
    from relight.lighting import presets

    tmp = Path(tempfile.mkdtemp(prefix="bench_addon_"))
    model = Path(args.model) if args.model else _export_default_model(tmp)
    relighter = engine.open_relighter(str(model))
    photo, figure = _person_photo(h, w)
    print(f"photo {h}x{w}, model {model.name} (SH order {relighter.sh_order}), "
          f"median and best of {args.repeat}\n")

    print("| quality | working size | network s (median) | best |")
    print("|---|---|---|---|")
    decompositions = {}
    wanted = set(args.qualities.upper().split(",")) | {"BALANCED"}
    for key, label, _ in quality.enum_items():
        if key not in wanted:
            continue
        size = quality.preset(key).working_size
        engine.decompose(relighter, photo, None, size)  # warm-up
        med, best = _timed(lambda: decompositions.__setitem__(
            key, engine.decompose(relighter, photo, None, size)), args.repeat)
        print(f"| {label} | {size} | {med:.3f} | {best:.3f} |")

    d = decompositions["BALANCED"]
    light = light_sources.preset_light("studio", relighter.sh_order)
    angle = iter(range(10 ** 6))
    relit_holder = {}

    def relight_step():
        relit_holder["r"] = engine.relight(d, light, float(next(angle)), 0.0)

    def blend_step():
        relit_holder["b"] = pixel_buffers.blend(relit_holder["r"], photo, 0.8)

    def write_step():
        bl_images.write_image("bench.relit", relit_holder["b"])

    relight_step(); blend_step(); write_step()  # noqa: E702  (warm-up)
    # a random network finds no person, so its crop is the whole frame (the
    # worst case); with the figure as mask the runtime works on its box only
    masked = engine.decompose(relighter, photo, figure, quality.preset("BALANCED").working_size)
    rows = [("relight (runtime, full resolution)", _timed(relight_step, args.repeat)),
            ("  same, crop = the figure's box (mask)",
             _timed(lambda: engine.relight(masked, light, float(next(angle)), 0.0), args.repeat)),
            ("strength blend", _timed(blend_step, args.repeat)),
            ("write Blender image", _timed(write_step, args.repeat))]
    total = sum(r[1][0] for r in rows if not r[0].startswith("  "))
    print(f"\nOne dial change at Balanced ({d.working_size[0]}x{d.working_size[1]} working, "
          f"{h}x{w} output):\n")
    print("| step | s (median) | best | share |")
    print("|---|---|---|---|")
    for name, (med, best) in rows:
        share = "" if name.startswith("  ") else f"{med / total:.0%}"
        print(f"| {name} | {med:.4f} | {best:.4f} | {share} |")
    print(f"| total | {total:.4f} | | |")

    world = bpy.data.worlds.new("bench_world")
    tree = world.node_tree
    bg = next(n for n in tree.nodes if n.type == "BACKGROUND")
    env = tree.nodes.new("ShaderNodeTexEnvironment")
    env.image = bpy.data.images.load(str(presets.preset_path("studio")))
    tree.links.new(env.outputs["Color"], bg.inputs["Color"])
    read = _timed(lambda: light_sources.equirect_light(bl_world.read_world(world).equirect, relighter.sh_order),
                  args.repeat)
    sky = bpy.data.worlds.new("bench_sky")
    bg = next(n for n in sky.node_tree.nodes if n.type == "BACKGROUND")
    node = sky.node_tree.nodes.new("ShaderNodeTexSky")
    sky.node_tree.links.new(node.outputs["Color"], bg.inputs["Color"])
    baked = _timed(lambda: light_sources.equirect_light(bl_world.read_world(sky).equirect, relighter.sh_order),
                   args.repeat)
    print("\nWorld -> SH light:\n")
    print("| world | s (median) | best |")
    print("|---|---|---|")
    print(f"| environment texture (512x256 EXR), read + project | {read[0]:.4f} | {read[1]:.4f} |")
    print(f"| Sky Texture, Cycles bake 128x64 + project | {baked[0]:.4f} | {baked[1]:.4f} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
