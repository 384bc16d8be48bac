"""Loose clothing: shells that stand off the body, closed slabs with thickness, folds.

Every mesh here is built so that the transport bake and
`farm.scene.visible_vertices` stay right without special cases:

* a garment with an opening you can look into (an open jacket front, a
  skirt's hem, a hood) is a closed *slab*: the outer surface, an inner surface
  `thickness` below it with reversed faces, and a rim joining their
  boundaries; every directed edge then has exactly one twin and every face
  normal points out of the cloth, so "facing the camera" means "can be seen";
* loose shells are offset along a smoothed normal field (so they bridge
  small concavities instead of hugging them) and carry folds: a ridge
  displacement along the normal in rest (pattern) space, rings around the
  limbs and vertical drape on the torso and skirts, deep enough (5-20 mm)
  for the grooves to shadow themselves in the bake;
* parametric pieces (skirt tubes, hoods) are built in the rest frame and
  moved with the body by a rigid fit of a nearby body region (Kabsch), so
  the rest coordinates stay the pattern space like everywhere else.

Everything is numpy and deterministic given the numpy Generator.
"""

from __future__ import annotations

import math

import numpy as np

from farm.synthesis.meshops import smooth_noise, submesh, vertex_normals

# ------------------------------------------------------------------ mesh tools


def directed_edges(faces: np.ndarray) -> np.ndarray:
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def boundary_edges(faces: np.ndarray) -> np.ndarray:
    """Directed edges (a, b) of the faces whose twin (b, a) is absent: the open boundary."""
    e = directed_edges(np.asarray(faces, dtype=np.int64))
    n = int(e.max()) + 1 if len(e) else 1
    key = e[:, 0] * n + e[:, 1]
    twin = e[:, 1] * n + e[:, 0]
    return e[~np.isin(key, twin)]


def is_closed(faces: np.ndarray) -> bool:
    """Every directed edge appears once and its twin once: a closed, consistently oriented surface."""
    e = directed_edges(np.asarray(faces, dtype=np.int64))
    n = int(e.max()) + 1
    key = e[:, 0] * n + e[:, 1]
    twin = e[:, 1] * n + e[:, 0]
    return len(np.unique(key)) == len(key) and bool(np.isin(twin, key).all())


def signed_volume(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Enclosed volume (positive when the faces point outward)."""
    v = vertices[faces]
    return float(np.einsum("ij,ij->i", v[:, 0], np.cross(v[:, 1], v[:, 2])).sum() / 6.0)


def slab(outer: np.ndarray, inner: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Faces of the closed slab between two layers of the same topology.

    Vertices are [outer; inner]; the inner layer's faces are reversed and each
    boundary edge a->b of the outer layer gets the rim quad (b, a, a', b').
    """
    n = len(outer)
    if inner.shape != outer.shape:
        raise ValueError("slab layers must have the same shape")
    rim = boundary_edges(faces)
    a, b = rim[:, 0], rim[:, 1]
    rim_faces = np.concatenate([np.stack([b, a, a + n], 1), np.stack([b, a + n, b + n], 1)])
    return np.concatenate([faces, faces[:, ::-1] + n, rim_faces]).astype(np.int64)


def smooth_field(values: np.ndarray, faces: np.ndarray, iterations: int) -> np.ndarray:
    """`iterations` rounds of v <- (v + mean of the edge neighbours) / 2 (numpy only)."""
    e = directed_edges(np.asarray(faces, dtype=np.int64))
    e = np.concatenate([e, e[:, ::-1]])
    deg = np.bincount(e[:, 0], minlength=len(values)).astype(np.float64)
    out = np.asarray(values, dtype=np.float64)
    for _ in range(iterations):
        acc = np.zeros_like(out)
        np.add.at(acc, e[:, 0], out[e[:, 1]])
        out = 0.5 * out + 0.5 * acc / np.maximum(deg, 1.0)[:, None]
    return out


def unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=-1, keepdims=True), 1e-12)


def erode(mask: np.ndarray, faces: np.ndarray, rings: int) -> np.ndarray:
    """Vertices of `mask` at least `rings` edges away from any vertex outside it."""
    out = mask.copy()
    e = directed_edges(faces)
    e = np.concatenate([e, e[:, ::-1]])
    for _ in range(rings):
        outside = ~out
        touch = np.zeros_like(out)
        touch[e[:, 0][outside[e[:, 1]]]] = True
        out &= ~touch
    return out


def rigid_fit(src: np.ndarray, dst: np.ndarray):
    """(R, t) minimising |R src + t - dst| (Kabsch, no reflection)."""
    cs, cd = src.mean(axis=0), dst.mean(axis=0)
    u, _, vt = np.linalg.svd((src - cs).T @ (dst - cd))
    d = np.sign(np.linalg.det(vt.T @ u.T))
    r = vt.T @ np.diag([1.0, 1.0, d]) @ u.T
    return r, cd - r @ cs


