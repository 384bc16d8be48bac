"""Per-vertex SH light transport by ray casting (numpy + embreex, no bpy).

T_lm(x) = integral over the sphere of f_r(x, v, w) V(x, w) max(0, n.w) Y_lm(w) dw,
estimated with S stratified directions (a randomly rotated spherical Fibonacci
set, each of weight 4 pi / S). Visibility comes from embree occlusion queries,
vectorised over every (vertex, upper-hemisphere direction) pair and split into
chunks run on a thread pool (embreex releases the GIL).

f_r is a white BRDF:
- diffuse-only bake: Lambert 1/pi, so an unoccluded point under constant
  radiance 1 gets T.L = 1;
- view-dependent bake: Oren-Nayar diffuse (Fujii's energy-bounded form) plus
  GGX specular (height-correlated Smith shadowing, Schlick Fresnel, roughness
  shared with the diffuse lobe), the view direction pointing at the camera.
"""

from __future__ import annotations

import math
import os
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numpy as np

from relight.lighting import sh

# Smallest GGX alpha ever used: alpha -> 0 is a delta lobe that no finite
# direction set can integrate.
ALPHA_FLOOR = 0.02
# Fresnel reflectance at normal incidence of a dielectric with IOR 1.5.
DIELECTRIC_F0 = 0.04


@dataclass(frozen=True)
class VertexMaterials:
    """Per-vertex white-BRDF parameters for the view-dependent bake (all [V])."""

    roughness: np.ndarray  # Principled roughness in [0, 1]; GGX alpha = roughness^2
    metallic: np.ndarray  # [0, 1]
    specular: np.ndarray  # dielectric Fresnel scale in [0, 2] (Principled "Specular IOR Level" * 2)

    def validate(self, count: int) -> None:
        for name in ("roughness", "metallic", "specular"):
            values = np.asarray(getattr(self, name))
            if values.shape != (count,):
                raise ValueError(f"VertexMaterials.{name} must have shape ({count},), got {values.shape}")
            if not np.all(np.isfinite(values)):
                raise ValueError(f"VertexMaterials.{name} holds NaN or Inf")
        if np.any((self.roughness < 0) | (self.roughness > 1)):
            raise ValueError("VertexMaterials.roughness must lie in [0, 1]")
        if np.any((self.metallic < 0) | (self.metallic > 1)):
            raise ValueError("VertexMaterials.metallic must lie in [0, 1]")
        if np.any((self.specular < 0) | (self.specular > 2)):
            raise ValueError("VertexMaterials.specular must lie in [0, 2]")


@dataclass
class BakeResult:
    transport: np.ndarray  # [V, (order+1)^2] float32
    directions: int
    rays: int  # occlusion rays cast
    ray_seconds: float  # wall time inside embree
    seconds: float  # wall time of the whole bake
    specular: bool  # True when the view-dependent BRDF was used
    alpha_floor: float  # GGX alpha clamp actually applied (0 for diffuse)


def fibonacci_directions(count: int, rng: np.random.Generator | None = None) -> np.ndarray:
    """`count` unit vectors of a spherical Fibonacci set (equal-area strata).

    With `rng`, the whole set is turned by a uniformly random rotation so that
    successive scenes do not share the same stratification.
    """
    if count < 1:
        raise ValueError(f"direction count must be >= 1, got {count}")
    i = np.arange(count, dtype=np.float64)
    z = 1.0 - (2.0 * i + 1.0) / count
    radius = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    golden_angle = math.pi * (3.0 - math.sqrt(5.0))
    phi = golden_angle * i
    dirs = np.stack([radius * np.cos(phi), radius * np.sin(phi), z], axis=1)
    if rng is not None:
        dirs = dirs @ random_rotation(rng).T
    return dirs


def random_rotation(rng: np.random.Generator) -> np.ndarray:
    """Uniformly distributed 3x3 rotation (QR of a Gaussian matrix, sign-fixed)."""
    q, r = np.linalg.qr(rng.standard_normal((3, 3)))
    q = q * np.sign(np.diag(r))
    if np.linalg.det(q) < 0:
        q[:, 0] = -q[:, 0]
    return q


