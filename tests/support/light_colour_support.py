"""Lights whose colour varies, for the tests of the World maps' colours (tests/relight/lighting/test_light_map.py,
tests/relight/lighting/test_key_light.py)."""

from __future__ import annotations

import math

import numpy as np

from relight.imaging.colour import LUMINANCE_WEIGHTS
from relight.lighting import sh_projection
from relight.lighting.light_colour import saturation

SUN, SKY, GROUND = (1.0, 0.75, 0.45), (0.35, 0.55, 1.0), (0.3, 0.28, 0.25)


def sun_and_sky(order, sun_rgb=SUN, sky_rgb=SKY, ground_rgb=GROUND):
    """A warm 2-degree sun 30 degrees up over a blue sky and a grey-brown ground (a light >= 0 of three
    colours), its map and its SH at `order`."""
    dirs, _ = sh_projection.equirect_directions(256, 512)
    sky = np.where(dirs[..., 2:] > 0, [sky_rgb], [ground_rgb])
    sun = dirs @ np.array([0.6, -0.6928, 0.4]) / np.linalg.norm([0.6, -0.6928, 0.4]) > math.cos(math.radians(1.0))
    pixels = sky + sun[..., None] * (3000.0 * np.asarray(sun_rgb))
    return pixels, sh_projection.project_equirect(pixels, order, precision="float64")


def lit_saturation(pixels, fraction=0.0):
    """HSV saturation of the texels brighter than `fraction` of the brightest (luminance)."""
    rgb = np.asarray(pixels, np.float64).reshape(-1, 3)
    lum = rgb @ LUMINANCE_WEIGHTS
    return saturation(rgb[lum > fraction * lum.max()])


# the shipped model's light at Draft on evaluation/data/matte_eval/astronaut.jpg (5 decimals): its
# lamp-free map had 65 % of its lit texels above saturation 0.8 (issue 48's fringes), each channel
# clamped at 0 where it alone rings
ASTRONAUT_DRAFT = np.array([
    [3.76431, 4.3052, 4.17314], [-2.33081, -1.08944, -1.33428], [1.95581, 2.26289, 2.91533],
    [-0.07904, -0.20725, 0.0784], [0.26701, 1.02137, 0.84777], [-1.26351, -0.65999, -0.90566],
    [-1.00122, 0.49526, 0.15387], [1.66061, 1.6248, 0.98127], [-1.34623, 0.11248, -0.44808],
    [0.16772, 0.21377, 0.16826], [0.05258, 0.03633, 0.04322], [0.69158, 0.66229, 0.8566],
    [-0.88037, -0.98177, -1.38642], [0.05014, 0.03346, -0.04299], [-0.65173, -0.5051, -0.60639],
    [0.01102, -0.07841, -0.08109], [-0.32137, 0.13341, 0.41444], [-0.29168, 0.15896, 0.18227],
    [-0.30347, -0.19701, -0.51061], [0.77838, 1.32367, 1.38491], [0.42575, 0.54982, 0.17415],
    [0.4775, 0.43632, 0.62763], [0.16193, 0.46964, 0.17324], [0.65027, 0.43343, 0.49193],
    [0.11697, 0.27057, -0.13301]])


def most_saturated() -> float:
    """The saturation of sun_and_sky's most saturated colour (the sky's: 0.65)."""
    return float(saturation(np.array([SUN, SKY, GROUND])).max())
