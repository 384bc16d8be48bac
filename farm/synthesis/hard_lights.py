"""Hard lights beside the HDR maps (issue 37): a sun-like small source over a sky, a studio key
with a fill, a single lamp in a dark room.

Each is drawn as an equirect map of small bright lobes over a dim ambient, in Blender's
mapping (relight.lighting.sh_projection.equirect_directions), and then used exactly like a bundled
map: Cycles' World shows these pixels (the path-traced images: crisp shadows, the lobe's own
size) and the sidecar's SH is their projection (the PRT targets: the same light cut at order
N). So the two agree the way they agree for a map with a sun in it, and the gap between them
(the shadow's sharpness above order N) is what the residual E and the path-traced images
carry. A lobe is at least MIN_RADIUS_TEXELS texels wide so that a map of MAP_SIZE resolves it.

Directions are drawn about the camera: azimuth 0 is the camera's side of the person, positive
toward the camera's right (turned with the camera's own azimuth about world Z).
"""

from __future__ import annotations

import math

import numpy as np

from relight.lighting import sh, sh_rotation
from relight.lighting.light import SHLight
from relight.imaging.colour import luminance
from relight.lighting.sh_projection import equirect_directions

HARD_KINDS = ("sun", "studio", "lamp")
MAP_SIZE = (256, 512)  # 0.7 degrees a texel
MIN_RADIUS_TEXELS = 1.0


def direction(azimuth_deg: float, elevation_deg: float) -> np.ndarray:
    """World direction toward a light at an azimuth about the camera's side (-Y) and an elevation."""
    a, e = math.radians(azimuth_deg), math.radians(elevation_deg)
    return np.array([math.sin(a) * math.cos(e), -math.cos(a) * math.cos(e), math.sin(e)])


def lobe_map(lobes: list[dict], ambient: dict, size=MAP_SIZE) -> np.ndarray:
    """[H, W, 3] equirect radiance: each lobe {direction, radius_deg, colour, power} a disc of
    constant radiance whose integral over the sphere is power * colour (soft over its outer
    fifth, so it has no one-texel stair), plus the ambient {sky, ground, power}: a sky colour
    above the horizon blending into a ground colour below, integrating to power (luminance)."""
    dirs, solid = equirect_directions(*size)
    texel_deg = 180.0 / size[0]
    out = np.zeros(size + (3,))
    for lobe in lobes:
        radius = max(float(lobe["radius_deg"]), MIN_RADIUS_TEXELS * texel_deg)
        angle = np.degrees(np.arccos(np.clip(dirs @ np.asarray(lobe["direction"], np.float64), -1.0, 1.0)))
        t = np.clip((radius - angle) / (0.2 * radius), 0.0, 1.0)
        weight = t * t * (3.0 - 2.0 * t)
        integral = float((weight * solid[:, None]).sum())
        out += weight[..., None] * (float(lobe["power"]) / integral) * np.asarray(lobe["colour"], np.float64)
    up = np.clip(dirs[..., 2:3] * 4.0 + 0.5, 0.0, 1.0)  # the horizon blends over +-7 degrees
    amb = up * np.asarray(ambient["sky"], np.float64) + (1.0 - up) * np.asarray(ambient["ground"], np.float64)
    lum = luminance(amb)
    integral = float((lum * solid[:, None]).sum())
    out += amb * (float(ambient["power"]) / max(integral, 1e-12))
    return out.astype(np.float32)


def mean_luminance(pixels: np.ndarray) -> float:
    """Solid-angle-weighted mean luminance of an equirect map (what a map's scale normalizes)."""
    _, solid = equirect_directions(*pixels.shape[:2])
    return float((luminance(np.asarray(pixels, np.float64)) * solid[:, None]).sum() / (4.0 * math.pi))


def facing_shading(pixels: np.ndarray, normal) -> float:
    """Luminance of the shading (irradiance / pi) of an unoccluded white Lambertian surface with
    this normal under the map, computed on the map's texels (no SH cut)."""
    dirs, solid = equirect_directions(*pixels.shape[:2])
    cos = np.clip(dirs @ np.asarray(normal, np.float64), 0.0, None)
    return float((luminance(np.asarray(pixels, np.float64)) * cos * solid[:, None]).sum() / math.pi)


def _kelvin_tint(rng, lo: float, hi: float) -> list[float]:
    """A rough blackbody white between lo and hi kelvin, luminance 1 (warm lamps, daylight)."""
    k = float(rng.uniform(lo, hi))
    warm = float(np.clip((6500.0 - k) / 3800.0, -0.3, 1.0))  # 1 at 2700 K, 0 at 6500 K
    rgb = np.array([1.0 + 0.1 * max(-warm, 0), 1.0 - 0.28 * max(warm, 0), 1.0 - 0.62 * max(warm, 0)])
    rgb[2] += 0.15 * max(-warm, 0)
    return (rgb / luminance(rgb)).tolist()


