"""blender_addon.logic.photo_light without Blender: the camera, the floor, the EXIF focal length, the map file."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from blender_addon.logic import photo_light
from relight.lighting.light import directional_light
from relight.files.exr import read_exr
from relight.lighting.light_map import light_map


def test_camera_is_the_photo_camera_at_the_photos_resolution():
    setup = photo_light.camera_setup((4000, 6000))
    assert setup.resolution == (6000, 4000)
    assert setup.lens_mm == photo_light.DEFAULT_LENS_MM and setup.sensor_width_mm == 36.0
    # Blender's camera looks along its -Z; (90, 0, 0) degrees about X turns it to +Y, its up to +Z
    assert setup.rotation_euler == (math.pi / 2, 0.0, 0.0)
    assert setup.location == (0.0, 0.0, photo_light.CAMERA_HEIGHT)
    assert photo_light.camera_setup((10, 20), lens_mm=28.0).lens_mm == 28.0
    with pytest.raises(ValueError, match="no camera"):
        photo_light.camera_setup((0, 20))


def test_floor_is_on_the_ground_in_front_of_the_camera():
    corners = np.array(photo_light.floor_corners())
    assert np.all(corners[:, 2] == 0.0) and corners[:, 1].min() == 0.0
    assert corners[:, 1].max() == photo_light.FLOOR_DEPTH
    assert np.ptp(corners[:, 0]) == 2 * photo_light.FLOOR_HALF_WIDTH


def _jpeg(path, focal=None):
    exif = Image.Exif()
    if focal is not None:
        exif.get_ifd(0x8769)[0xA405] = focal
    Image.new("RGB", (16, 12), (120, 90, 60)).save(path, exif=exif)
    return str(path)


def test_focal_length_comes_from_exif_when_the_photo_says_it(tmp_path):
    assert photo_light.focal_35mm(_jpeg(tmp_path / "a.jpg", 28)) == 28.0
    assert photo_light.focal_35mm(_jpeg(tmp_path / "b.jpg")) is None
    assert photo_light.focal_35mm(_jpeg(tmp_path / "c.jpg", 0)) is None  # 0: "unknown" in EXIF
    assert photo_light.focal_35mm(str(tmp_path / "missing.jpg")) is None
    (tmp_path / "bad.jpg").write_bytes(b"not an image")
    assert photo_light.focal_35mm(str(tmp_path / "bad.jpg")) is None


def test_the_map_file_is_the_light_map_written_losslessly(tmp_path):
    from relight.lighting.key_light import split_light

    light = directional_light(30.0, 4)
    pixels, key = photo_light.write_light_map(light, str(tmp_path / "light.exr"), width=64)
    planes = read_exr(tmp_path / "light.exr")
    split = split_light(light, 64)
    np.testing.assert_array_equal(np.stack([planes[c] for c in "RGB"], -1), split.pixels)  # the smooth World
    np.testing.assert_array_equal(pixels, split.pixels)
    np.testing.assert_allclose(key.direction, split.key.direction)
    pixels, key = photo_light.write_light_map(light, str(tmp_path / "light.exr"), width=64, lamp_free=True)
    planes = read_exr(tmp_path / "light.exr")
    np.testing.assert_array_equal(np.stack([planes[c] for c in "RGB"], -1), light_map(light, 64).pixels)
    assert key is None and pixels.shape == (32, 64, 3)
    with pytest.raises(FileNotFoundError):
        photo_light.write_light_map(light, str(tmp_path / "no" / "light.exr"), width=64)
    assert [p.name for p in tmp_path.iterdir()] == ["light.exr"]  # nothing else was left behind


def test_names_follow_the_add_ons_outputs():
    assert photo_light.datablock_name("p.jpg", "light") == "p.jpg.light"


def test_the_key_lamp_is_a_sun_or_a_disk_subtending_the_keys_cone():
    from relight.lighting.key_light import KeyLight, direction_from_angles

    d = direction_from_angles(40.0, 30.0)
    sun = photo_light.lamp_setup(KeyLight(d, np.array([2.0, 1.0, 0.5]), math.radians(5.0)))
    assert sun.kind == "SUN" and sun.angle == pytest.approx(math.radians(10.0))
    assert sun.energy == pytest.approx(2.0 * (1 + math.cos(math.radians(5.0))) / 2)  # S g_1: Cycles' Strength
    np.testing.assert_allclose(sun.colour, [1.0, 0.5, 0.25])
    np.testing.assert_allclose(sun.direction, d)
    np.testing.assert_allclose(np.subtract(sun.location, photo_light.PERSON_POSITION), photo_light.SUN_DISTANCE * d)
    for half_deg in (60.0, 85.0):  # wide: a disk 4 m away; beyond 75 degrees its cone is capped there
        key = KeyLight(d, np.array([1.0, 1.0, 1.0]), math.radians(half_deg))
        area = photo_light.lamp_setup(key)
        a = min(math.radians(half_deg), photo_light.AREA_MAX_HALF_ANGLE)
        D = photo_light.AREA_DISTANCE
        assert area.kind == "AREA" and area.size == pytest.approx(2 * D * math.tan(a))
        # a Lambertian disk of Power P gives a facing surface P cos^2 a / (pi D^2): the key's S g_1
        assert area.energy * math.cos(a) ** 2 / (math.pi * D * D) == pytest.approx(key.blender_strength)
        np.testing.assert_allclose(np.subtract(area.location, photo_light.PERSON_POSITION), D * d)
