"""Surface parameters the farm draws: skin, fabric and hair colours (linear RGB) and the
Principled parameter dicts of farm.synthesis.appearance's parts (numpy; farm.rendering.materials turns a dict
into Cycles nodes, the sidecar records it)."""

from __future__ import annotations

import colorsys

import numpy as np

from relight.imaging.colour import srgb_decode

# Linear-RGB skin reflectance anchors, very light to very dark (roughly the
# range of measured skin albedos).
_SKIN_ANCHORS = np.array([
    [0.66, 0.47, 0.38],
    [0.52, 0.33, 0.24],
    [0.33, 0.19, 0.12],
    [0.17, 0.09, 0.055],
    [0.07, 0.038, 0.025],
])


def sample_skin(rng: np.random.Generator) -> list[float]:
    t = rng.uniform(0.0, 1.0) * (len(_SKIN_ANCHORS) - 1)
    i = min(int(t), len(_SKIN_ANCHORS) - 2)
    rgb = (1 - (t - i)) * _SKIN_ANCHORS[i] + (t - i) * _SKIN_ANCHORS[i + 1]
    rgb = rgb * rng.uniform(0.9, 1.1, size=3) ** 0.5  # small per-channel (hue) jitter
    return np.clip(rgb, 0.01, 0.9).tolist()


def hsv_linear(h: float, s: float, v: float) -> list[float]:
    """A colour picked in HSV (sRGB-encoded, as a colour picker shows it) as linear RGB."""
    lin = srgb_decode(np.array(colorsys.hsv_to_rgb(h % 1.0, s, v)))
    return np.clip(lin, 0.005, 0.95).tolist()


def sample_fabric_colour(rng: np.random.Generator) -> list[float]:
    kind = rng.random()
    if kind < 0.3:  # neutrals: black, grey, white
        return hsv_linear(0.0, 0.0, rng.uniform(0.08, 0.95))
    if kind < 0.45:  # denim-like blues
        return hsv_linear(rng.uniform(0.55, 0.64), rng.uniform(0.3, 0.7), rng.uniform(0.25, 0.7))
    return hsv_linear(rng.uniform(0, 1), rng.uniform(0.2, 0.9), rng.uniform(0.2, 0.95))


def sample_hair_colour(rng: np.random.Generator) -> list[float]:
    kind = rng.random()
    if kind < 0.1:  # grey / white
        return hsv_linear(0.08, rng.uniform(0.0, 0.1), rng.uniform(0.5, 0.85))
    if kind < 0.2:  # dyed
        return hsv_linear(rng.uniform(0, 1), rng.uniform(0.5, 0.9), rng.uniform(0.3, 0.8))
    # black .. brown .. blond
    v = rng.uniform(0.06, 0.8)
    return hsv_linear(rng.uniform(0.05, 0.11), rng.uniform(0.35, 0.75), v)


def jitter_hue(rgb: list[float], rng: np.random.Generator, amount: float = 0.03) -> list[float]:
    h, s, v = colorsys.rgb_to_hsv(*np.clip(rgb, 0, 1))
    return list(colorsys.hsv_to_rgb((h + rng.uniform(-amount, amount)) % 1.0, s, v))


def material(
    kind: str,
    rng: np.random.Generator,
    colour: list[float],
    roughness: tuple[float, float],
    diffuse_only: bool,
    pattern_p: float = 0.0,
    metallic_p: float = 0.0,
    transmission_p: float = 0.0,
    patterns: tuple[str, ...] = ("stripes", "checks", "noise"),
    sheen: tuple[float, float] | None = None,
    palette=sample_fabric_colour,
    pattern_scales: dict | None = None,
) -> dict:
    """Principled parameters; `diffuse_only` gives a pure Lambert surface.

    Pattern kinds: stripes, checks, noise (two colours, garment scale),
    denim (twill lines at thread scale), knit (ribs at stitch scale);
    `sheen` adds a Principled sheen lobe (hair). Prints, irises, skin
    mottle and hair streaks are added by `dress` (keys print / iris /
    mottle / streaks). `palette(rng)` draws the second colour; `pattern_scales`
    {pattern: (lo, hi)} redraws the scale of those patterns (farm.synthesis.looks'
    held-out pool: dots, plaid, finer stripes and checks).
    """
    rough = float(rng.uniform(*roughness))
    spec = {
        "kind": kind,
        "base_color": [float(c) for c in colour],
        "second_color": [float(c) for c in jitter_hue(palette(rng), rng)],
        "pattern": "none",
        "pattern_scale": float(rng.uniform(4.0, 30.0)),
        "pattern_axis": int(rng.integers(3)),
        "roughness": rough,
        "metallic": float(rng.uniform(0.5, 1.0)) if rng.random() < metallic_p else 0.0,
        "transmission": float(rng.uniform(0.05, 0.3)) if rng.random() < transmission_p else 0.0,
        "specular_level": float(rng.uniform(0.3, 0.6)),
        "diffuse_roughness": rough,
        "sheen": float(rng.uniform(*sheen)) if sheen else 0.0,
    }
    if rng.random() < pattern_p:
        spec["pattern"] = str(rng.choice(list(patterns)))
        if pattern_scales is not None:
            if spec["pattern"] in pattern_scales:
                spec["pattern_scale"] = float(rng.uniform(*pattern_scales[spec["pattern"]]))
        elif spec["pattern"] == "denim":
            spec["pattern_scale"] = float(rng.uniform(150.0, 260.0))  # 2.4-4 mm twill period
        elif spec["pattern"] == "knit":
            spec["pattern_scale"] = float(rng.uniform(50.0, 90.0))  # 3.5-6 mm ribs
    if diffuse_only:
        spec.update(roughness=1.0, metallic=0.0, transmission=0.0, specular_level=0.0, diffuse_roughness=0.0,
                    sheen=0.0)
    return spec


def is_diffuse(spec: dict) -> bool:
    """True when the material is a pure Lambertian (no specular, metal, glass, or roughness)."""
    return (
        spec["specular_level"] == 0.0
        and spec["metallic"] == 0.0
        and spec["transmission"] == 0.0
        and spec["diffuse_roughness"] == 0.0
        and spec.get("sheen", 0.0) == 0.0
    )
