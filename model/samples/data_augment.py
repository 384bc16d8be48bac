"""Random draws of the training augmentation (model.samples.data.TrainingScenes): backgrounds,
extra lights at a reference radiance, mixed and tilted lights, light tints, the sun-response
loss's suns, and the signs of a mirrored photo's SH.
Every draw comes from the Generator passed in."""

from __future__ import annotations

import math

import numpy as np
import torch
from torch.nn import functional as F

from model.samples.data_splits import held_out_light_names
from relight.imaging.colour import luminance, srgb_decode
from relight.lighting.light import SHLight

REFERENCE_RADIANCE = (0.7, 0.9)  # paper: lights scaled to a reference radiance in this range
# the sun-response loss's suns (random_sun_light): further than this off the camera's axis a sun
# lights little of what the camera sees; elevations from a little below the horizon to high
SUN_MAX_OFF_AXIS_DEG = 150.0
SUN_ELEVATION_DEG = (-20.0, 70.0)
SUN_MAX_ANGLE_DEG = 10.0  # full angle of its disc: a point to a hazy sun


MIRROR_X = np.array([-1.0, 1.0, 1.0], dtype=np.float32)  # a mirrored photo's normals: x flips


def mirror_signs(order: int) -> np.ndarray:
    """Per-coefficient signs s with Y_k(-x, y, z) = s_k Y_k(x, y, z).

    Mirroring x maps azimuth phi -> pi - phi: cos(m phi) terms (m > 0) gain
    (-1)^m, sin(|m| phi) terms (m < 0) gain (-1)^(|m|+1), zonal terms stay.
    A horizontally flipped photo has transport s * T and light s * L, and
    (s T) . (s L) = T . L: an exact augmentation.
    """
    signs = []
    for l in range(order + 1):
        for m in range(-l, l + 1):
            signs.append(1.0 if m == 0 else (-1.0) ** (abs(m) + (1 if m < 0 else 0)))
    return np.asarray(signs, dtype=np.float32)


def random_background(rng: np.random.Generator, size: int) -> np.ndarray:
    """A linear RGB background [3, S, S]: flat colour, smooth noise or a gradient, each drawn
    uniformly in sRGB-encoded values (as a photo's background would be) and decoded to linear."""
    kind = rng.integers(3)
    if kind == 0:
        colour = srgb_decode(rng.uniform(0.0, 1.0, 3))
        return np.broadcast_to(colour[:, None, None], (3, size, size)).astype(np.float32)
    if kind == 1:
        cells = int(rng.integers(2, 9))
        coarse = torch.from_numpy(rng.uniform(0.0, 1.0, (1, 3, cells, cells)).astype(np.float32))
        smooth = F.interpolate(coarse, size=(size, size), mode="bicubic", align_corners=False)
        return srgb_decode(smooth[0].numpy())  # srgb_decode clips to [0, 1]
    a, b = srgb_decode(rng.uniform(0.0, 1.0, (2, 3)))
    angle = rng.uniform(0, 2 * math.pi)
    yy, xx = np.mgrid[0:size, 0:size] / max(size - 1, 1)
    t = np.clip(0.5 + (xx - 0.5) * math.cos(angle) + (yy - 0.5) * math.sin(angle), 0.0, 1.0)
    return (a[:, None, None] * (1 - t) + b[:, None, None] * t).astype(np.float32)


def random_reference_light(base: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Rotate an SH light [n, 3] about Z at random, scale to a reference radiance in [0.7, 0.9]."""
    rotation = rng.uniform(0.0, 360.0)
    target = rng.uniform(*REFERENCE_RADIANCE)
    scaled = SHLight(base, target).at(rotation)  # relight.lighting.light's recipe for maps
    return scaled.astype(np.float32)


MIX_TILT_DEG = 30.0  # a mixed light is also tilted about a random horizontal axis by up to this


def random_mixed_light(first: np.ndarray, second: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A light no map gives: two SH lights [n, 3], each turned about Z at random and brought to
    the same radiance, mixed with a random weight in [0.2, 0.8], tilted about a random
    horizontal axis by up to MIX_TILT_DEG and scaled to a reference radiance in [0.7, 0.9].
    A sum of lights is a light (radiance is linear in it), so the PRT image under it is exact;
    it widens the few dozen training maps into light fields the network cannot memorise."""
    from relight.lighting.sh_rotation import rotate

    a, b = (SHLight(base, 1.0).at(rng.uniform(0.0, 360.0)) for base in (first, second))
    w = rng.uniform(0.2, 0.8)
    axis_angle = rng.uniform(0.0, 2 * math.pi)
    tilt = math.radians(rng.uniform(-MIX_TILT_DEG, MIX_TILT_DEG))
    k = np.array([math.cos(axis_angle), math.sin(axis_angle), 0.0])  # a horizontal axis (camera frame: Z up)
    K = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    R = np.eye(3) + math.sin(tilt) * K + (1.0 - math.cos(tilt)) * (K @ K)  # Rodrigues
    mixed = rotate(w * a + (1.0 - w) * b, R)
    return SHLight(mixed, rng.uniform(*REFERENCE_RADIANCE)).at(0.0).astype(np.float32)


def random_sun_light(rng: np.random.Generator, order: int) -> np.ndarray:
    """A hard white sun [n, 3] (relight.lighting.lamps.sun_light, with its ambient) from a random
    direction at most SUN_MAX_OFF_AXIS_DEG off the camera's axis (camera frame), for the
    sun-response loss (model.networks.response_loss); its level is arbitrary (that loss ignores it)."""
    from relight.lighting.lamps import sun_light

    while True:
        azimuth, elevation = rng.uniform(-180.0, 180.0), rng.uniform(*SUN_ELEVATION_DEG)
        toward_camera = math.cos(math.radians(azimuth)) * math.cos(math.radians(elevation))
        if toward_camera >= math.cos(math.radians(SUN_MAX_OFF_AXIS_DEG)):
            return sun_light(azimuth, elevation, rng.uniform(0.0, SUN_MAX_ANGLE_DEG), order).astype(np.float32)


def random_light_tint(rng: np.random.Generator, sigma: float) -> np.ndarray:
    """Per-channel factors exp(N(0, sigma^2)) rescaled to Rec.709 luminance 1.

    Multiplying a light by it changes the light's colour, never its reference
    radiance; the image under it is multiplied by the same factors.
    """
    tint = np.exp(rng.normal(0.0, sigma, 3))
    return (tint / float(luminance(tint))).astype(np.float32)


def preset_training_lights(order: int) -> list[tuple[str, np.ndarray]]:
    """SH [n, 3] of every bundled HDR preset that is not held out."""
    from relight.lighting import presets
    from relight.lighting.light import sh_light

    held_out = held_out_light_names()
    out = []
    for name in presets.training_presets():
        assert name.lower() not in held_out, f"relight.lighting.presets offered held-out map {name}"
        out.append((name.lower(), np.asarray(sh_light(name, order, normalize=False), dtype=np.float32)))
    return out
