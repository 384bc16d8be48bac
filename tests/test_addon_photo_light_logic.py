"""blender_addon.photo_light without Blender: the camera, the floor, the EXIF focal length, the map file."""

from __future__ import annotations

import math

import numpy as np
import pytest
from PIL import Image

from blender_addon import photo_light
from relight.light import directional_light
from relight.exr import read_exr
from relight.light_map import light_map


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
    light = directional_light(30.0, 4)
    result = photo_light.write_light_map(light, str(tmp_path / "light.exr"), width=64)
    planes = read_exr(tmp_path / "light.exr")
    np.testing.assert_array_equal(np.stack([planes[c] for c in "RGB"], -1), light_map(light, 64).pixels)
    assert result.pixels.shape == (32, 64, 3)
    with pytest.raises(FileNotFoundError):
        photo_light.write_light_map(light, str(tmp_path / "no" / "light.exr"), width=64)
    assert [p.name for p in tmp_path.iterdir()] == ["light.exr"]  # nothing else was left behind


def test_names_follow_the_add_ons_outputs():
    assert photo_light.datablock_name("p.jpg", "light") == "p.jpg.light"
