"""The person in the 3D scene: a relief mesh of the decomposition's depth, seen from the photo camera (no bpy).

Compositing Setup puts a proxy of the person where the photo shows them (bl_proxy builds the two
objects): a mesh with a quad for each working pixel the matte covers, each corner moved along its
pixel's camera ray to a distance D plus the relief. Seen from the camera it covers exactly the
person's pixels at any D and any relief (a point anywhere on a pixel's ray projects to that
pixel), so D only sets the person's size in metres: it is the distance at which the lowest point
stands on the floor (the person's feet, when the matte ends above the photo's bottom edge and below
the horizon), else photo_light.PERSON_DISTANCE.

Frames: the upright photo camera of docs/conventions.md (X right, Y along the view, Z up, the
camera at the origin; pixels of the upright photo, rows down). The relief (relight.geometry.relief,
Decomposition.shadows.depth) is orthographic and in working pixels along +Y; one working pixel spans
s = (y1 - y0) / h photo pixels, and a photo pixel at distance D spans D / f metres (f the focal
length in photo pixels), so a depth d sits d s D / f metres behind the distance D.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from .photo_light import CAMERA_HEIGHT, FLOOR_DEPTH, PERSON_DISTANCE

COVERAGE = 0.5          # a working pixel is the person's when the matte covers at least half of it
CASTER_MARGIN = 0.01    # the shadow caster's nearest point this much (relative) behind the catcher's farthest
MAX_CASTER_SCALE = 1.25 # a deeper relief's caster would cast shadows this much too large: not pushed farther
MIN_DISTANCE = 0.5      # metres: a grounded distance outside [MIN_DISTANCE, FLOOR_DEPTH] is not trusted


@dataclass(frozen=True)
class ReliefMesh:
    """vertices [n, 3] float32 (metres, upright camera frame), faces [m, 4] int32 (quads facing the
    camera, one per working pixel of the person), the distance D (metres) and whether it grounds
    the person's lowest point on the floor."""

    vertices: np.ndarray
    faces: np.ndarray
    distance: float
    grounded: bool


def focal_pixels(lens_mm: float, sensor_width_mm: float, sensor_height_mm: float, sensor_fit: str,
                 width: int, height: int) -> float:
    """The focal length in pixels of a camera rendering width x height (square pixels), as Blender
    fits its sensor: AUTO the sensor width to the longer side, HORIZONTAL to the width, VERTICAL the
    sensor height to the height."""
    if sensor_fit == "VERTICAL":
        return lens_mm / sensor_height_mm * height
    side = width if sensor_fit == "HORIZONTAL" else max(width, height)
    return lens_mm / sensor_width_mm * side


def _corner_grid(depth: np.ndarray, inside: np.ndarray):
    """The corners of the pixels `inside` [h, w]: their flat indices into the (h + 1) x (w + 1)
    corner grid, and each corner's depth, the mean of the inside pixels it touches."""
    h, w = inside.shape
    total = np.zeros((h + 1, w + 1), np.float64)
    count = np.zeros((h + 1, w + 1), np.float64)
    d = np.where(inside, depth, 0.0)
    for dr in (0, 1):
        for dc in (0, 1):
            total[dr:dr + h, dc:dc + w] += d
            count[dr:dr + h, dc:dc + w] += inside
    used = count > 0
    corner_depth = np.where(used, total / np.maximum(count, 1.0), 0.0)
    return used, corner_depth