def blend_rigid(points: np.ndarray, fits: list, weights: np.ndarray) -> np.ndarray:
    """Linear blend of rigid transforms: weights [P, len(fits)] summing to 1."""
    out = np.zeros_like(points)
    for k, (r, t) in enumerate(fits):
        out += weights[:, k : k + 1] * (points @ r.T + t)
    return out


def smoothstep(e0: float, e1: float, x):
    t = np.clip((np.asarray(x) - e0) / (e1 - e0), 0.0, 1.0)
    return t * t * (3 - 2 * t)


# ------------------------------------------------------------------ folds


def limb_axes(body, dominant: np.ndarray) -> np.ndarray:
    """[V, 3] unit rest-pose axis of each vertex's dominant bone (principal axis of its vertices)."""
    rest = body.rest_vertices
    axes = np.zeros_like(rest)
    for b in np.unique(dominant):
        sel = dominant == b
        pts = rest[sel] - rest[sel].mean(axis=0)
        if len(pts) < 4:
            axes[sel] = (0.0, 0.0, 1.0)
            continue
        _, _, vt = np.linalg.svd(pts, full_matrices=False)
        axis = vt[0] * np.sign(vt[0][2] if abs(vt[0][2]) > 1e-6 else 1.0)
        axes[sel] = axis
    return axes


def sample_folds(rng: np.random.Generator, depth: tuple[float, float], wavelength: tuple[float, float]) -> dict:
    return {
        "depth_m": float(rng.uniform(*depth)),
        "wavelength_m": float(rng.uniform(*wavelength)),
        "sharpness": float(rng.uniform(2.0, 4.0)),
        "warp": float(rng.uniform(0.5, 2.0)),
        "phase": float(rng.uniform(0.0, 2 * math.pi)),
        "noise_seed": int(rng.integers(2**31)),
    }


def fold_field(rest: np.ndarray, axes: np.ndarray, folds: dict) -> np.ndarray:
    """Ridge displacement in [0, depth]: narrow crests, broad troughs, across `axes`.

    The phase runs along each vertex's axis (rest position . axis), warped by
    a smooth noise so the folds meander; the amplitude varies smoothly too.
    """

    noise_rng = np.random.default_rng(folds["noise_seed"])
    warp = smooth_noise(rest, noise_rng, octaves=2, base_freq=8.0)
    amp = 0.6 + 0.4 * smooth_noise(rest, noise_rng, octaves=2, base_freq=6.0)
    phase = 2 * math.pi * np.einsum("ij,ij->i", rest, axes) / folds["wavelength_m"] + folds["warp"] * warp * math.pi
    ridge = (0.5 + 0.5 * np.cos(phase + folds["phase"])) ** folds["sharpness"]
    return folds["depth_m"] * amp * ridge


# ------------------------------------------------------------------ shells


def loose_shell(body, body_normals: np.ndarray, mask: np.ndarray, offset, folds: dict | None,
                fold_axes: np.ndarray | None, smoothing: int = 6):
    """Shell over the selected body vertices, standing `offset` off along a smoothed normal field.

    Returns (vertices, rest, faces, normals, body ids); folds displace outward.
    """

    faces, ids = submesh(body.faces, mask)
    if len(faces) == 0:
        raise ValueError("garment region selects no faces")
    n = unit(smooth_field(body_normals[ids], faces, smoothing))
    t = np.broadcast_to(np.asarray(offset, dtype=np.float64), (len(body.vertices),))[ids].copy()
    if folds is not None:
        t = t + fold_field(body.rest_vertices[ids], fold_axes[ids], folds)
    verts = body.vertices[ids] + t[:, None] * n
    return verts, body.rest_vertices[ids], faces, vertex_normals(verts, faces), ids


def thick(verts: np.ndarray, rest: np.ndarray, faces: np.ndarray, thickness: float):
    """Closed slab of a shell: (vertices, rest, faces, normals), the inner layer `thickness` under it."""
    n = vertex_normals(verts, faces)
    all_v = np.concatenate([verts, verts - thickness * n])
    all_f = slab(verts, verts - thickness * n, faces)
    return all_v, np.concatenate([rest, rest]), all_f, vertex_normals(all_v, all_f)


