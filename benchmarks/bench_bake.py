"""Benchmarks of the farm's scene half; prints markdown tables.

    .venv/bin/python benchmarks/bench_bake.py rays       # bake rays/s, 1 vs 2 threads
    .venv/bin/python benchmarks/bench_bake.py scene      # per-stage seconds, 256x256, K=4, 64 spp + denoise
    .venv/bin/python benchmarks/bench_bake.py directions # bake directions S vs error against S=4096
    .venv/bin/python benchmarks/bench_bake.py spp        # samples per pixel vs error against 1024 spp

Figures and the machine they came from are in docs/benchmarks/farm_scene.md.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


def dressed_mesh(seed: int = 0):
    """A posed, clothed body (bpy-free), as the bake sees it."""
    from farm.synthesis import appearance, bodies, poses
    from farm.rendering.bake import VertexMaterials

    rng = np.random.default_rng(seed)
    params = bodies.sample_body(rng)
    rest = bodies.build_body(params, None)
    axes = poses.RestAxes.from_joints(rest.joints, rest.bone_labels)
    body = bodies.build_body(params, poses.pose_deltas(poses.sample_pose(rng, axes, "walking"), rest.bone_labels))
    parts, _ = appearance.dress(body, rng)
    v = np.concatenate([p.vertices for p in parts])
    offsets = np.cumsum([0] + [len(p.vertices) for p in parts])
    f = np.concatenate([p.faces + offsets[i] for i, p in enumerate(parts)])
    n = np.concatenate([p.normals for p in parts])
    mats = VertexMaterials(
        roughness=np.concatenate([np.full(len(p.vertices), p.material["roughness"]) for p in parts]),
        metallic=np.concatenate([np.full(len(p.vertices), p.material["metallic"]) for p in parts]),
        specular=np.concatenate([np.full(len(p.vertices), 2 * p.material["specular_level"]) for p in parts]),
    )
    view = v.mean(axis=0) + np.array([0.0, -4.0, 0.0])
    return v, f, n, mats, view


def bench_rays(repeats: int) -> None:
    from farm.rendering import bake

    v, f, n, _, _ = dressed_mesh()
    S = 256
    dirs = bake.fibonacci_directions(S, np.random.default_rng(0))
    flat = np.flatnonzero((n @ dirs.T) > 0)
    points = v + 1e-3 * n
    print(f"mesh: {len(v)} vertices, {len(f)} triangles, S = {S} directions, {len(flat)} upper-hemisphere rays\n")
    # CPU seconds of this process (all threads) tell how fast a core is when it
    # is ours; wall seconds are what the shared, loaded machine gave.
    print("| threads | ray wall (s) | rays/s wall (M) | ray CPU (s) | rays per CPU-second (M) |")
    print("|---|---|---|---|---|")
    for threads in (1, 2):
        tester = bake.OcclusionTester(v, f, threads)
        best = None
        for _ in range(repeats):
            cpu0, wall0 = time.process_time(), time.perf_counter()
            tester.occluded_pairs(points, dirs, flat // S, flat % S)
            wall, cpu = time.perf_counter() - wall0, time.process_time() - cpu0
            if best is None or wall < best[0]:
                best = (wall, cpu)
        wall, cpu = best
        print(f"| {threads} | {wall:.3f} | {len(flat) / wall / 1e6:.2f} | {cpu:.3f} | {len(flat) / cpu / 1e6:.2f} |")
    r = bake.bake_transport(v, f, n, 4, S, rng=np.random.default_rng(0))
    print(f"\nwhole diffuse bake_transport (all {len(v)} vertices active): {r.seconds:.2f} s wall, of which rays {r.ray_seconds:.2f} s")


DIRECTION_COUNTS = (64, 128, 256, 512, 1024)
DIRECTION_REFERENCE = 4096


def directions_rows(counts=DIRECTION_COUNTS, reference: int = DIRECTION_REFERENCE) -> tuple[str, list[dict]]:
    """(description, rows): per bake kind and S, the error of T.L against S = `reference`.

    Rows: {"bake", "S", "mean", "p99", "seconds"}; error is |T.L - T_ref.L| of a white
    surface under the 'park' map at mean luminance 0.8, over the mesh's vertices.
    """
    from farm.rendering import bake
    from relight.lighting import presets, sh, sh_projection
    from relight.network import prt
    from relight.lighting.envmap import load_equirect

    v, f, n, mats, view = dressed_mesh()
    park = load_equirect(presets.preset_path("park")).pixels
    L = sh.normalize_reference(sh_projection.project_equirect(park, 4))[0]  # to sh.REFERENCE_LUMINANCE
    info = (f"mesh: {len(v)} vertices; error of T.L (white surface, 'park' map at mean luminance 0.8)\n"
            f"against S = {reference}; same random rotation family, different draws")
    rows = []
    for label, kw in (("diffuse", {}), ("view-dependent", {"materials": mats, "view_point": view})):
        ref = bake.bake_transport(v, f, n, 4, reference, rng=np.random.default_rng(99), **kw)
        ref_shade = prt.shading(ref.transport, L)
        for S in counts:
            r = bake.bake_transport(v, f, n, 4, S, rng=np.random.default_rng(S), **kw)
            err = np.abs(prt.shading(r.transport, L) - ref_shade)
            rows.append({"bake": label, "S": S, "mean": float(err.mean()),
                         "p99": float(np.percentile(err, 99)), "seconds": r.seconds})
    return info, rows


def bench_directions() -> None:
    info, rows = directions_rows()
    print(info + "\n")
    print("| bake | S | mean abs error | 99th pct abs error | bake seconds |")
    print("|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['bake']} | {r['S']} | {r['mean']:.4f} | {r['p99']:.4f} | {r['seconds']:.2f} |")


def bench_scene(resolution: int, lights: int, samples: int) -> None:
    import bpy  # noqa: F401

    from farm.synthesis import bodies
    from farm.scene import SceneOptions, render_scene

    t = time.perf_counter()
    bodies.body_model()
    print(f"anny model load (cache warm): {time.perf_counter() - t:.2f} s\n")
    with tempfile.TemporaryDirectory() as tmp:
        # A first scene warms up Warp's skinning kernel and Cycles' kernels.
        render_scene(0, 1, SceneOptions(resolution=32, lights=1, samples=1, denoise=False), Path(tmp))
        opts = SceneOptions(resolution=resolution, lights=lights, samples=samples, denoise=True)
        t = time.perf_counter()
        path = render_scene(1, 1, opts, Path(tmp))
        wall = time.perf_counter() - t
        meta = json.loads(path.read_text())
    timings = meta["timings"]
    pt_calls = timings["path_trace_render_calls"]
    b = meta["bake"]
    print(f"scene {resolution}x{resolution}, K = {lights}, {samples} spp + OIDN, {meta['geometry']['vertices']} vertices"
          f" ({b.get('baked_vertices')} baked), {b.get('rays')} rays, bake {b['specular']}\n")
    print("| stage | seconds |")
    print("|---|---|")
    for key, value in timings.items():
        if isinstance(value, list):
            value = " + ".join(f"{x:.2f}" for x in value)
            print(f"| {key} | {value} |")
        else:
            print(f"| {key} | {value:.3f} |")
    print(f"| wall (incl. EXR/JSON write) | {wall:.3f} |")
    outside = 1.0 - sum(pt_calls) / wall
    print(f"\nshare of wall time outside the path-traced render calls: {outside:.1%}")


SPP_COUNTS = (16, 32, 64, 128, 256)
SPP_REFERENCE = 1024
# (label, denoise, OIDN guide prefilter): farm.synthesis.scene_options.DENOISE_PREFILTERS
DENOISE_MODES = (("off", False, "fast"), ("OIDN fast", True, "fast"), ("OIDN accurate", True, "accurate"))


def spp_rows(resolution: int, counts=SPP_COUNTS, reference: int = SPP_REFERENCE) -> tuple[str, list[dict]]:
    """(description, rows): one scene's path-traced image at several spp against `reference` spp.

    Rows: {"spp", "denoise", "error", "seconds"}, denoise one of DENOISE_LABELS; error =
    mean |I - I_ref| / mean I_ref over the person's pixels only (the visible map behind is
    noise-free).
    """
    import bpy

    from farm.rendering import passes
    from farm.scene import SceneOptions, render_scene
    from relight.files import dataset

    with tempfile.TemporaryDirectory() as tmp:
        path = render_scene(2, 1, SceneOptions(resolution=resolution, lights=1, samples=1, denoise=False,
                                               passes=frozenset({"pt"})), Path(tmp))
        person = dataset.read_scene(path).alpha[..., 0] > 0.999
        scene = bpy.context.scene
        work = Path(tmp)
        ref = passes.render_path_traced(scene, work, "ref", reference, False).image[person]
        info = (f"{resolution}x{resolution}, one scene, error = mean |I - I_ref| / mean I_ref over the person's"
                f" {int(person.sum())} pixels, reference {reference} spp without denoising")
        rows = []
        for spp in counts:
            for label, denoise, prefilter in DENOISE_MODES:
                r = passes.render_path_traced(scene, work, f"s{spp}", spp, denoise, prefilter=prefilter)
                err = np.abs(r.image[person] - ref).mean() / np.abs(ref).mean()
                rows.append({"spp": spp, "denoise": label, "error": float(err), "seconds": r.seconds})
    return info, rows


def bench_spp(resolution: int) -> None:
    info, rows = spp_rows(resolution)
    print(info + "\n")
    print("| spp | denoise | relative error | render seconds |")
    print("|---|---|---|---|")
    for r in rows:
        print(f"| {r['spp']} | {r['denoise']} | {r['error']:.4f} | {r['seconds']:.2f} |")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("what", choices=["rays", "scene", "directions", "spp"])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--resolution", type=int, default=256)
    parser.add_argument("--lights", type=int, default=4)
    parser.add_argument("--samples", type=int, default=64)
    args = parser.parse_args()
    if args.what == "rays":
        bench_rays(args.repeats)
    elif args.what == "directions":
        bench_directions()
    elif args.what == "scene":
        bench_scene(args.resolution, args.lights, args.samples)
    else:
        bench_spp(args.resolution)


if __name__ == "__main__":
    main()
