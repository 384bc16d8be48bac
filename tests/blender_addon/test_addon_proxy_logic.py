"""The person proxy's geometry (blender_addon.logic.person_proxy, no bpy): a relief mesh of working
pixels, each corner on its pixel's camera ray, its relief in metres at the distance D, standing on
the floor when the person's feet are in view."""

from __future__ import annotations

import math

import numpy as np
import pytest

from blender_addon.logic import person_proxy, photo_light

F = 500.0                       # focal length, photo pixels
PHOTO = (400, 300)              # (height, width)
BOX = (100, 300, 50, 250)       # y0, y1, x0, x1: 200 x 200 photo pixels
WORK = (20, 20)                 # working size: one working pixel spans 10 photo pixels


def project(vertices: np.ndarray) -> np.ndarray:
    """Photo pixels (x right, y down) of upright-frame points, principal point at the photo's centre."""
    x, y, z = vertices[:, 0].astype(np.float64), vertices[:, 1].astype(np.float64), vertices[:, 2].astype(np.float64)
    return np.stack([PHOTO[1] / 2 + F * x / y, PHOTO[0] / 2 - F * z / y], -1)


def block(rows: slice, cols: slice) -> np.ndarray:
    alpha = np.zeros(WORK, np.float32)
    alpha[rows, cols] = 1.0
    return alpha


def test_a_block_of_pixels_gives_a_quad_each_and_their_corners():
    alpha = block(slice(5, 8), slice(4, 7))           # 3 x 3 pixels
    alpha[2, 2] = 0.49                                # under half covered: not the person's
    alpha[12, 12] = 0.5                               # a lone pixel: 1 quad, 4 corners
    mesh = person_proxy.relief_mesh(np.zeros(WORK), alpha, BOX, PHOTO, F, camera_height=None)
    assert mesh.faces.shape == (10, 4) and mesh.vertices.shape == (16 + 4, 3)
    assert mesh.vertices.dtype == np.float32 and mesh.faces.dtype == np.int32
    assert set(np.unique(mesh.faces)) == set(range(20))
    assert mesh.distance == photo_light.PERSON_DISTANCE and not mesh.grounded


def test_every_corner_projects_onto_its_pixel_corner_whatever_the_relief():
    rng = np.random.default_rng(0)
    alpha = block(slice(3, 17), slice(5, 15))
    depth = rng.normal(0.0, 8.0, WORK).astype(np.float32)
    mesh = person_proxy.relief_mesh(depth, alpha, BOX, PHOTO, F, camera_height=None)
    at = project(mesh.vertices)
    # corner (i, j) of the working grid is photo pixel (x0 + 10 j, y0 + 10 i)
    j, i = (at[:, 0] - BOX[2]) / 10.0, (at[:, 1] - BOX[0]) / 10.0
    np.testing.assert_allclose(j, np.round(j), atol=1e-4)
    np.testing.assert_allclose(i, np.round(i), atol=1e-4)
    corners = set(zip(np.round(i).astype(int), np.round(j).astype(int)))
    assert corners == {(r, c) for r in range(3, 18) for c in range(5, 16)}
    # each face's corners are its pixel's, counter-clockwise as the camera sees them (x right, y down:
    # down the left side, right along the bottom, up the right side)
    quad = at[mesh.faces]                                             # [m, 4, 2]
    assert np.all(quad[:, 1, 1] > quad[:, 0, 1]) and np.all(quad[:, 2, 0] > quad[:, 1, 0])
    assert np.all(quad[:, 3, 1] < quad[:, 2, 1])


def test_the_relief_keeps_its_depth_differences_in_metres_at_the_distance():
    alpha = block(slice(4, 6), slice(4, 6))
    depth = np.zeros(WORK, np.float32)
    depth[4:6, 5] = 25.0       # the right column 25 working pixels farther (its corners average it)
    mesh = person_proxy.relief_mesh(depth, alpha, BOX, PHOTO, F, camera_height=None)
    at = project(mesh.vertices)
    j = np.round((at[:, 0] - BOX[2]) / 10.0).astype(int)
    y = mesh.vertices[:, 1].astype(np.float64)
    # a working pixel is 10 photo pixels, a photo pixel at D = 3 m is 3 / 500 m: 25 px -> 1.5 m
    metres = 25.0 * 10.0 * photo_light.PERSON_DISTANCE / F
    np.testing.assert_allclose(y[j == 4], photo_light.PERSON_DISTANCE, rtol=1e-6)           # left edge: 0
    np.testing.assert_allclose(y[j == 5], photo_light.PERSON_DISTANCE + metres / 2, rtol=1e-6)  # the seam
    np.testing.assert_allclose(y[j == 6], photo_light.PERSON_DISTANCE + metres, rtol=1e-6)      # right edge


