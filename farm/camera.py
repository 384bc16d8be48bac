"""Photo-like full-body framing.

The camera frame is the one of docs/conventions.md: X right, Y forward (the
view axis), Z up. `world_to_camera` has those three unit vectors as rows, so
a world vector v becomes C @ v in the camera frame. Blender's camera object
looks along its local -Z with +Y up: its world rotation has the columns
(right, up, -forward).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

SENSOR_MM = 36.0  # full-frame width: focal lengths are 35 mm equivalents


@dataclass
class Camera:
    location: np.ndarray  # [3] world
    world_to_camera: np.ndarray  # [3, 3] rows: right, forward, up
    focal_mm: float
    pitch_deg: float
    roll_deg: float
    fill: float  # fraction of the frame height the person spans (before the fit check)
    offset: list[float]  # target offset from the person's centre, fractions of the frame

    @property
    def blender_rotation(self) -> np.ndarray:
        right, forward, up = self.world_to_camera
        return np.stack([right, up, -forward], axis=1)

    def to_camera(self, points: np.ndarray) -> np.ndarray:
        """World points [N, 3] -> camera frame [N, 3]."""
        return (np.asarray(points) - self.location) @ self.world_to_camera.T

    def project(self, points: np.ndarray) -> np.ndarray:
        """Camera-frame points -> normalized image coords in [-0.5, 0.5] (x right, y up), square film."""
        p = self.to_camera(points)
        scale = self.focal_mm / SENSOR_MM
        return np.stack([p[:, 0] / p[:, 1], p[:, 2] / p[:, 1]], axis=1) * scale

    def as_dict(self) -> dict:
        return {
            "location": self.location.tolist(),
            "world_to_camera": self.world_to_camera.tolist(),
            "focal_mm_35mm_equivalent": self.focal_mm,
            "sensor_width_mm": SENSOR_MM,
            "pitch_deg": self.pitch_deg,
            "roll_deg": self.roll_deg,
            "fill": self.fill,
            "offset": self.offset,
        }


def orientation(pitch_deg: float, roll_deg: float) -> np.ndarray:
    """World-to-camera rows for a camera looking along +Y, pitched up by pitch, rolled by roll."""
    p, r = math.radians(pitch_deg), math.radians(roll_deg)
    forward = np.array([0.0, math.cos(p), math.sin(p)])
    right0 = np.array([1.0, 0.0, 0.0])
    up0 = np.cross(right0, forward)
    right = math.cos(r) * right0 + math.sin(r) * up0
    up = np.cross(right, forward)
    return np.stack([right, forward, up])


def frame_person(vertices: np.ndarray, rng: np.random.Generator) -> Camera:
    """A camera that sees every vertex, with random focal length, tilt and placement."""
    focal = float(rng.uniform(35.0, 85.0))
    pitch = float(rng.uniform(-8.0, 8.0))
    roll = float(rng.uniform(-3.0, 3.0))
    fill = float(rng.uniform(0.72, 0.92))
    rot = orientation(pitch, roll)
    lo, hi = vertices.min(axis=0), vertices.max(axis=0)
    centre = 0.5 * (lo + hi)
    height = float(hi[2] - lo[2])
    # Distance that makes the person `fill` of the frame height: frame height at
    # distance d is d * SENSOR / focal.
    distance = height / fill * focal / SENSOR_MM + 0.5 * float(hi[1] - lo[1])
    slack = max(0.0, 1.0 - fill)
    offset = [float(rng.uniform(-0.5, 0.5) * slack), float(rng.uniform(-0.5, 0.5) * slack * 0.5)]
    frame_size = distance * SENSOR_MM / focal
    right, forward, up = rot
    target = centre - offset[0] * frame_size * right - offset[1] * frame_size * up
    for _ in range(40):
        cam = Camera(target - distance * forward, rot, focal, pitch, roll, fill, offset)
        uv = cam.project(vertices)
        depth = cam.to_camera(vertices)[:, 1]
        if depth.min() > 0.3 and np.abs(uv).max() < 0.48:
            return cam
        distance *= 1.06
    raise ValueError("could not frame the person inside the image")
