"""Blender's lamps (Sun, point, spot, area) as SH light at a point, and the `sun:` light.

A lamp seen from a point is a cone of light (relight.lighting.key_light): toward the lamp,
of half-angle the angle its emitter subtends (a Sun's Angle / 2; asin(radius / D) for
a point or spot lamp of Radius at distance D; atan(r / D) for an area lamp, r the
radius of the disk of the same area, which a disk facing the point is exactly), and of
integral S with S g_1 the irradiance the lamp gives a surface facing it, in Cycles'
units (measured in tests/blender_addon/test_addon_lamps.py):

    Sun of Strength E          S g_1 = E                       (W/m^2, for any Angle)
    point of Power P           S g_1 = P / (4 pi D^2)
    spot of Power P            S g_1 = P / (4 pi D^2) * smoothstep((cos t - cos(size/2)) / ((1 - cos(size/2)) blend))
    area of Power P            S g_1 = P cos t_e / (pi (D^2 + r^2))   (t_e from the lamp's normal; 0 behind it)

(t the angle between the spot's axis and the point, g_1 = (1 + cos a) / 2.) Each
channel is the lamp's colour times that. A lamp at the point itself gives no light here.
`sun_light` / `parse_sun` are the command's `--light sun:AZIMUTH,ELEVATION[,ANGLE]`.
numpy only.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from relight.lighting import sh
from relight.lighting.key_light import cone_profile, direction_from_angles, lobe_coeffs

__all__ = ["Lamp", "LAMP_KINDS", "lamp_coeffs", "lamps_coeffs", "sun_light", "parse_sun", "SUN_AMBIENT"]

LAMP_KINDS = ("SUN", "POINT", "SPOT", "AREA")
SUN_AMBIENT = 0.2   # sun:AZ,EL: the ambient share of a facing surface's irradiance (as directional_light)
NEAR = 1e-6         # metres: a lamp this close to the point has no direction from it


@dataclass(frozen=True)
class Lamp:
    """One lamp in Blender's terms. `rgb` is colour * energy (Strength in W/m^2 for a Sun, Power
    in W otherwise); `location` (m) and `axis` (where it points: its object's -Z) in world axes;
    `angle` a Sun's Angle (rad); `radius` a point or spot lamp's Radius (m); `spot_size` (rad) and
    `spot_blend` a spot's cone; `size` (x, y) (m) and `shape` (SQUARE, RECTANGLE, DISK, ELLIPSE)
    an area lamp's."""

    kind: str
    rgb: tuple
    location: tuple = (0.0, 0.0, 0.0)
    axis: tuple = (0.0, 0.0, -1.0)
    angle: float = 0.0
    radius: float = 0.0
    spot_size: float = math.pi
    spot_blend: float = 0.0
    size: tuple = (1.0, 1.0)
    shape: str = "SQUARE"

    def __post_init__(self):
        if self.kind not in LAMP_KINDS:
            raise ValueError(f"lamp kind must be one of {', '.join(LAMP_KINDS)}, got {self.kind!r}")
        values = [*self.rgb, *self.location, *self.axis, self.angle, self.radius, self.spot_size,
                  self.spot_blend, *self.size]
        if len(self.rgb) != 3 or len(self.location) != 3 or len(self.axis) != 3 or len(self.size) != 2 \
                or not all(math.isfinite(float(v)) for v in values):
            raise ValueError("a lamp's colour, location, axis and sizes must be finite 3-, 3-, 3- and 2-vectors")
        if min(self.rgb) < 0 or self.angle < 0 or self.radius < 0 or min(self.size) < 0:
            raise ValueError("a lamp's energy, angle, radius and size must be >= 0")
        if float(np.linalg.norm(self.axis)) == 0:
            raise ValueError("a lamp's axis must not be the zero vector")


def _smoothstep(x: float) -> float:
    x = min(1.0, max(0.0, x))
    return x * x * (3.0 - 2.0 * x)


def _cone(lamp: Lamp, at: np.ndarray):
    """(unit vector toward the lamp, half-angle, irradiance per channel of a facing surface) at `at`,
    or None when the lamp gives `at` no light."""
    rgb = np.asarray(lamp.rgb, dtype=np.float64)
    axis = np.asarray(lamp.axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    if lamp.kind == "SUN":
        return -axis, min(lamp.angle, math.pi) / 2.0, rgb
    offset = np.asarray(lamp.location, dtype=np.float64) - at
    distance = float(np.linalg.norm(offset))
    if distance < NEAR:
        return None
    toward = offset / distance
    if lamp.kind in ("POINT", "SPOT"):
        facing = rgb / (4.0 * math.pi * distance * distance)
        if lamp.kind == "SPOT":
            cos_half = math.cos(min(lamp.spot_size, math.pi) / 2.0)
            cos_t = float(-toward @ axis)
            if cos_t <= cos_half:
                return None
            width = (1.0 - cos_half) * lamp.spot_blend
            facing = facing * (_smoothstep((cos_t - cos_half) / width) if width > 0 else 1.0)
        return toward, math.asin(min(1.0, lamp.radius / distance)), facing
    cos_e = float(-toward @ axis)   # AREA: Lambertian, front side only
    if cos_e <= 0:
        return None
    sx, sy = (float(v) for v in lamp.size)
    if lamp.shape in ("SQUARE", "DISK"):
        sy = sx
    area = sx * sy * (math.pi / 4.0 if lamp.shape in ("DISK", "ELLIPSE") else 1.0)
    radius2 = area / math.pi   # the disk of the same area: exact on its axis, P / (pi (D^2 + r^2))
    facing = rgb * cos_e / (math.pi * (distance * distance + radius2))
    return toward, math.atan(math.sqrt(radius2) / distance), facing


def lamp_coeffs(lamp: Lamp, at, order: int) -> np.ndarray:
    """SH [(order+1)^2, 3] of the light `lamp` gives the point `at` (m, world axes)."""
    at = np.asarray(at, dtype=np.float64)
    if at.shape != (3,) or not np.all(np.isfinite(at)):
        raise ValueError(f"the point a lamp lights must be a finite 3-vector, got {at!r}")
    cone = _cone(lamp, at)
    n = sh.num_coeffs(order)
    if cone is None:
        return np.zeros((n, 3))
    toward, half_angle, facing = cone
    integral = facing / float(cone_profile(half_angle, 1)[1])
    return lobe_coeffs(toward, half_angle, order)[:, None] * integral[None, :]


def lamps_coeffs(lamps, at, order: int) -> np.ndarray:
    """The sum of lamp_coeffs over `lamps` (zeros for none)."""
    out = np.zeros((sh.num_coeffs(order), 3))
    for lamp in lamps:
        out += lamp_coeffs(lamp, at, order)
    return out


def sun_light(azimuth_deg: float, elevation_deg: float, angle_deg: float, order: int,
              ambient: float = SUN_AMBIENT) -> np.ndarray:
    """A white sun (a cone of full angle `angle_deg`) at (azimuth, elevation) (angles_from_direction's
    convention) plus a constant ambient, SH [n, 3], unscaled: the sun's integral is 1 and the
    ambient is `ambient` of a facing surface's irradiance (relight.lighting.light.directional_light's rule)."""
    for name, value in (("azimuth", azimuth_deg), ("elevation", elevation_deg), ("angle", angle_deg)):
        if not math.isfinite(value):
            raise ValueError(f"sun: {name} must be finite, got {value}")
    if not -90.0 <= elevation_deg <= 90.0:
        raise ValueError(f"sun: elevation must be within -90..90 degrees, got {elevation_deg:g}")
    if not 0.0 <= angle_deg <= 180.0:
        raise ValueError(f"sun: angle must be within 0..180 degrees, got {angle_deg:g}")
    if not 0.0 <= ambient < 1.0:
        raise ValueError(f"sun: ambient must be in [0, 1), got {ambient}")
    half = math.radians(angle_deg) / 2.0
    lobe = lobe_coeffs(direction_from_angles(azimuth_deg, elevation_deg), half, order)
    facing = float(cone_profile(half, 1)[1])           # a facing surface's irradiance from the cone
    constant = ambient / (1.0 - ambient) * facing / math.pi
    coeffs = np.repeat(lobe[:, None], 3, axis=1)
    coeffs[0] += 2.0 * math.sqrt(math.pi) * constant   # radiance `constant` everywhere
    return coeffs


def parse_sun(text: str) -> tuple[float, float, float]:
    """(azimuth, elevation, angle) degrees of 'sun:AZIMUTH,ELEVATION[,ANGLE]' (angle default 0);
    ValueError in one line otherwise."""
    usage = "a sun light is sun:AZIMUTH,ELEVATION[,ANGLE] in degrees, e.g. sun:30,45 or sun:30,45,10"
    if not isinstance(text, str) or not text.startswith("sun:"):
        raise ValueError(f"{usage}; got {text!r}")
    parts = text[4:].split(",")
    if len(parts) not in (2, 3):
        raise ValueError(f"{usage}; got {text!r}")
    try:
        values = [float(p) for p in parts]
    except ValueError:
        raise ValueError(f"{usage}; got {text!r}") from None
    if len(values) == 2:
        values.append(0.0)
    azimuth, elevation, angle = values
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{usage}: the numbers must be finite; got {text!r}")
    if not -90.0 <= elevation <= 90.0 or not 0.0 <= angle <= 180.0:
        raise ValueError(f"{usage}, elevation within -90..90 and angle within 0..180; got {text!r}")
    return azimuth, elevation, angle