def test_the_person_stands_on_the_floor_when_their_feet_are_in_view():
    alpha = block(slice(2, 18), slice(8, 12))   # rows 120 to 280 of 400: the feet below the horizon
    flat = person_proxy.relief_mesh(np.zeros(WORK), alpha, BOX, PHOTO, F, camera_height=1.5)
    # the feet's row (photo row 280, 80 below the centre) meets the floor at D = 1.5 * 500 / 80
    assert flat.grounded and flat.distance == pytest.approx(1.5 * F / 80.0, rel=1e-9)
    depth = np.linspace(-3.0, 3.0, WORK[0] * WORK[1]).reshape(WORK).astype(np.float32)
    mesh = person_proxy.relief_mesh(depth, alpha, BOX, PHOTO, F, camera_height=1.5)
    assert mesh.grounded
    assert mesh.vertices[:, 2].min() == pytest.approx(-1.5, abs=1e-6)   # the lowest point on the floor
    at = project(mesh.vertices)
    assert np.all(np.abs(at[:, 1] - np.round(at[:, 1])) < 1e-3)   # still on the pixels' corners
    # the feet cut off by the photo's bottom edge, above the horizon, or no floor: the set distance
    low = block(slice(2, 20), slice(8, 12))
    tall = person_proxy.relief_mesh(depth, low, (200, 400, 50, 250), PHOTO, F, camera_height=1.5)
    high = person_proxy.relief_mesh(depth, block(slice(0, 4), slice(8, 12)), BOX, PHOTO, F, camera_height=1.5)
    none = person_proxy.relief_mesh(depth, alpha, BOX, PHOTO, F, camera_height=None)
    for mesh in (tall, high, none):
        assert not mesh.grounded and mesh.distance == photo_light.PERSON_DISTANCE


def test_the_caster_lies_wholly_behind_the_mesh_on_the_same_rays():
    alpha = block(slice(3, 9), slice(3, 9))
    depth = np.zeros(WORK, np.float32)
    depth[3:9, 3:6] = 10.0      # the left half 10 working pixels (0.6 m at 3 m) farther
    mesh = person_proxy.relief_mesh(depth, alpha, BOX, PHOTO, F, None)
    caster = person_proxy.caster_vertices(mesh.vertices)
    np.testing.assert_allclose(project(caster), project(mesh.vertices), atol=1e-4)   # the same silhouette
    y, yc = mesh.vertices[:, 1].astype(np.float64), caster[:, 1].astype(np.float64)
    scale = yc / y
    np.testing.assert_allclose(scale, scale[0], rtol=1e-6)                             # scaled about the camera
    # nearest caster point 1 % behind the farthest proxy point: 3 m and 3.6 m deep -> 3.6 / 3 * 1.01
    assert scale[0] == pytest.approx(3.6 / 3.0 * (1.0 + person_proxy.CASTER_MARGIN), rel=1e-5)
    assert yc.min() > y.max()
    # a relief deeper than MAX_CASTER_SCALE allows: pushed back that far only
    depth[3:9, 3:6] = 100.0
    deep = person_proxy.relief_mesh(depth, alpha, BOX, PHOTO, F, None)
    assert person_proxy.caster_scale(deep.vertices) == person_proxy.MAX_CASTER_SCALE
    flat = person_proxy.relief_mesh(np.zeros(WORK), alpha, BOX, PHOTO, F, None)
    assert person_proxy.caster_scale(flat.vertices) == pytest.approx(1.0 + person_proxy.CASTER_MARGIN)


def test_the_camera_local_frame_undoes_the_cameras_rotation():
    # the unrolled photo camera (90, 0, 0): its local -Z is the view (+Y), its local +Y is up (+Z)
    points = np.array([[0.0, 3.0, 0.0], [1.0, 3.0, 0.0], [0.0, 3.0, 1.0]], np.float32)
    local = person_proxy.to_camera_local(points, (math.pi / 2, 0.0, 0.0))
    np.testing.assert_allclose(local, [[0, 0, -3], [1, 0, -3], [0, 1, -3]], atol=1e-6)
    rotation = person_proxy.euler_xyz_matrix((math.pi / 2, math.pi / 2, 0.0))  # rolled (EXIF 6)
    np.testing.assert_allclose(person_proxy.to_camera_local(points, (math.pi / 2, math.pi / 2, 0.0)) @ rotation.T,
                               points, atol=1e-6)


def test_focal_length_in_pixels_follows_blenders_sensor_fit():
    assert person_proxy.focal_pixels(50, 36, 24, "AUTO", 48, 72) == pytest.approx(100.0)   # the longer side
    assert person_proxy.focal_pixels(50, 36, 24, "AUTO", 72, 48) == pytest.approx(100.0)
    assert person_proxy.focal_pixels(50, 36, 24, "HORIZONTAL", 48, 72) == pytest.approx(50 / 36 * 48)
    assert person_proxy.focal_pixels(50, 36, 24, "VERTICAL", 48, 72) == pytest.approx(50 / 24 * 72)


def test_bad_input_is_refused_with_its_cause():
    with pytest.raises(ValueError, match="one size"):
        person_proxy.relief_mesh(np.zeros((3, 3)), np.zeros((3, 4)), BOX, PHOTO, F)
    with pytest.raises(ValueError, match="finite"):
        person_proxy.relief_mesh(np.full(WORK, np.nan), block(slice(1, 2), slice(1, 2)), BOX, PHOTO, F)
    with pytest.raises(ValueError, match="focal"):
        person_proxy.relief_mesh(np.zeros(WORK), block(slice(1, 2), slice(1, 2)), BOX, PHOTO, 0.0)