def relief_mesh(depth, alpha, box, photo_size: tuple[int, int], focal_px: float,
                camera_height: float | None = CAMERA_HEIGHT) -> ReliefMesh:
    """The proxy of the person whose relief `depth` [h, w] (working pixels along +Y) and matte
    `alpha` [h, w] cover the crop `box` (y0, y1, x0, x1, upright photo pixels) of a photo of
    `photo_size` (height, width) seen by a camera of focal length `focal_px` pixels with its
    principal point at the photo's centre. The person stands on a floor `camera_height` metres
    below the camera when their lowest point is in view (None: never grounded)."""
    depth = np.asarray(depth, np.float64)
    alpha = np.asarray(alpha)
    if depth.ndim != 2 or depth.shape != alpha.shape:
        raise ValueError(f"depth and alpha must be [h, w] of one size, got {depth.shape} and {alpha.shape}")
    if not np.all(np.isfinite(depth)):
        raise ValueError("the relief must be finite")
    if not focal_px > 0:
        raise ValueError(f"the focal length must be > 0 pixels, got {focal_px}")
    h, w = depth.shape
    y0, y1, x0, x1 = (float(v) for v in box)
    height, width = (int(v) for v in photo_size)
    sy, sx = (y1 - y0) / h, (x1 - x0) / w         # photo pixels per working pixel
    inside = alpha >= COVERAGE
    used, corner_depth = _corner_grid(depth, inside)
    index = np.full((h + 1, w + 1), -1, np.int64)
    index[used] = np.arange(int(used.sum()))
    rows, cols = np.nonzero(used)
    # each corner on its ray (u, 1, -v) at distance t = D (1 + d s / f); built at D = 1, scaled after
    u = (x0 + cols * sx - 0.5 * width) / focal_px
    v = (y0 + rows * sy - 0.5 * height) / focal_px
    t = 1.0 + corner_depth[rows, cols] * sy / focal_px
    unit = np.stack([u * t, t, -v * t], axis=-1)
    pr, pc = np.nonzero(inside)  # quads (i, j), (i + 1, j), (i + 1, j + 1), (i, j + 1): counter-clockwise
    faces = np.stack([index[pr, pc], index[pr + 1, pc], index[pr + 1, pc + 1], index[pr, pc + 1]], axis=-1)
    distance, grounded = PERSON_DISTANCE, False
    lowest = float(unit[:, 2].min()) if len(unit) else 0.0
    feet_in_view = bool(len(pr)) and y0 + (pr.max() + 1) * sy < height - sy  # the matte ends above the bottom edge
    if camera_height is not None and camera_height > 0 and feet_in_view and lowest < 0:
        ground = camera_height / -lowest
        if MIN_DISTANCE <= ground <= FLOOR_DEPTH:
            distance, grounded = ground, True
    return ReliefMesh((unit * distance).astype(np.float32), faces.astype(np.int32), float(distance), grounded)


def caster_scale(vertices: np.ndarray) -> float:
    """How much the shadow caster is the proxy scaled about the camera: every vertex stays on its ray
    (the caster's silhouette is the person's) and the caster's nearest point lies CASTER_MARGIN behind
    the proxy's farthest, so that no shadow ray leaving the proxy toward a light on the camera's side
    of the person meets the caster (the photo holds the person's own shadows already: they would darken
    it twice). At most MAX_CASTER_SCALE: the person's shadow on the floor grows with the scale (8 %
    for a relief 0.2 m deep at 3 m)."""
    y = np.asarray(vertices, np.float64)[:, 1]
    if not len(y):
        return 1.0 + CASTER_MARGIN
    return float(min(y.max() / y.min() * (1.0 + CASTER_MARGIN), MAX_CASTER_SCALE))


def caster_vertices(vertices: np.ndarray) -> np.ndarray:
    """The shadow caster's vertices: the proxy's scaled about the camera by caster_scale."""
    return (np.asarray(vertices, np.float64) * caster_scale(vertices)).astype(np.float32)


def euler_xyz_matrix(euler) -> np.ndarray:
    """Blender's XYZ Euler rotation (radians) as a 3 x 3 matrix: Rz @ Ry @ Rx."""
    a, b, c = (float(x) for x in euler)
    rx = np.array([[1, 0, 0], [0, math.cos(a), -math.sin(a)], [0, math.sin(a), math.cos(a)]])
    ry = np.array([[math.cos(b), 0, math.sin(b)], [0, 1, 0], [-math.sin(b), 0, math.cos(b)]])
    rz = np.array([[math.cos(c), -math.sin(c), 0], [math.sin(c), math.cos(c), 0], [0, 0, 1]])
    return rz @ ry @ rx


def to_camera_local(vertices: np.ndarray, camera_rotation_euler) -> np.ndarray:
    """Upright-frame vertices in the local frame of the photo camera as Compositing Setup makes it
    (rotation `camera_rotation_euler`, photo_light.camera_setup: its roll follows the photo's EXIF
    orientation), so that a proxy parented to the camera stays on the person wherever the artist
    moves the camera."""
    rotation = euler_xyz_matrix(camera_rotation_euler)
    return (np.asarray(vertices, np.float64) @ rotation).astype(np.float32)  # R^T v for each row v
