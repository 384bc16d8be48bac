"""The light as a World map: per-band windows against relight.lighting.light_map's fit.

    .venv/bin/python benchmarks/bench_light_map.py [--data DATA/heldout_light128] [--lambdas]

An order-4 SH light evaluated on the sphere rings below 0; a World texel cannot
be negative. For three sets of lights (the 18 bundled presets projected at
order 4; with --data, the shipped model's estimates on the held-out scenes'
path-traced images, the scene's alpha as the mask; three extreme lights: a
delta, a white directional light without ambient, the camera-left light of
tests/blender_addon/test_addon_photo_world_cycles.py), each way of making a map >= 0 is scored by
the irradiance error of its map against the light's SH irradiance
(relight.lighting.light_map.irradiance_error, relative RMS over all normals) and by how
often it needed clamping:

- clamp: the SH itself, negative texels set to 0;
- hanning, lanczos: the fixed windows of relight.lighting.sh.window, then clamped
  where still negative;
- smallest heat window: sigma_l = exp(-t l(l+1)) with the smallest t that
  makes every texel >= 0 (bisection; the heat equation's minimum principle
  makes the minimum rise with t), never clamped;
- fit: relight.lighting.light_map (what `relight light` and the add-on use).

--lambdas repeats the fit for several regularisation weights (the choice of
relight.lighting.light_map.REGULARISATION) and prints the hot spot's peak over the mean.
Timings are wall-clock per light on a possibly shared machine: compare within a run.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
import time
from pathlib import Path

import numpy as np

from relight.lighting import light_map as lm
from relight.lighting import presets, sh, sh_projection
from relight.lighting.light import directional_light, sh_light

ORDER = 4
WIDTH = 512
BAND = np.repeat(np.arange(ORDER + 1), 2 * np.arange(ORDER + 1) + 1)


def evaluate(coeffs):
    """The light's SH on the map's texels (float64 [H, W, 3])."""
    dirs, _ = sh_projection.equirect_directions(WIDTH // 2, WIDTH)
    return sh.sh_basis(dirs, ORDER) @ coeffs


def windowed(coeffs, sigma):
    return coeffs * sigma[BAND][:, None]


def heat_sigma(t):
    l = np.arange(ORDER + 1)
    return np.exp(-t * l * (l + 1))


def smallest_heat_window(coeffs):
    if evaluate(coeffs).min() >= 0:
        return np.ones(ORDER + 1)
    hi = 1e-3
    while evaluate(windowed(coeffs, heat_sigma(hi))).min() < 0:
        hi *= 2
    lo = 0.0
    for _ in range(30):
        mid = 0.5 * (lo + hi)
        if evaluate(windowed(coeffs, heat_sigma(mid))).min() >= 0:
            hi = mid
        else:
            lo = mid
    return heat_sigma(hi)


def methods():
    def clamped(sigma_of):
        def make(coeffs):
            values = evaluate(windowed(coeffs, sigma_of(coeffs)))
            return np.maximum(values, 0.0), bool(values.min() < 0)
        return make

    return {
        "clamp": clamped(lambda c: np.ones(ORDER + 1)),
        "hanning": clamped(lambda c: sh.window(ORDER, "hanning")),
        "lanczos": clamped(lambda c: sh.window(ORDER, "lanczos")),
        "smallest heat window": clamped(smallest_heat_window),
        "fit (relight.lighting.light_map)": lambda c: (lm.light_map(c, WIDTH).pixels, False),
    }


def network_lights(data: Path, model: str, quality: str):
    from relight.files import dataset
    from relight.network.quality import preset
    from relight.network.runtime import Relighter

    relighter = Relighter(model, working_size=preset(quality).working_size)
    out = []
    for path in dataset.list_finished_scenes(data):
        scene = dataset.read_scene(path)
        alpha = scene.alpha[..., 0] if scene.alpha.ndim == 3 else scene.alpha
        for k, image in enumerate(scene.images):
            out.append((f"{path.stem} L{k}", relighter.decompose(image, alpha).light.astype(np.float64)))
    return out


def light_sets(args):
    sets = {"presets": [(n, sh_light(n, ORDER)) for n in presets.list_presets()]}
    if args.data is not None:
        sets["held-out estimates"] = network_lights(args.data, args.model, args.quality)
    sets["extreme"] = [
        ("delta", np.outer(sh.sh_basis(np.array([0.3, -0.5, 0.8]), ORDER), [1.0, 1.0, 1.0])),
        ("directional, no ambient", directional_light(-90.0, ORDER, 20.0, 0.0)),
        ("camera-left + ambient", directional_light(-90.0, ORDER, 20.0, 0.2)),
    ]
    return sets


def table(sets) -> str:
    lines = ["| lights | method | clamped | irradiance error mean | max | ms per light |", "|---|---|---|---|---|---|"]
    for set_name, lights in sets.items():
        for name, make in methods().items():
            errors, clamps, seconds = [], 0, []
            for _, coeffs in lights:
                t0 = time.perf_counter()
                pixels, was_clamped = make(coeffs)
                seconds.append(time.perf_counter() - t0)
                errors.append(lm.irradiance_error(coeffs, pixels))
                clamps += was_clamped
            lines.append(f"| {set_name} ({len(lights)}) | {name} | {clamps} | {statistics.fmean(errors):.2%} | "
                         f"{max(errors):.2%} | {1000 * statistics.median(seconds):.0f} |")
    return "\n".join(lines)


def lambda_table(sets) -> str:
    lines = ["| lambda | " + " | ".join(f"{s}: error mean / max, peak / mean" for s in sets) + " |",
             "|---" * (len(sets) + 1) + "|"]
    default = lm.REGULARISATION
    try:
        for lam in (1e-6, 1e-5, 1e-4, 1e-3, 1e-2):
            lm.REGULARISATION = lam
            cells = []
            for lights in sets.values():
                errors, peaks = [], []
                for _, coeffs in lights:
                    pixels = lm.light_map(coeffs, WIDTH).pixels
                    errors.append(lm.irradiance_error(coeffs, pixels))
                    mean = float(coeffs[0].max()) / (2 * math.sqrt(math.pi))
                    peaks.append(float(pixels.max()) / mean)
                cells.append(f"{statistics.fmean(errors):.2%} / {max(errors):.2%}, {max(peaks):.0f}")
            lines.append(f"| {lam:g} | " + " | ".join(cells) + " |")
    finally:
        lm.REGULARISATION = default
    return "\n".join(lines)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, default=None, help="held-out farm scenes (path-traced)")
    parser.add_argument("--model", default="relight/models/geometry.onnx")
    parser.add_argument("--quality", default="balanced")
    parser.add_argument("--lambdas", action="store_true", help="also scan the fit's regularisation")
    args = parser.parse_args(argv)
    sets = light_sets(args)
    print(f"load average before: {os.getloadavg()[0]:.2f}")
    print(table(sets))
    if args.lambdas:
        print()
        print(lambda_table(sets))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
