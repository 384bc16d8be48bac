"""The farm's Cycles stage, one change at a time, and the samples-per-pixel trade.

    .venv/bin/python benchmarks/bench_farm_render.py calls --res 128 --samples 16
    .venv/bin/python benchmarks/bench_farm_render.py calls --res 256 --samples 64
    .venv/bin/python benchmarks/bench_farm_render.py spp --res 128

`calls`: one farm scene is sampled, baked and built in this process (farm.scene's
own steps), then each light's path-traced render call is timed under variants
that differ from the farm's current setting by one change, in rounds so that
every variant sees the same machine state:

- "automatic map": the World left on Cycles' automatic importance map (what the
  farm did before; Blender 5.0 builds 4096 x 2048 for a map without a sun);
- "zip-compressed EXR": the scratch EXR compressed (what the farm did before);
- "farm" (the current setting): a fresh World per light, map at the HDR map's
  own resolution, uncompressed scratch EXR;
- "no denoiser": OIDN off (its share of a call);
- "no EXR file": the render kept in memory, not written (Blender cannot hand a
  render result to Python in background mode; this bounds what reading from
  memory could save);
- "same World": the render call repeated without a light change (what a call
  costs when nothing has to be synced: the floor).
Each variant's time is split into Cycles' render call and the EXR read-back.

`spp`: PSNR of the person's pixels against a 1024-spp reference (no denoiser)
for several spp, with and without OIDN, under the farm's importance map and
Cycles' automatic one, and the time per render call; a few scenes, each at its
own first light.

The machine may be shared: compare rows of one run, not across runs.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np


def _build(index: int, seed: int, options, work: Path):
    """A farm scene in Blender: reset, sample, bake, build, geometry pass (farm.scene's steps)."""
    from farm.rendering import blender_scene, passes
    from farm.synthesis import lights
    from farm.scene import bake_scene, build_blender_scene, render_buffers, sample_scene

    scene = blender_scene.reset_scene()
    sample = sample_scene(index, seed, options,
                          render_sky=lambda p: passes.render_sky_equirect(p, lights.SKY_SIZE, work))
    baked = bake_scene(sample, passes.thread_count())
    spec = build_blender_scene(scene, sample, baked)
    channels, _ = render_buffers(scene, sample, spec, baked, work)
    return scene, sample, channels


def _set_light(scene, light, name: str, automatic_map: bool) -> None:
    from farm.rendering import blender_scene

    blender_scene.set_environment_world(scene, None, light.rotation_deg, light.scale, pixels=light.pixels, name=name)
    if automatic_map:
        # Before Cycles first syncs this World: the pre-fix farm's setting.
        scene.world.cycles.sampling_method = "AUTOMATIC"


def _timed_call(scene, work: Path, samples: int, denoise: bool, prefilter: str,
                write: bool = True) -> tuple[float, float]:
    """(render call seconds, EXR read-back seconds) of one path-traced render."""
    import bpy

    from farm.rendering import passes

    if not write:  # the same render kept in memory (unreadable from Python in background mode)
        scene.cycles.samples, scene.cycles.use_denoising = samples, denoise
        t0 = time.perf_counter()
        bpy.ops.render.render(write_still=False)
        return time.perf_counter() - t0, 0.0

    original = passes.read_exr
    read_seconds = []

    def timed_read(path):
        t0 = time.perf_counter()
        out = original(path)
        read_seconds.append(time.perf_counter() - t0)
        return out

    passes.read_exr = timed_read
    try:
        t0 = time.perf_counter()
        passes.render_path_traced(scene, work, "bench", samples, denoise, prefilter=prefilter)
        total = time.perf_counter() - t0
    finally:
        passes.read_exr = original
    return total - sum(read_seconds), sum(read_seconds)


VARIANTS = ("automatic map", "zip-compressed EXR", "farm", "no denoiser", "no EXR file", "same World")


def bench_calls(args) -> None:
    from farm.rendering import passes
    from farm.synthesis.scene_options import SceneOptions

    options = SceneOptions(resolution=args.res, lights=2, samples=args.samples)
    rows = {v: [] for v in VARIANTS}
    for index in range(args.first, args.first + args.scenes):
        work = Path(tempfile.mkdtemp(prefix="bench_farm_render_"))
        scene, sample, _ = _build(index, args.seed, options, work)
        for round_ in range(args.rounds):
            for variant in VARIANTS:
                light = sample.lights[round_ % len(sample.lights)]
                scene.render.image_settings.exr_codec = "ZIP" if variant == "zip-compressed EXR" else "NONE"
                if variant != "same World":
                    _set_light(scene, light, f"{variant}{round_}", automatic_map=variant == "automatic map")
                call, read = _timed_call(scene, work, args.samples, variant != "no denoiser", "fast",
                                         write=variant != "no EXR file")
                rows[variant].append((call, read))
    print(f"# {args.res}x{args.res}, {args.samples} spp, {args.scenes} scenes x {args.rounds} rounds, "
          f"Cycles threads: {passes.thread_count() or 'all'}; seconds per path-traced render call (median)")
    print("| variant | render call | EXR read-back | total | x farm |")
    print("|---|---|---|---|---|")
    farm_total = statistics.median(c + r for c, r in rows["farm"])
    for variant in VARIANTS:
        calls = [c for c, _ in rows[variant]]
        reads = [r for _, r in rows[variant]]
        total = statistics.median(c + r for c, r in rows[variant])
        print(f"| {variant} | {statistics.median(calls):.3f} | {statistics.median(reads):.3f} | {total:.3f} "
              f"| {total / farm_total:.2f} |")


def psnr(image: np.ndarray, reference: np.ndarray, mask: np.ndarray) -> float:
    """model.scoring.metrics.psnr over the masked pixels, peak = the reference's 99th percentile there (HDR-safe)."""
    from model.scoring import metrics

    peak = float(np.percentile(reference[mask], 99.0))
    return metrics.psnr(image, reference, mask.astype(np.float64), peak=peak)


REFERENCE_SEED = 7919


def bench_spp(args) -> None:
    from farm.rendering import blender_scene, passes
    from farm.synthesis.scene_options import SceneOptions

    counts = [int(c) for c in args.counts.split(",")]
    maps = args.maps.split(",")  # "automatic" or an oversampling factor of the map's own width
    results = {(m, spp, dn): [] for m in maps for spp in counts for dn in (False, True)}
    options = SceneOptions(resolution=args.res, lights=1, samples=1, denoise=False)
    for index in range(args.first, args.first + args.scenes):
        work = Path(tempfile.mkdtemp(prefix="bench_farm_render_"))
        scene, sample, channels = _build(index, args.seed, options, work)
        person = channels["alpha"] > 0.999
        # Another sampling seed: with the farm's seed the reference's first N samples would be
        # the N-spp image itself (same sequence), and the image would look closer than it is.
        scene.cycles.seed = REFERENCE_SEED
        reference = passes.render_path_traced(scene, work, "ref", args.reference, False).image
        scene.cycles.seed = 0
        for m in maps:
            if m != "automatic":
                blender_scene.IMPORTANCE_MAP_OVERSAMPLING = int(m)
            _set_light(scene, sample.lights[0], f"spp_{m}", automatic_map=m == "automatic")
            t0 = time.perf_counter()
            passes.render_path_traced(scene, work, "first", counts[0], False)
            first_call = time.perf_counter() - t0
            for spp in counts:
                for denoise in (False, True):
                    t0 = time.perf_counter()
                    image = passes.render_path_traced(scene, work, "s", spp, denoise, prefilter="fast").image
                    results[(m, spp, denoise)].append(
                        (psnr(image, reference, person), time.perf_counter() - t0, first_call))
    print(f"# {args.res}x{args.res}, {args.scenes} scenes, PSNR on the person's pixels against "
          f"{args.reference} spp without denoising (peak: the reference's 99th percentile); mean over scenes; "
          "importance map: N = N x the HDR map's own width, automatic = Cycles' default (4096 wide)")
    print(f"| map | spp | denoiser | PSNR dB | seconds per call (no light change) "
          f"| first {counts[0]}-spp call after the light change |")
    print("|---|---|---|---|---|---|")
    for m in maps:
        for spp in counts:
            for denoise in (False, True):
                values = results[(m, spp, denoise)]
                print(f"| {m} | {spp} | {'OIDN' if denoise else 'off'} | {statistics.fmean(v[0] for v in values):.2f} "
                      f"| {statistics.fmean(v[1] for v in values):.3f} | {statistics.fmean(v[2] for v in values):.3f} |")


def main() -> None:
    import shutil

    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["calls", "spp"])
    parser.add_argument("--res", type=int, default=128)
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--scenes", type=int, default=3)
    parser.add_argument("--first", type=int, default=1)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--rounds", type=int, default=4)
    parser.add_argument("--counts", default="4,8,16,32,64,128")
    parser.add_argument("--reference", type=int, default=1024)
    parser.add_argument("--maps", default="1,2,4,automatic",
                        help="comma list: importance-map oversampling factors and/or 'automatic'")
    args = parser.parse_args()
    scratch = tempfile.mkdtemp(prefix="bench_farm_render_")
    tempfile.tempdir = scratch  # every scene's scratch folder lands here and goes with it
    try:
        bench_calls(args) if args.what == "calls" else bench_spp(args)
    finally:
        tempfile.tempdir = None
        shutil.rmtree(scratch, ignore_errors=True)


if __name__ == "__main__":
    main()
