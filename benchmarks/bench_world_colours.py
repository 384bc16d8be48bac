"""How saturated the World maps are, and what bounding their colour costs their irradiance.

    PYTHONPATH=. .venv/bin/python benchmarks/bench_world_colours.py [--width 512]

For the 18 bundled presets' order-4 SH and the shipped model's lights of the bundled photos
(evaluation/data/matte_eval, each preset: Draft, Balanced, Best), both World maps:
`relight light --lamp-free`'s single map (relight.lighting.light_map) and the smooth World
left after the key light (relight.lighting.key_light.split_light). Printed per group: the share
of lit texels (luminance >= 1 % of the brightest) with HSV saturation > 0.8 and the highest
saturation (median over the lights, and the largest), and the irradiance error against the
light's SH (relight.lighting.light_map.irradiance_error, key_light.split_irradiance_error at order 4).
It uses no module newer than the measure, so it runs on a tree from before issue 48 as well
(the figures of docs/EVALUATION.md, "The key light's direction and the World's colours").
"""

from __future__ import annotations

import argparse
import os
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
LUMINANCE = np.array([0.2126, 0.7152, 0.0722])


def lit_saturation(pixels) -> np.ndarray:
    rgb = np.asarray(pixels, np.float64).reshape(-1, 3)
    rgb = rgb[rgb @ LUMINANCE > 0.01 * float((rgb @ LUMINANCE).max())]
    top = rgb.max(axis=-1)
    return np.where(top > 0, (top - rgb.min(axis=-1)) / np.where(top > 0, top, 1.0), 0.0)


def lights():
    """(group, name, SH [25, 3])."""
    from relight.files.photo import read_photo
    from relight.lighting import presets, sh_projection
    from relight.lighting.envmap import load_equirect
    from relight.network import quality
    from relight.network.runtime import Relighter

    for name in presets.list_presets():
        pixels = load_equirect(presets.preset_path(name)).pixels[..., :3].astype(np.float64)
        yield "presets", name, sh_projection.project_equirect(pixels, 4, precision="float64")
    for key in ("draft", "balanced", "best"):
        preset = quality.preset(key)
        relighter = Relighter(str(quality.model_path(key)), working_size=preset.working_size)
        for path in sorted((REPO / "evaluation/data/matte_eval").glob("*.jpg")):
            image, _ = read_photo(path)
            light = relighter.decompose(image, **preset.decompose_options(working_size=False)).light
            yield f"bundled photos, {key}", path.stem, np.asarray(light, np.float64)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--width", type=int, default=512)
    args = parser.parse_args(argv)

    from relight.lighting import key_light
    from relight.lighting.light_map import irradiance_error, light_map

    groups: dict[str, list[dict]] = {}
    for group, _, L in lights():
        single = light_map(L, args.width).pixels
        split = key_light.split_light(L, args.width)
        s_single, s_world = lit_saturation(single), lit_saturation(split.pixels)
        groups.setdefault(group, []).append({
            "over": float(np.mean(s_single > 0.8)), "single": float(s_single.max()),
            "single_error": irradiance_error(L, single), "world_over": float(np.mean(s_world > 0.8)),
            "world": float(s_world.max()), "world_error": key_light.split_irradiance_error(split, 4)})
    print(f"width {args.width}; load average {os.getloadavg()[0]:.2f}\n")
    print("| lights | single map: lit texels > 0.8 | highest saturation, median (max) | irradiance error, mean (max) "
          "| World: lit texels > 0.8 | highest saturation, median (max) | irradiance error, mean |")
    print("|---|---|---|---|---|---|---|")
    for group, rows in groups.items():
        def col(key):
            return np.array([r[key] for r in rows])
        print(f"| {group} ({len(rows)}) | {100 * col('over').mean():.0f} % | {np.median(col('single')):.2f} "
              f"({col('single').max():.2f}) | {100 * col('single_error').mean():.2f} % "
              f"({100 * col('single_error').max():.2f} %) | {100 * col('world_over').mean():.0f} % | "
              f"{np.median(col('world')):.2f} ({col('world').max():.2f}) | {100 * col('world_error').mean():.2f} % |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
