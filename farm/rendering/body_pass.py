"""The body under the clothes, seen by the scene's camera (issue 25): the posed, unclothed
body mesh ray-cast once per sub-pixel (numpy + embreex; no bpy, no Cycles).

    body_pass(cam_vertices, faces, cam_normals, resolution, focal_mm) -> BodyBuffers

The rays leave the camera (the origin of its own frame: X right, Y forward, Z up) through
the film as Blender's perspective camera maps it for a square image with the sensor fitted
horizontally: pixel (row i, column j) of R covers x in [j, j+1] / R - 1/2 and z in
1/2 - [i, i+1] / R of the film, at distance focal / sensor. `body_alpha` is the share of
a pixel's SUPERSAMPLE^2 rays that hit the body (box filter; Cycles' alpha uses a wider
Blackman-Harris filter, so edges differ by about a pixel). `body_normal` is the
smooth-shaded normal (the mesh's vertex normals, interpolated as Cycles does) averaged
over the hits and renormalized, 0 where nothing was hit; `body_depth` the mean hit
distance along the view axis (Y), 0 where nothing was hit. `body_back_depth` (the `body_back`
pass) is the same mean for the far side, where each ray leaves the body (cast back toward the
camera from beyond the body): with `body_depth`, the body's thickness along the ray.

RAY_CAST_PASSES is what farm.scene renders from here: a pass of relight/files/scene_passes.py
-> its channels of a drawn scene.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from farm.synthesis.camera import SENSOR_MM
from farm.synthesis.meshops import vertex_normals

SUPERSAMPLE = 2  # rays a pixel side: coverage in steps of 1/4


@dataclass
class BodyBuffers:
    normal: np.ndarray  # [R, R, 3] float32
    alpha: np.ndarray   # [R, R] float32 in [0, 1]
    depth: np.ndarray   # [R, R] float32, metres along the view axis

    def channels(self) -> dict[str, np.ndarray]:
        """The scene channels (relight.files.dataset names)."""
        return {"body_normal": self.normal, "body_alpha": self.alpha, "body_depth": self.depth}


def film_directions(resolution: int, focal_mm: float, supersample: int = SUPERSAMPLE) -> np.ndarray:
    """[R, R, s*s, 3] float32 ray directions (camera frame, not normalized) through the
    sub-pixel centres of each pixel, row 0 at the top of the image."""
    s = int(supersample)
    offsets = (np.arange(s) + 0.5) / s
    cells = (np.arange(resolution)[:, None] + offsets[None, :]).reshape(-1) / resolution  # [R*s]
    x = cells - 0.5                      # columns, left to right
    z = 0.5 - cells                      # rows, top to bottom
    scale = SENSOR_MM / float(focal_mm)
    zz, xx = np.meshgrid(z, x, indexing="ij")  # [R*s, R*s]
    dirs = np.stack([xx * scale, np.ones_like(xx), zz * scale], axis=-1)
    dirs = dirs.reshape(resolution, s, resolution, s, 3).transpose(0, 2, 1, 3, 4)
    return np.ascontiguousarray(dirs.reshape(resolution, resolution, s * s, 3), dtype=np.float32)


def body_pass(cam_vertices: np.ndarray, faces: np.ndarray, cam_normals: np.ndarray, resolution: int,
              focal_mm: float, supersample: int = SUPERSAMPLE) -> BodyBuffers:
    """Ray-cast the body mesh (camera frame) from the camera; see the module docstring."""
    faces = np.ascontiguousarray(faces, dtype=np.int32)
    flat = film_directions(resolution, focal_mm, supersample).reshape(-1, 3)
    hit = _cast(cam_vertices, faces, np.zeros_like(flat), flat)
    prim = np.asarray(hit["primID"])
    inside = prim >= 0
    u, v = np.asarray(hit["u"], np.float64), np.asarray(hit["v"], np.float64)
    tri = faces[np.where(inside, prim, 0)]
    n = cam_normals.astype(np.float64)
    normal = ((1.0 - u - v)[:, None] * n[tri[:, 0]] + u[:, None] * n[tri[:, 1]] + v[:, None] * n[tri[:, 2]])
    normal *= inside[:, None]
    depth = np.asarray(hit["tfar"], np.float64) * flat[:, 1] * inside  # Y of the hit point
    k = supersample * supersample
    normal = normal.reshape(resolution, resolution, k, 3).sum(axis=2)
    length = np.linalg.norm(normal, axis=-1, keepdims=True)
    normal = np.where(length > 1e-9, normal / np.maximum(length, 1e-9), 0.0)
    hits = inside.reshape(resolution, resolution, k).sum(axis=2)
    depth = depth.reshape(resolution, resolution, k).sum(axis=2) / np.maximum(hits, 1)
    return BodyBuffers(normal=normal.astype(np.float32), alpha=(hits / k).astype(np.float32),
                       depth=depth.astype(np.float32))


def _cast(vertices: np.ndarray, faces: np.ndarray, origins: np.ndarray, directions: np.ndarray) -> dict:
    from embreex import rtcore_scene
    from embreex.mesh_construction import TriangleMesh

    scene = rtcore_scene.EmbreeScene()
    TriangleMesh(scene, np.ascontiguousarray(vertices, dtype=np.float32), np.ascontiguousarray(faces, dtype=np.int32))
    return scene.run(np.ascontiguousarray(origins, np.float32), np.ascontiguousarray(directions, np.float32),
                     output=1)


def body_back_depth(cam_vertices: np.ndarray, faces: np.ndarray, resolution: int, focal_mm: float,
                    supersample: int = SUPERSAMPLE) -> np.ndarray:
    """[R, R] float32: the mean view-axis depth where the camera's sub-pixel rays leave the mesh
    (its last crossing along each ray), 0 where no ray meets it. Each ray is cast back toward the
    camera from beyond the mesh; its first hit is the ray's last crossing."""
    flat = film_directions(resolution, focal_mm, supersample).reshape(-1, 3)  # Y component 1: t is depth
    beyond = float(np.max(cam_vertices[:, 1])) + 1.0
    hit = _cast(cam_vertices, faces, flat * beyond, -flat)
    inside = np.asarray(hit["primID"]) >= 0
    depth = (beyond - np.asarray(hit["tfar"], np.float64)) * inside
    k = supersample * supersample
    hits = inside.reshape(resolution, resolution, k).sum(axis=2)
    return (depth.reshape(resolution, resolution, k).sum(axis=2) / np.maximum(hits, 1)).astype(np.float32)


def _camera_body(sample):
    if sample.body_mesh is None:
        raise ValueError(f"scene {sample.index}: no body mesh was drawn (the body pass needs one)")
    vertices, faces = sample.body_mesh
    return sample.camera.to_camera(vertices), faces


def scene_body_back(sample) -> dict[str, np.ndarray]:
    """The `body_back` pass of a farm.scene.SceneSample: its unclothed body's far side."""
    vertices, faces = _camera_body(sample)
    return {"body_back_depth": body_back_depth(vertices, faces, sample.options.resolution, sample.camera.focal_mm)}


def scene_body_buffers(sample) -> BodyBuffers:
    """The unclothed body of a farm.scene.SceneSample seen by its camera."""
    vertices, faces = _camera_body(sample)
    normals = vertex_normals(*sample.body_mesh) @ sample.camera.world_to_camera.T
    return body_pass(vertices, faces, normals, sample.options.resolution, sample.camera.focal_mm)


RAY_CAST_PASSES = {
    "body": lambda sample: scene_body_buffers(sample).channels(),
    "body_back": scene_body_back,
}
