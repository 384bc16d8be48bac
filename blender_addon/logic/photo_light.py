"""The photo's light as a World, and the compositing setup around it: the plain parts (no bpy).

bl_photo_world and bl_compositing build the datablocks; what they build is
decided here: the map of the session's light (relight.lighting.light_map, written as a
lossless EXR that Blender packs into the .blend), the datablocks' names, and
the camera and floor that match the photo. Scene frame: the photo camera of
docs/conventions.md (looking along +Y, X right, Z up), so the light needs no
rotation; the camera stands CAMERA_HEIGHT above a floor at z = 0. The key light
(relight.lighting.key_light) becomes a Sun, or an area lamp when it is wide, aimed at the
person, who stands PERSON_DISTANCE ahead of the camera with PERSON_POSITION at
their middle: where the scene's lamps are projected to SH (light_sources.with_lamps).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

MAP_WIDTH = 512             # texels: the light is order-4 SH, far smoother than this (docs/addon.md)
SENSOR_WIDTH_MM = 36.0      # a full-frame sensor: a 35 mm-equivalent focal length applies as is
DEFAULT_LENS_MM = 50.0      # when the photo does not say its focal length (EXIF FocalLengthIn35mmFilm)
CAMERA_HEIGHT = 1.5         # metres above the floor: a standing photographer
FLOOR_HALF_WIDTH = 20.0     # metres either side of the view axis
FLOOR_DEPTH = 40.0          # metres in front of the camera
PERSON_DISTANCE = 3.0       # metres ahead of the camera: where the person stands
PERSON_POSITION = (0.0, PERSON_DISTANCE, 1.0)   # the middle of a standing person: where lamps light them
SUN_DISTANCE = 5.0          # metres from the person toward the light: where the Sun lamp is drawn (a Sun has
                            # no position; only its direction lights)
AREA_DISTANCE = 4.0         # metres from the person: where a wide key's area lamp stands
AREA_MAX_HALF_ANGLE = math.radians(75.0)  # a wider key is drawn as a disk of this half-angle (same irradiance)


def datablock_name(photo_name: str, what: str) -> str:
    """'<photo>.<what>', like the add-on's output images: light (World and its map), camera,
    shadow_catcher, composite."""
    return f"{photo_name}.{what}"


@dataclass(frozen=True)
class CameraSetup:
    resolution: tuple[int, int]            # (x, y) pixels: the photo's size
    lens_mm: float
    sensor_width_mm: float
    location: tuple[float, float, float]
    rotation_euler: tuple[float, float, float]


# the camera's roll about its view axis (Blender's Euler Y after X = 90 degrees) that renders the
# scene as a photo file of this EXIF orientation stores it: 6 stores the upright image turned 90
# degrees counter-clockwise, which a camera rolled 90 degrees clockwise (seen from behind) sees.
# The mirrored orientations (2, 4, 5, 7) no camera takes: unrolled
CAMERA_ROLL = {3: math.pi, 6: math.pi / 2, 8: -math.pi / 2}


def camera_setup(photo_size: tuple[int, int], lens_mm: float | None = None, orientation: int = 1) -> CameraSetup:
    """The photo camera for a photo of (height, width) pixels as Blender shows it (as stored): at
    CAMERA_HEIGHT, looking along +Y (Blender's rotation (90, 0, 0) degrees), rolled as the file's
    EXIF `orientation` says (CAMERA_ROLL: the world stays upright, as the network saw the photo),
    the photo's resolution, `lens_mm` (35 mm-equivalent) or DEFAULT_LENS_MM on a SENSOR_WIDTH_MM
    sensor fitted to the longer side."""
    height, width = (int(v) for v in photo_size)
    if height < 1 or width < 1:
        raise ValueError(f"a photo of {width} x {height} pixels has no camera")
    lens = DEFAULT_LENS_MM if lens_mm is None else float(lens_mm)
    return CameraSetup(resolution=(width, height), lens_mm=lens, sensor_width_mm=SENSOR_WIDTH_MM,
                       location=(0.0, 0.0, CAMERA_HEIGHT),
                       rotation_euler=(math.pi / 2, CAMERA_ROLL.get(orientation, 0.0), 0.0))


def floor_corners() -> list[tuple[float, float, float]]:
    """The shadow catcher: a rectangle on z = 0 from the camera's foot to FLOOR_DEPTH ahead."""
    w, d = FLOOR_HALF_WIDTH, FLOOR_DEPTH
    return [(-w, 0.0, 0.0), (w, 0.0, 0.0), (w, d, 0.0), (-w, d, 0.0)]


def focal_35mm(path: str) -> float | None:
    """The photo file's 35 mm-equivalent focal length (EXIF FocalLengthIn35mmFilm) as its header
    says it (relight.files.photo_header), or None (no such file, no EXIF, no tag, "unknown", an
    unreadable file)."""
    from relight.files.image_limits import ImageFileError
    from relight.files.photo_header import read_header

    try:
        return read_header(path, weigh=False).focal_35mm
    except (ImageFileError, OSError):
        return None


def write_light_map(light, path: str, width: int = MAP_WIDTH, lamp_free: bool = False):
    """The World map of the SH light `light` [n, 3] written to `path` as a float32 EXR (atomically):
    the smooth World left after the key light (relight.lighting.key_light.split_light), or with `lamp_free`
    the whole light as one map (relight.lighting.light_map). Returns (pixels, the KeyLight or None)."""
    from relight.files.exr import write_exr

    if lamp_free:
        from relight.lighting.light_map import light_map

        pixels, key = light_map(light, width).pixels, None
    else:
        from relight.lighting.key_light import split_light

        split = split_light(light, width)
        pixels, key = split.pixels, split.key
    write_exr(path, {c: pixels[..., i] for i, c in enumerate("RGB")})
    return pixels, key


@dataclass(frozen=True)
class LampSetup:
    """A Blender lamp for a key light: `kind` SUN or AREA, `location`, `direction` (unit, from the
    person toward the lamp: the lamp's local +Z, so it shines along -direction), `colour` (largest
    channel 1), `energy` (a Sun's Strength in W/m^2, an area lamp's Power in W), a Sun's `angle`
    (radians), an area disk's `size` (diameter, m)."""

    kind: str
    location: tuple[float, float, float]
    direction: tuple[float, float, float]
    colour: tuple[float, float, float]
    energy: float
    angle: float = 0.0
    size: float = 0.0


def lamp_setup(key) -> LampSetup:
    """The lamp that gives the person the key light `key` (relight.lighting.key_light.KeyLight).

    A Sun: Strength = the key's Blender strength, Angle = its angle. A wide key (KeyLight.wide): a
    disk of half-angle a (<= AREA_MAX_HALF_ANGLE) seen from the person at AREA_DISTANCE D, which
    is the key's cone; a Lambertian disk of Power P gives a surface facing it E = P / (pi (D^2 +
    r^2)) = P cos^2 a / (pi D^2), so P = pi E D^2 / cos^2 a with E the key's facing irradiance.
    """
    direction = tuple(float(v) for v in key.direction)
    colour = tuple(float(v) for v in key.colour)
    person = PERSON_POSITION
    if not key.wide:
        location = tuple(p + SUN_DISTANCE * d for p, d in zip(person, direction))
        return LampSetup("SUN", location, direction, colour, key.blender_strength, angle=2.0 * key.half_angle)
    half = min(key.half_angle, AREA_MAX_HALF_ANGLE)
    location = tuple(p + AREA_DISTANCE * d for p, d in zip(person, direction))
    power = math.pi * key.blender_strength * AREA_DISTANCE ** 2 / math.cos(half) ** 2
    return LampSetup("AREA", location, direction, colour, power, size=2.0 * AREA_DISTANCE * math.tan(half))
