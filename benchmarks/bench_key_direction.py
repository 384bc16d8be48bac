"""How far the key light points from the true light: held-out hard-light farm scenes, every preset.

    python -m farm --out DATA --scenes 24 --seed 4801 --res 128 --lights 2 --samples 16 --framing all \
        --hard-lights 1.0 --workers 1 --passes pt
    PYTHONPATH=. .venv/bin/python benchmarks/bench_key_direction.py --data DATA [--presets draft,balanced,best]
        [--mask matte|alpha] [--estimators] [--lights-cache FILE.npz]

For every path-traced image of every scene in DATA whose light is a hard light
(farm/synthesis/hard_lights.py: a sun, a studio key with a fill, a lamp), the runtime
decomposes the image at each preset (its model, working size, augmentations and refinement;
the preset's person matte, as `relight light`; --mask alpha: the scene's alpha, the light
alone, as benchmarks/eval_photo_light.py) and relight.lighting.key_light.fit_key points the key. The
truth is the sidecar's first lobe (the sun, the studio key, the lamp: `hard.lobes[0]
.direction_camera`, the photo-camera frame of the estimated light). Printed: per preset and
framing, the median and worst angle between the two. --estimators adds the candidate
direction estimates compared when the key's direction was chosen (docs/EVALUATION.md, "The key
light's direction and the World's colours"); --lights-cache keeps the estimated lights between runs.
"""

from __future__ import annotations

import argparse
import math
import os
import statistics
from pathlib import Path

import numpy as np

FRAMINGS = ("full-body", "three-quarter", "waist-up", "head-and-shoulders", "face")


def angle_deg(a, b) -> float:
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    return math.degrees(math.acos(max(-1.0, min(1.0, float(a @ b / np.linalg.norm(a) / np.linalg.norm(b))))))


def estimate_lights(data: Path, preset_keys, mask: str) -> list[dict]:
    """One record per hard-light image: framing, kind, true direction, the estimated light per preset
    (mask "matte": the preset's person matte finds the person, as `relight light`; "alpha": the
    scene's own alpha)."""
    from relight.files import dataset
    from relight.network import quality
    from relight.network.runtime import Relighter

    records = []
    scenes = [dataset.read_scene(path) for path in dataset.list_finished_scenes(data)]
    for scene in scenes:
        for k, light in enumerate(scene.lights):
            if light.get("source") != "hard":
                continue
            records.append({"scene": scene.index, "image": k, "framing": scene.meta["camera"]["framing"],
                            "kind": light["hard"]["kind"],
                            "truth": np.asarray(light["hard"]["lobes"][0]["direction_camera"], np.float64),
                            "lights": {}})
    for key in preset_keys:
        preset = quality.preset(key)
        relighter = Relighter(str(quality.model_path(key)), working_size=preset.working_size)
        options = preset.decompose_options(working_size=False)
        by_scene = {scene.index: scene for scene in scenes}
        for record in records:
            scene = by_scene[record["scene"]]
            alpha = scene.alpha[..., 0] if scene.alpha.ndim == 3 else scene.alpha
            image = scene.images[record["image"]]
            d = relighter.decompose(image, alpha if mask == "alpha" else None, **options)
            record["lights"][key] = np.asarray(d.light, np.float64)
    return records


def save(records, path: Path) -> None:
    flat = {}
    for i, r in enumerate(records):
        flat[f"{i}/meta"] = np.array([r["scene"], r["image"], r["framing"], r["kind"]])
        flat[f"{i}/truth"] = r["truth"]
        for key, L in r["lights"].items():
            flat[f"{i}/light/{key}"] = L
    np.savez(path, **flat)


def load(path: Path) -> list[dict]:
    with np.load(path) as z:
        count = len({name.split("/")[0] for name in z.files})
        records = []
        for i in range(count):
            scene, image, framing, kind = z[f"{i}/meta"].tolist()
            lights = {name.rsplit("/", 1)[1]: z[name] for name in z.files if name.startswith(f"{i}/light/")}
            records.append({"scene": int(scene), "image": int(image), "framing": framing, "kind": kind,
                            "truth": z[f"{i}/truth"], "lights": lights})
    return records


def estimators() -> dict:
    """name -> (light [n, 3] -> unit direction): fit_key as shipped, and the candidates compared."""
    from relight.lighting import key_light as kl

    out = {"fit_key (shipped)": lambda L: kl.fit_key(L).direction,
           "band-1 vector": lambda L: kl.key_direction(L, bands=1)}
    for bands in (2, 3, 4):
        for window in (None, "hanning", "lanczos"):
            out[f"peak of bands 1-{bands}, {window or 'unwindowed'}{' (before)' if (bands, window) == (2, None) else ''}"] = \
                lambda L, b=bands, w=window: kl.key_direction(L, bands=b, window=w)
    return out


def table(records, preset_keys, estimate) -> list[tuple]:
    rows = []
    for key in preset_keys:
        errors = {f: [] for f in FRAMINGS}
        for r in records:
            errors[r["framing"]].append(angle_deg(estimate(r["lights"][key]), r["truth"]))
        every = [e for f in FRAMINGS for e in errors[f]]
        for framing in (*FRAMINGS, "all"):
            e = every if framing == "all" else errors[framing]
            if e:
                rows.append((key, framing, len(e), statistics.median(e), max(e)))
    return rows


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--data", type=Path, required=True, help="held-out farm scenes with hard lights")
    parser.add_argument("--presets", default="draft,balanced,best")
    parser.add_argument("--mask", choices=("matte", "alpha"), default="matte",
                        help="the person: found by the preset's matte, as `relight light` (default), or the "
                             "scene's alpha (the light alone)")
    parser.add_argument("--estimators", action="store_true", help="also the candidate direction estimates")
    parser.add_argument("--lights-cache", type=Path, default=None,
                        help="an .npz of the estimated lights: read when it exists, else written")
    args = parser.parse_args(argv)
    preset_keys = [p.strip() for p in args.presets.split(",") if p.strip()]

    if args.lights_cache is not None and args.lights_cache.is_file():
        records = load(args.lights_cache)
    else:
        records = estimate_lights(args.data, preset_keys, args.mask)
        if args.lights_cache is not None:
            save(records, args.lights_cache)
    if not records:
        raise SystemExit(f"{args.data}: no scene with a hard light")
    kinds = {k: sum(r["kind"] == k for r in records) for k in sorted({r["kind"] for r in records})}
    print(f"{len(records)} hard-light images ({', '.join(f'{v} {k}' for k, v in kinds.items())}) in {args.data}; "
          f"load average {os.getloadavg()[0]:.2f}")
    print("\nfit_key (shipped)\n\n| preset | framing | images | median (deg) | worst (deg) |\n|---|---|---|---|---|")
    for key, framing, n, median, worst in table(records, preset_keys, estimators()["fit_key (shipped)"]):
        bold = "**" if framing == "all" else ""
        print(f"| {key} | {bold}{framing}{bold} | {n} | {bold}{median:.1f}{bold} | {worst:.1f} |")
    if args.estimators:
        print("\nmedian over all images (largest median of one framing), degrees\n")
        print("| direction | " + " | ".join(preset_keys) + " |\n|---|" + "---|" * len(preset_keys))
        for name, estimate in estimators().items():
            rows = table(records, preset_keys, estimate)
            cells = []
            for key in preset_keys:
                every = [m for k, f, _, m, _ in rows if k == key and f == "all"][0]
                framing = max(m for k, f, _, m, _ in rows if k == key and f != "all")
                cells.append(f"{every:.1f} ({framing:.1f})")
            print(f"| {name} | " + " | ".join(cells) + " |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