def sample_lobes(kind: str, rng: np.random.Generator) -> tuple[list[dict], dict]:
    """The lobes and ambient of one hard light of `kind` (world directions; powers in luminance)."""
    side = float(rng.choice([-1.0, 1.0]))
    if kind == "sun":
        # a sun 1.4-2.0 degrees across (the real one is 0.53; a texel of MAP_SIZE is 0.7),
        # anywhere around, 10-70 degrees up, 60-85 % of the light; the rest a blue sky
        lobes = [{"direction": direction(float(rng.uniform(0.0, 360.0)), float(rng.uniform(10.0, 70.0))),
                  "radius_deg": float(rng.uniform(0.7, 1.0)), "colour": _kelvin_tint(rng, 4800, 6000),
                  "power": float(rng.uniform(0.6, 0.85))}]
        ambient = {"sky": [0.55, 0.7, 1.0], "ground": [0.35, 0.3, 0.25], "power": 1.0 - lobes[0]["power"]}
    elif kind == "studio":
        key = float(rng.uniform(0.7, 0.9))
        fill = key * float(rng.uniform(0.12, 0.35))
        tint = _kelvin_tint(rng, 4500, 6500)
        lobes = [{"direction": direction(side * float(rng.uniform(25.0, 70.0)), float(rng.uniform(15.0, 45.0))),
                  "radius_deg": float(rng.uniform(6.0, 14.0)), "colour": tint, "power": key},
                 {"direction": direction(-side * float(rng.uniform(20.0, 60.0)), float(rng.uniform(0.0, 20.0))),
                  "radius_deg": float(rng.uniform(15.0, 30.0)), "colour": tint, "power": fill}]
        ambient = {"sky": [0.5, 0.5, 0.5], "ground": [0.35, 0.35, 0.35], "power": float(rng.uniform(0.03, 0.08))}
    elif kind == "lamp":
        lobes = [{"direction": direction(side * float(rng.uniform(0.0, 150.0)), float(rng.uniform(-10.0, 50.0))),
                  "radius_deg": float(rng.uniform(1.5, 4.0)), "colour": _kelvin_tint(rng, 2700, 4000),
                  "power": 1.0}]
        ambient = {"sky": [0.45, 0.4, 0.35], "ground": [0.3, 0.27, 0.24], "power": float(rng.uniform(0.02, 0.06))}
    else:
        raise ValueError(f"hard light kind must be one of {HARD_KINDS}, got {kind!r}")
    return lobes, ambient


def sample_hard_light(rng: np.random.Generator, order: int, world_to_camera: np.ndarray, kind: str | None = None):
    """One hard light as a farm.synthesis.lights.SampledLight (source "hard", name "hard:KIND"): its map,
    its SH (order N and 8, camera frame) scaled so that a white surface facing the key shades a
    drawn 0.9-1.3 (recorded as `key_shading`; the reference luminance is the mean that gives)."""
    from farm.synthesis.lights import SampledLight

    kind = str(rng.choice(HARD_KINDS)) if kind is None else kind
    lobes, ambient = sample_lobes(kind, rng)
    # about the camera: its horizontal view direction is +Y turned by theta about world Z
    forward = np.asarray(world_to_camera, np.float64)[1]
    t = math.atan2(-forward[0], forward[1])
    turn = np.array([[math.cos(t), -math.sin(t), 0.0], [math.sin(t), math.cos(t), 0.0], [0.0, 0.0, 1.0]])
    lobes = [{**lobe, "direction": turn @ lobe["direction"]} for lobe in lobes]
    pixels = lobe_map(lobes, ambient)
    # exposed for the key, as a photographer exposes a face: a white Lambertian surface facing the
    # key light shades `exposure` (a map is scaled by its mean instead, which would put a lamp's
    # lit side at 3-4 and its shadow near 0); the mean luminance that gives is the recorded target
    exposure = float(rng.uniform(0.9, 1.3))
    target = exposure * mean_luminance(pixels) / facing_shading(pixels, lobes[0]["direction"])
    coeffs, scale = SHLight.resolve(pixels, max(order, 8), target=target).turned(0.0)
    coeffs = sh_rotation.rotate(coeffs, world_to_camera)
    record = {"kind": kind, "ambient": ambient, "key_shading": exposure,
              "lobes": [{**lobe, "direction": [float(x) for x in lobe["direction"]],
                         "direction_camera": [float(x) for x in world_to_camera @ lobe["direction"]]}
                        for lobe in lobes]}
    return SampledLight(name=f"hard:{kind}", source="hard", rotation_deg=0.0, scale=float(scale),
                        reference_luminance=target, pixels=pixels, sh=coeffs[: sh.num_coeffs(order)].copy(),
                        sh8=coeffs[:81].copy(), hard=record)


def replace_share(scene_lights: list, share: float, stream: list[int], order: int, world_to_camera: np.ndarray) -> None:
    """Replace each of the scene's drawn lights, with probability `share`, by a hard light, all
    drawn from default_rng(stream): the maps drawn before stay those of --hard-lights 0."""
    if share <= 0:
        return
    rng = np.random.default_rng(stream)
    for k in range(len(scene_lights)):
        if rng.random() < share:
            scene_lights[k] = sample_hard_light(rng, order, world_to_camera)