def _validate_mesh(vertices, faces, normals):
    vertices = np.asarray(vertices)
    faces = np.asarray(faces)
    normals = np.asarray(normals)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or len(vertices) == 0:
        raise ValueError(f"vertices must have shape [V, 3] with V > 0, got {vertices.shape}")
    if faces.ndim != 2 or faces.shape[1] != 3 or len(faces) == 0:
        raise ValueError(f"faces must have shape [F, 3] with F > 0, got {faces.shape}")
    if normals.shape != vertices.shape:
        raise ValueError(f"normals must have the shape of vertices {vertices.shape}, got {normals.shape}")
    if not np.all(np.isfinite(vertices)):
        raise ValueError("vertices hold NaN or Inf")
    if not np.all(np.isfinite(normals)):
        raise ValueError("normals hold NaN or Inf")
    if faces.min() < 0 or faces.max() >= len(vertices):
        raise ValueError("faces index vertices out of range")
    lengths = np.linalg.norm(normals, axis=1)
    if np.any(np.abs(lengths - 1.0) > 1e-3):
        raise ValueError("normals must be unit vectors")


class OcclusionTester:
    """Embree scene of one triangle mesh answering batched shadow-ray queries."""

    def __init__(self, vertices: np.ndarray, faces: np.ndarray, threads: int | None = None):
        from embreex import rtcore_scene
        from embreex.mesh_construction import TriangleMesh

        self._scene = rtcore_scene.EmbreeScene()
        # embreex keeps a reference to the buffers it was given.
        self._vertices = np.ascontiguousarray(vertices, dtype=np.float32)
        self._faces = np.ascontiguousarray(faces, dtype=np.int32)
        TriangleMesh(self._scene, self._vertices, self._faces)
        self.threads = max(1, threads or os.cpu_count() or 1)

    def occluded(self, origins: np.ndarray, directions: np.ndarray, chunk: int = 1 << 16) -> np.ndarray:
        """Boolean [R]: True where the ray from origin along direction hits anything."""
        origins = np.ascontiguousarray(origins, dtype=np.float32)
        directions = np.ascontiguousarray(directions, dtype=np.float32)
        index = np.arange(len(origins))
        return self.occluded_pairs(origins, directions, index, index, chunk)

    def occluded_pairs(
        self, points: np.ndarray, dirs: np.ndarray, point_ids: np.ndarray, dir_ids: np.ndarray,
        chunk: int = 1 << 16,
    ) -> np.ndarray:
        """Occlusion of rays (points[point_ids[i]], dirs[dir_ids[i]]), gathered chunk by chunk.

        Gathering inside the worker threads keeps the ray arrays small (a chunk
        at a time) and lets numpy's copies overlap with embree's traversal.
        """
        points = np.ascontiguousarray(points, dtype=np.float32)
        dirs = np.ascontiguousarray(dirs, dtype=np.float32)
        total = len(point_ids)
        out = np.empty(total, dtype=bool)

        def run(start: int) -> None:
            stop = min(start + chunk, total)
            o = np.take(points, point_ids[start:stop], axis=0)
            d = np.take(dirs, dir_ids[start:stop], axis=0)
            out[start:stop] = self._scene.run(o, d, query="OCCLUDED") != -1

        starts = range(0, total, chunk)
        if self.threads == 1 or total <= chunk:
            for s in starts:
                run(s)
        else:
            with ThreadPoolExecutor(self.threads) as pool:
                list(pool.map(run, starts))
        return out


def _ggx_alpha(roughness: np.ndarray, floor: float) -> np.ndarray:
    return np.maximum(np.asarray(roughness, dtype=np.float32) ** 2, np.float32(floor))