def flared_tube(body, h: np.ndarray, region: np.ndarray, top: float, hem: float, flare: float,
                folds: dict | None, gap_deg: float = 0.0, segments: int = 48, rings: int = 9):
    """A skirt-like surface from rest height `top` down to `hem` around the region's vertices.

    Each ring is centred on the posed vertices at that rest height and
    encloses all of them (+12 mm), widening by `flare` per metre of drop; folds
    modulate the radius with vertical flutes. `gap_deg` > 0 leaves the front
    open (a coat). Returns the open surface (vertices, rest, faces), normals out.
    """
    levels = np.linspace(top, hem, rings)
    closed = gap_deg <= 0.0
    if closed:
        angle = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    else:
        half = math.radians(gap_deg) / 2
        # the body faces -Y: angle -pi/2 is the front; leave [-pi/2 - half, -pi/2 + half] open
        angle = np.linspace(-math.pi / 2 + half, 1.5 * math.pi - half, segments)
    circle = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    flutes = np.zeros((rings, segments))
    if folds is not None:
        k = max(3, int(round(2 * math.pi * 0.16 / folds["wavelength_m"])))
        frng = np.random.default_rng(folds["noise_seed"])
        wobble = frng.uniform(0, 2 * math.pi, 3)
        theta = angle[None, :] + 0.25 * np.sin(2 * angle[None, :] + wobble[0])
        grow = np.linspace(0.3, 1.0, rings)[:, None]  # flutes open up toward the hem
        flutes = folds["depth_m"] * grow * (0.5 + 0.5 * np.cos(k * theta + folds["phase"])) ** folds["sharpness"]
    verts, rest = [], []
    z_top = None
    for r_i, level in enumerate(levels):
        for tol in (0.012, 0.025, 0.05):
            near = region & (np.abs(h - level) < tol)
            if near.sum() >= 8:
                break
        else:
            raise ValueError("tube ring found no body vertices at its height")
        pts = body.vertices[near]
        centre = pts[:, :2].mean(axis=0)
        z = float(pts[:, 2].mean())
        z_top = z if z_top is None else z_top
        radius = np.linalg.norm(pts[:, :2] - centre, axis=1).max() + 0.012 + flare * (z_top - z) + flutes[r_i]
        verts.append(np.concatenate([centre + radius[:, None] * circle, np.full((segments, 1), z)], axis=1))
        rc = body.rest_vertices[near].mean(axis=0)
        rest.append(np.concatenate([rc[:2] + radius[:, None] * circle, np.full((segments, 1), rc[2])], axis=1))
    verts, rest = np.concatenate(verts), np.concatenate(rest)
    faces = []
    span = segments if closed else segments - 1
    for r in range(rings - 1):
        for i in range(span):
            a, b = r * segments + i, r * segments + (i + 1) % segments
            faces += [[a, b + segments, b], [a, a + segments, b + segments]]
    faces = np.array(faces, dtype=np.int64)
    # Orient outward: the first face's normal must point away from its ring centre.
    n0 = np.cross(verts[faces[0, 1]] - verts[faces[0, 0]], verts[faces[0, 2]] - verts[faces[0, 0]])
    if np.dot(n0[:2], verts[faces[0, 0], :2] - verts[:segments, :2].mean(axis=0)) < 0:
        faces = faces[:, ::-1]
    return verts, rest, faces


def tube(path: np.ndarray, radii: np.ndarray, segments: int = 12, squash: float = 1.0):
    """Closed tube along a polyline (capped ends): (vertices, faces), faces pointing out."""
    path = np.asarray(path, dtype=np.float64)
    tang = np.gradient(path, axis=0)
    tang = unit(tang)
    ref = np.array([1.0, 0.0, 0.0]) if abs(tang[0][0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    ang = np.linspace(0, 2 * math.pi, segments, endpoint=False)
    verts = []
    for p, t, r in zip(path, tang, radii):
        u = unit(np.cross(t, ref))
        w = np.cross(t, u)
        verts.append(p + r * (np.cos(ang)[:, None] * u + squash * np.sin(ang)[:, None] * w))
    verts = np.concatenate(verts + [path[:1], path[-1:]])
    n_rings = len(path)
    faces = []
    for k in range(n_rings - 1):
        for i in range(segments):
            a, b = k * segments + i, k * segments + (i + 1) % segments
            faces += [[a, b, b + segments], [a, b + segments, a + segments]]
    s0, s1 = len(verts) - 2, len(verts) - 1
    last = (n_rings - 1) * segments
    for i in range(segments):
        faces += [[s0, (i + 1) % segments, i], [s1, last + i, last + (i + 1) % segments]]
    faces = np.array(faces, dtype=np.int64)
    if signed_volume(verts, faces) < 0:
        faces = faces[:, ::-1]
    return verts, faces


def ellipsoid(centre, radii, rows: int = 8, segments: int = 14):
    """Closed UV ellipsoid (vertices, faces), faces out."""
    path = np.array([[0.0, 0.0, z] for z in np.linspace(-1, 1, rows + 2)[1:-1]])
    r = np.sqrt(np.maximum(1.0 - path[:, 2] ** 2, 0.0))
    path[:, 2] *= 1.0
    v, f = tube(path, r, segments)
    v[-2] = (0, 0, -1)
    v[-1] = (0, 0, 1)
    return np.asarray(centre) + v * np.asarray(radii), f
