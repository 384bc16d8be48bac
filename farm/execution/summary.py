"""`python -m farm --summary DIR`: what fraction of a dataset's scenes has each appearance feature.

Reads the sidecars (the `appearance` record farm.synthesis.appearance.dress writes)
and the albedo/alpha channels, and prints one line per feature: the
fraction of scenes that have it, then the albedo-texture figure: the
fraction of person pixels (alpha > 0.999) whose albedo differs from the
mean of the person pixels in their 5 x 5 neighbourhood (the pixel itself
left out) by more than 0.04 in some channel, pooled over the scenes.
Sidecars written before a feature existed simply count as not having it.
"""

from __future__ import annotations

import colorsys
import sys
from collections import Counter
from pathlib import Path

import numpy as np

from relight.imaging.colour import luminance, srgb_encode

TEXTURE_THRESHOLD = 0.04
TEXTURE_WINDOW = 5
HAIR_VOLUMES = ("none", "shell", "short", "medium", "long", "updo", "big")
OLD_HAIR = {"bald": "none", "short": "shell", "medium": "shell", "long": "shell"}  # thin caps before issue 20


def is_dark(rgb) -> bool:
    """Linear albedo whose luminance is below 0.02 (sRGB value about 0.15 or less)."""
    return float(luminance(np.asarray(rgb, dtype=np.float64))) < 0.02


def is_saturated(rgb) -> bool:
    """sRGB saturation above 0.7 at a value of at least 0.25."""
    _, s, v = colorsys.rgb_to_hsv(*srgb_encode(np.asarray(rgb, dtype=np.float64)))
    return s > 0.7 and v >= 0.25


def features(meta: dict) -> dict[str, bool]:
    """Feature flags of one scene from its sidecar."""
    look = meta.get("appearance", {})
    garments = look.get("garments", {})
    mats = [g.get("material", {}) for g in garments.values()]
    cloth = [g.get("material", {}) for slot, g in garments.items() if slot != "shoes"]
    top = garments.get("top", garments.get("dress", {}))
    hair = look.get("hair", {})
    volume = hair.get("volume", OLD_HAIR.get(hair.get("style", "bald"), "none"))
    face = look.get("face", {})
    prints = [m["print"] for m in mats if m.get("print")]
    f = {
        "loose clothing (any)": any(g.get("loose") for g in garments.values()),
        "loose top": bool(top.get("loose")) or "outer" in garments,
        "jacket or coat": "outer" in garments,
        "open front": bool(garments.get("outer", {}).get("open_front")),
        "coat": garments.get("outer", {}).get("kind") == "coat",
        "dress": "dress" in garments,
        "skirt": garments.get("bottom", {}).get("kind") == "skirt",
        "hood": any("hood" in g for g in garments.values()),
        "folds": any(g.get("folds") for g in garments.values()),
        "volumetric hair": volume not in ("none", "shell"),
    }
    for v in HAIR_VOLUMES:
        f[f"hair volume: {v}"] = volume == v
    f.update({
        "print or logo": bool(prints),
        **{f"print: {k}": any(p["kind"] == k for p in prints) for k in ("logo", "text", "band", "number")},
        "garment pattern": any(m.get("pattern", "none") != "none" for m in cloth),
        "denim or knit (thread scale)": any(m.get("pattern") in ("denim", "knit") for m in cloth),
        "dark garment": any(is_dark(m["base_color"]) for m in cloth if "base_color" in m),
        "saturated garment": any(is_saturated(m["base_color"]) for m in cloth if "base_color" in m),
        "face details (lips, brows, irises)": all(k in face for k in ("lips", "brows", "eyes"))
        and "iris" in face.get("eyes", {}).get("material", {}),
        "lipstick": bool(face.get("lipstick")),
        "nails": "nails" in face,
        "nail polish": bool(face.get("nail_polish")),
        "skin texture": "mottle" in look.get("skin", {}),
        "barefoot": "shoes" not in garments,
        "all diffuse": bool(look.get("diffuse_only")),
    })
    from farm.synthesis.camera import FRAMINGS

    framing = meta.get("camera", {}).get("framing", "full-body")  # absent before issue 37
    f.update({f"framing: {name}": framing == name for name in FRAMINGS})
    f["hard light (any)"] = any(light.get("source") == "hard" for light in meta.get("lights", []))
    from farm.synthesis.people import MAX_PEOPLE

    group = meta.get("people", {"count": 1, "persons": []})  # absent: one person (the features above are person 0's)
    f.update({f"people: {n}": group["count"] == n for n in range(1, MAX_PEOPLE + 1)})
    f["people placed overlapping (any)"] = any(p["placement"]["relation"] == "overlap" for p in group["persons"])
    return f


def _box_sum(x: np.ndarray) -> np.ndarray:
    """Sum over the TEXTURE_WINDOW x TEXTURE_WINDOW window around each pixel, zero outside (x: [H, W, C])."""
    r = TEXTURE_WINDOW // 2
    p = np.pad(x, ((r + 1, r), (r + 1, r), (0, 0)))
    c = p.cumsum(0).cumsum(1)
    k = TEXTURE_WINDOW
    return c[k:, k:] - c[:-k, k:] - c[k:, :-k] + c[:-k, :-k]


def texture_counts(albedo: np.ndarray, alpha: np.ndarray) -> tuple[int, int]:
    """(person pixels differing from their neighbourhood mean by > 0.04, person pixels with neighbours)."""
    m = (alpha.reshape(alpha.shape[:2]) > 0.999).astype(np.float64)
    a = albedo.astype(np.float64) * m[..., None]
    box_m = _box_sum(m[..., None])[..., 0] - m
    box_a = _box_sum(a) - a
    valid = (m > 0) & (box_m > 0.5)
    mean = box_a[valid] / box_m[valid][:, None]
    differs = np.abs(albedo[valid] - mean).max(axis=1) > TEXTURE_THRESHOLD
    return int(differs.sum()), int(valid.sum())


def summarise(folder) -> dict:
    from relight.files import dataset

    paths = dataset.list_finished_scenes(folder)
    counts: Counter = Counter()
    names: list[str] = []
    differ = total = 0
    for path in paths:
        scene = dataset.read_scene(path, verify_hash=False)
        f = features(scene.meta)
        names = names or list(f)
        counts.update(k for k, v in f.items() if v)
        d, t = texture_counts(scene.albedo, scene.alpha)
        differ, total = differ + d, total + t
    n = len(paths)
    return {
        "scenes": n,
        "fractions": {k: counts[k] / n for k in names} if n else {},
        "albedo_texture": differ / total if total else float("nan"),
    }


def main(argv) -> int:
    """Print the summary of DIR (argv: [DIR] or a path); 2 on a usage error."""
    args = [argv] if isinstance(argv, (str, Path)) else list(argv)
    if len(args) != 1 or not Path(args[0]).is_dir():
        print("farm: error: --summary needs one dataset folder", file=sys.stderr)
        return 2
    s = summarise(args[0])
    if not s["scenes"]:
        print(f"farm: error: no finished scenes in {args[0]}", file=sys.stderr)
        return 1
    print(f"{'scenes':<40} {s['scenes']}")
    for name, frac in s["fractions"].items():
        print(f"{name:<40} {frac:6.3f}")
    print(f"{'albedo texture (5x5, > 0.04)':<40} {s['albedo_texture']:6.3f}")
    return 0