def view_dependent_brdf_cos(
    normals: np.ndarray,
    views: np.ndarray,
    dirs: np.ndarray,
    roughness: np.ndarray,
    metallic: np.ndarray,
    specular: np.ndarray,
    alpha_floor: float = ALPHA_FLOOR,
) -> np.ndarray:
    """f_r(v, w) max(0, n.w) for a white surface, [V, S] float32, finite everywhere.

    normals, views: [V, 3] unit (views point from the surface to the camera);
    dirs: [S, 3] unit. A view below the shading horizon (back-facing normal
    from interpolation or a silhouette) is folded onto the horizon first.
    """
    n = np.asarray(normals, dtype=np.float32)
    v = np.asarray(views, dtype=np.float32)
    w = np.asarray(dirs, dtype=np.float32)
    # Fold back-facing views to just above the horizon: n.v >= 1e-3.
    nv_raw = np.sum(n * v, axis=1, keepdims=True)
    v = v + np.maximum(0.0, 1e-3 - nv_raw) * n
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    nv = np.clip(np.sum(n * v, axis=1, keepdims=True), 1e-3, 1.0)  # [V,1]
    nl = n @ w.T  # [V,S]
    cos = np.maximum(nl, 0.0)
    vl = v @ w.T

    alpha = _ggx_alpha(roughness, alpha_floor)[:, None]
    a2 = alpha * alpha
    metal = np.asarray(metallic, dtype=np.float32)[:, None]
    level = np.asarray(specular, dtype=np.float32)[:, None]

    def fresnel_of(cos_angle):
        # Schlick for IOR 1.5 scaled by the specular level (0 removes the lobe,
        # as Principled's "Specular IOR Level" does), white metal F = 1.
        schlick = DIELECTRIC_F0 + (1.0 - DIELECTRIC_F0) * (1.0 - cos_angle) ** 5
        return np.minimum(1.0, (1.0 - metal) * level * schlick + metal)

    # Half vector: |v + w|^2 = 2 + 2 v.w; guarded where v = -w.
    h_len = np.sqrt(np.maximum(2.0 + 2.0 * vl, 1e-12))
    nh = np.clip((nv + nl) / h_len, 0.0, 1.0)
    vh = np.clip((1.0 + vl) / h_len, 0.0, 1.0)
    d = a2 / (math.pi * np.square(nh * nh * (a2 - 1.0) + 1.0))
    # Height-correlated Smith visibility G2 / (4 n.l n.v), denominator > 0 for alpha > 0.
    lam_v = cos * np.sqrt(a2 + (1.0 - a2) * nv * nv)
    lam_l = nv * np.sqrt(a2 + (1.0 - a2) * cos * cos)
    vis = 0.5 / np.maximum(lam_v + lam_l, 1e-12)
    fresnel = fresnel_of(vh)
    spec = d * vis * fresnel * cos

    # Fujii's Oren-Nayar with sigma = roughness; sigma = 0 is Lambert.
    sigma = np.asarray(roughness, dtype=np.float32)[:, None]
    a = 1.0 / (math.pi + (math.pi / 2.0 - 2.0 / 3.0) * sigma)
    b = sigma * a
    s = vl - nl * nv
    t = np.where(s > 0.0, np.maximum(np.maximum(cos, nv), 1e-6), 1.0)
    diffuse = (a + b * s / t) * cos
    diffuse = np.maximum(diffuse, 0.0)
    # Fresnel-weighted layering, metals have no diffuse.
    fresnel_v = fresnel_of(nv)
    return (1.0 - metal) * (1.0 - fresnel_v) * diffuse + spec


def bake_transport(
    vertices: np.ndarray,
    faces: np.ndarray,
    normals: np.ndarray,
    order: int,
    directions: int = 256,
    *,
    view_point: np.ndarray | None = None,
    materials: VertexMaterials | None = None,
    rng: np.random.Generator | None = None,
    threads: int | None = None,
    offset: float | None = None,
    vertex_chunk: int = 4096,
    active: np.ndarray | None = None,
) -> BakeResult:
    """Per-vertex SH transport [V, (order+1)^2] of a white BRDF with self-shadowing.

    Diffuse (Lambert) unless `materials` and `view_point` are both given, in
    which case the view-dependent BRDF is used with the view direction toward
    `view_point`. Energy never exceeds 1: each vertex's unoccluded directional
    albedo under the same quadrature is clamped to 1.

    `active` (bool [V]) restricts the bake to the vertices that can be seen;
    the others get T = 0 (they still occlude).
    """
    t_start = time.perf_counter()
    _validate_mesh(vertices, faces, normals)
    if order < 0:
        raise ValueError(f"SH order must be >= 0, got {order}")
    if directions < 1:
        raise ValueError(f"bake directions must be >= 1, got {directions}")
    specular = materials is not None and view_point is not None
    if (materials is None) != (view_point is None):
        raise ValueError("give both materials and view_point for a view-dependent bake, or neither")
    verts = np.asarray(vertices, dtype=np.float64)
    nrm = np.asarray(normals, dtype=np.float64)
    count = len(verts)
    if specular:
        materials.validate(count)
        view_point = np.asarray(view_point, dtype=np.float64)
        if view_point.shape != (3,) or not np.all(np.isfinite(view_point)):
            raise ValueError(f"view_point must be a finite 3-vector, got {view_point}")

    dirs = fibonacci_directions(directions, rng)
    basis = sh.sh_basis(dirs, order).astype(np.float32)  # [S, n]
    d_omega = 4.0 * math.pi / directions
    # Direction spacing sqrt(4 pi / S): a GGX lobe narrower than about half of
    # it falls between samples, so alpha is floored there.
    alpha_floor = max(ALPHA_FLOOR, 0.5 * math.sqrt(d_omega)) if specular else 0.0

    extent = float(np.linalg.norm(verts.max(axis=0) - verts.min(axis=0)))
    eps = offset if offset is not None else max(1e-6, 5e-4 * extent)
    tester = OcclusionTester(verts, faces, threads)

    if active is None:
        active = np.ones(count, dtype=bool)
    active = np.asarray(active, dtype=bool)
    if active.shape != (count,):
        raise ValueError(f"active must be a bool mask of shape ({count},), got {active.shape}")
    cos_all = nrm.astype(np.float32) @ dirs.astype(np.float32).T  # [V, S]
    upper = (cos_all > 0.0) & active[:, None]
    flat = np.flatnonzero(upper)
    t_ray = time.perf_counter()
    blocked = tester.occluded_pairs(verts + eps * nrm, dirs, flat // directions, flat % directions)
    ray_seconds = time.perf_counter() - t_ray
    visible = np.zeros(count * directions, dtype=bool)
    visible[flat[~blocked]] = True
    visible = visible.reshape(count, directions)
    del blocked, flat

    # Inactive vertices keep T = 0 and cost nothing below.
    transport = np.zeros((count, basis.shape[1]), dtype=np.float32)
    baked = np.flatnonzero(active)
    for start in range(0, len(baked), vertex_chunk):
        ids = baked[start : start + vertex_chunk]
        if specular:
            views = view_point[None, :] - verts[ids]
            views /= np.maximum(np.linalg.norm(views, axis=1, keepdims=True), 1e-12)
            weight = view_dependent_brdf_cos(
                nrm[ids], views, dirs,
                materials.roughness[ids], materials.metallic[ids], materials.specular[ids],
                alpha_floor,
            )
        else:
            weight = (np.maximum(cos_all[ids], 0.0) / math.pi).astype(np.float32)
        weight *= np.float32(d_omega)
        # Directional albedo of the white BRDF under this quadrature, kept <= 1.
        albedo = weight.sum(axis=1, keepdims=True, dtype=np.float64)
        weight /= np.maximum(albedo, 1.0).astype(np.float32)
        weight *= visible[ids]
        transport[ids] = weight @ basis
    return BakeResult(
        transport=transport,
        directions=directions,
        rays=int(upper.sum()),
        ray_seconds=ray_seconds,
        seconds=time.perf_counter() - t_start,
        specular=specular,
        alpha_floor=alpha_floor,
    )
