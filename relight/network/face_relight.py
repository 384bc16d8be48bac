"""The face relit from its own mesh (issue 37): the face mesh's normals (relight.network.face_mesh) stand in
for the network's inside the face, feathered at the mesh's edge, on a grid of the face at up to
GRID_MAX px (the network sees a full-body face at about 10 px).

The transport follows from the normals by the network's own physics (model.networks.physics.lobe_transport):
T_lm(x) = v(x) A_l / pi Y_lm(n(x)), with v the network's ambient visibility there (its T_00 against
an unoccluded point's, clamped to [0, 1]). The albedo follows by the network's photo-consistent
rule (relight.network.prt.photo_consistent_albedo): photo / max(T . L, floor), at most 1, with the
decomposition's light L and its floor (RELIABLE x the person's mean shading). Relit under L':
albedo x (T . L'), written per full-resolution pixel as min(photo, c) x g with c = max(T . L,
floor) and g = (T . L') / c on the grid, upsampled bilinearly (the photo's own texture kept, as
Decomposition.relight's quotient keeps it).

The eyes and the mouth are holes of MediaPipe's mesh: filled by normalised box means of the
normals around them. The layer's weight is the mesh's coverage eroded and ramped over FEATHER of
the face's width, times the person matte.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from relight.network import face_mesh
from relight.lighting import sh
from relight.person.mask_ops import box_mean, label
from relight.network.refine import MIN_MEAN, RELIABLE, SATURATED
from relight.imaging.resample import Bilinear, resize_linear, sample_points

RIDGE = 0.1             # the network's (its network_config's ridge)
GRID_MAX = 160          # px: the longest side of the face grid
MIN_FACE_PX = 40        # px: faces narrower than this in the photo are left to the network
SMOOTH = 0.03          # of the face's width: the box radius the mesh's normals are averaged over
FEATHER = 0.08          # of the face's width: the ramp from the network's normals to the mesh's
MARGIN = 0.05           # of the face's width: the grid's box around the landmarks
UNOCCLUDED_DC = 1.0 / (2.0 * np.sqrt(np.pi))   # T_00 of an unoccluded white Lambertian point


def lobe_transport(normals: np.ndarray, visibility: np.ndarray, order: int) -> np.ndarray:
    """[..., n]: v A_l / pi Y_lm(n) (model.networks.physics.lobe_transport's numpy twin)."""
    scale = np.repeat(sh.clamped_cosine_coeffs(order) / np.pi, 2 * np.arange(order + 1) + 1)
    return (sh.sh_basis(normals.astype(np.float64), order) * scale * visibility[..., None]).astype(np.float32)


def fill_holes(normals: np.ndarray, covered: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The mesh's holes (uncovered parts not touching the grid's border: eyes, mouth) filled with
    normalised box means of the covered normals, widening until each is reached."""
    labels, _ = label(~covered)
    edge = set(np.unique(np.concatenate([labels[0], labels[-1], labels[:, 0], labels[:, -1]])).tolist())
    holes = (labels > 0) & ~np.isin(labels, list(edge))
    if not holes.any():
        return normals, covered
    out = normals.copy()
    known = covered.astype(np.float32)
    todo = holes.copy()
    r = 1
    while todo.any() and r < max(normals.shape[:2]):
        weight = box_mean(known, r)
        ok = todo & (weight > 1e-3)
        for c in range(3):
            mean = box_mean(out[..., c] * known, r)
            out[..., c][ok] = mean[ok] / weight[ok]
        todo &= ~ok
        r *= 2
    out /= np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-12)
    return out, covered | holes


def smooth(normals: np.ndarray, covered: np.ndarray, radius: float) -> np.ndarray:
    """The normals [h, w, 3] averaged over (2r+1)^2 boxes of the covered pixels and normalised:
    the mesh's 468 points leave facets and landmark jitter that the relit face would show."""
    r = int(round(radius))
    if r < 1:
        return normals
    known = covered.astype(np.float32)
    weight = np.maximum(box_mean(known, r), 1e-6)
    out = np.stack([box_mean(normals[..., c] * known, r) / weight for c in range(3)], axis=-1)
    out /= np.maximum(np.linalg.norm(out, axis=-1, keepdims=True), 1e-12)
    return np.where(covered[..., None], out, normals).astype(np.float32)


def feather(covered: np.ndarray, width_px: float) -> np.ndarray:
    """Weight [h, w] in [0, 1]: 0 outside the coverage, ramping to 1 about width_px inside it
    (a box mean of the coverage, remapped so that its edge value 1/2 is 0 and 1 stays 1)."""
    r = max(1, int(round(width_px / 2)))
    m = box_mean(covered.astype(np.float32), r)
    return np.clip(2.0 * m - 1.0, 0.0, 1.0) * covered


@dataclass
class FaceLayer:
    """The face's mesh geometry on a grid over the photo box (y0, y1, x0, x1)."""

    box: tuple[int, int, int, int]
    normals: np.ndarray      # [h, w, 3] camera frame, holes filled
    weight: np.ndarray       # [h, w] in [0, 1]: how much of the relit face is the mesh's
    transport: np.ndarray    # [h, w, n]: v A_l / pi Y_lm(n)
    floor: float             # the network's shading floor (RELIABLE x the person's mean shading)
    mesh: face_mesh.FaceMesh
    light: np.ndarray        # [n, 3]: the photo's light refitted to the face with the mesh's transport

    def shading(self, light: np.ndarray) -> np.ndarray:
        """[h, w, 3]: T . L on the grid."""
        n = min(light.shape[0], self.transport.shape[-1])
        return self.transport[..., :n] @ light[:n].astype(np.float32)

    def relit_box(self, photo_box: np.ndarray, light: np.ndarray, target: np.ndarray) -> np.ndarray:
        """The face box of the photo [H', W', 3] relit from light (the photo's) to target, with
        the photo's albedo rule: min(photo, c) x (T . L') / c, c = max(T . L, floor)."""
        c = np.maximum(self.shading(light), np.float32(self.floor))
        g = self.shading(target) / c
        up = Bilinear(photo_box.shape[0], photo_box.shape[1], *self.weight.shape)
        c_full, g_full = _up(up, c), _up(up, g)
        return np.minimum(np.clip(photo_box, 0.0, 1.0), c_full) * g_full

    def apply(self, photo: np.ndarray, light: np.ndarray, target: np.ndarray, out: np.ndarray,
              scale: float = 1.0) -> np.ndarray:
        """`out` [H, W, 3] (the relit photo) with the face box blended toward the mesh's relit face
        (times `scale`, the exposure) by the layer's weight; returned."""
        y0, y1, x0, x1 = self.box
        relit = self.relit_box(photo[y0:y1, x0:x1], light, target) * np.float32(scale)
        up = Bilinear(y1 - y0, x1 - x0, *self.weight.shape)
        w = _up(up, self.weight[..., None])
        region = out[y0:y1, x0:x1]
        region += (relit - region) * w
        return out


def _up(up: Bilinear, small: np.ndarray) -> np.ndarray:
    """A grid map [h, w, C] upsampled to the box's size."""
    prepared = up.prepare(np.ascontiguousarray(small, dtype=np.float32))
    return up.strip(prepared, 0, len(up.rows[0]))


def fit_light(transport: np.ndarray, albedo: np.ndarray, photo: np.ndarray, weight: np.ndarray,
              prior: np.ndarray, ridge: float = RIDGE) -> np.ndarray:
    """The light [n, 3] that best explains `photo` [h, w, 3] as albedo x (T . L) over the face,
    per channel, pulled toward `prior` (the network's light) by a ridge relative to the data's
    own scale (model.networks.physics.fit_light's rule: lam = ridge x mean diagonal of the normal matrix;
    what the face's normals cannot see stays at the prior)."""
    w = weight.reshape(-1).astype(np.float64)
    t = transport.reshape(-1, transport.shape[-1]).astype(np.float64)
    n = t.shape[1]
    out = np.empty((n, 3))
    for c in range(3):
        design = t * albedo.reshape(-1, 3)[:, c:c + 1]
        normal = (design * w[:, None]).T @ design
        rhs = (design * w[:, None]).T @ photo.reshape(-1, 3)[:, c]
        lam = ridge * np.trace(normal) / n + 1e-20
        out[:, c] = np.linalg.solve(normal + lam * np.eye(n), rhs + lam * prior[:n, c])
    return out.astype(np.float32)


def photo_floor(d) -> float:
    """The network's shading floor for decomposition `d`: RELIABLE x the weighted mean of the
    shading's luminance over the person (relight.network.refine.consistent_albedo's weights)."""
    photo = np.clip(d.photo_working, 0.0, 1.0)
    alpha = d.network_alpha if d.network_alpha is not None else d.alpha
    weight = alpha * (photo.max(axis=-1) < SATURATED)
    lum = (d.transport @ d.light).mean(axis=-1)
    mean = float((lum * weight).sum() / (weight.sum() + 1e-4))
    return RELIABLE * max(mean, MIN_MEAN)


def on_grid(d, working_map: np.ndarray, box: tuple[int, int, int, int], shape: tuple[int, int]) -> np.ndarray:
    """A map of d's working resolution ([h, w] or [h, w, C]) sampled bilinearly on the face grid."""
    y0, y1, x0, x1 = box
    h, w = shape
    by0, by1, bx0, bx1 = d.box
    wh, ww = d.working_size
    gx = x0 + (np.arange(w) + 0.5) * (x1 - x0) / w                      # photo coordinates
    gy = y0 + (np.arange(h) + 0.5) * (y1 - y0) / h
    u = (gx - bx0) * ww / (bx1 - bx0)                                    # working coordinates
    v = (gy - by0) * wh / (by1 - by0)
    uu, vv = np.meshgrid(u, v)
    return sample_points(np.ascontiguousarray(working_map, dtype=np.float32), uu, vv)


def face_layer(d, *, threads: int | None = None, min_face_px: float = MIN_FACE_PX,
               visibility: str = "network", refit: bool = True) -> FaceLayer | None:
    """The face layer of decomposition `d` (relight.network.runtime's): None when there is no face mesh
    (the network sees no face in the head's crop) or the face is narrower than `min_face_px`.
    `visibility`: "network" (its ambient occlusion) or "none" (unoccluded)."""
    H, W = d.photo.shape[:2]
    matte = d.person_matte.alpha if d.person_matte is not None else (
        d.mask if d.mask is not None else d.full_alpha())
    mesh = face_mesh.find_face(d.photo, matte, threads=threads)
    if mesh is None or mesh.width < min_face_px:
        return None
    pts = mesh.points
    pad = MARGIN * mesh.width
    y0, y1 = max(int(np.floor(pts[:, 1].min() - pad)), 0), min(int(np.ceil(pts[:, 1].max() + pad)), H)
    x0, x1 = max(int(np.floor(pts[:, 0].min() - pad)), 0), min(int(np.ceil(pts[:, 0].max() + pad)), W)
    if y1 - y0 < 4 or x1 - x0 < 4:
        return None
    s = min(1.0, GRID_MAX / max(y1 - y0, x1 - x0))
    shape = (max(4, round((y1 - y0) * s)), max(4, round((x1 - x0) * s)))
    normals, covered = face_mesh.rasterize(mesh, (y0, y1, x0, x1), shape)
    normals, covered = fill_holes(normals, covered)
    normals = smooth(normals, covered, SMOOTH * mesh.width * shape[1] / (x1 - x0))
    return layer_from_normals(d, mesh, (y0, y1, x0, x1), normals, covered, matte, visibility, refit)


def layer_from_normals(d, mesh, box, normals: np.ndarray, covered: np.ndarray, matte: np.ndarray,
                       visibility: str = "network", refit: bool = True) -> FaceLayer:
    """The face layer of `d` with these normals [h, w, 3] (camera frame) covering `covered` on the
    grid of the photo box (y0, y1, x0, x1): the mesh's, or for a ceiling the truth's. `refit`:
    the photo's light refitted to the face (False: the network's light as it is)."""
    y0, y1, x0, x1 = box
    shape = covered.shape
    normals = normals.copy()
    normals[~covered] = (0.0, -1.0, 0.0)   # weight 0 there: any unit normal (facing the camera)
    grid_per_px = shape[1] / (x1 - x0)
    weight = feather(covered, FEATHER * mesh.width * grid_per_px)
    matte = np.asarray(matte, np.float32)
    matte_grid = sample_points(np.ascontiguousarray(matte[..., 0] if matte.ndim == 3 else matte),
                               *np.meshgrid(x0 + (np.arange(shape[1]) + 0.5) / grid_per_px,
                                            y0 + (np.arange(shape[0]) + 0.5) * (y1 - y0) / shape[0]))
    weight = (weight * np.clip(matte_grid, 0.0, 1.0)).astype(np.float32)
    v = np.clip(on_grid(d, d.transport[..., 0], box, shape) / UNOCCLUDED_DC, 0.0, 1.0) \
        if visibility == "network" else np.ones(shape)
    transport = lobe_transport(normals, v, d.sh_order)
    # the photo's light seen by the face: refitted to the face's pixels with the mesh's transport
    # and the network's albedo there (the network fitted it to the body with its own normals)
    photo_grid = resize_linear(np.ascontiguousarray(d.photo[y0:y1, x0:x1]), *shape)
    albedo_grid = np.clip(on_grid(d, d.albedo, box, shape), 1e-3, 1.0)
    fit_weight = (weight > 0.5) * (photo_grid.max(axis=-1) < SATURATED)
    light = fit_light(transport, albedo_grid, photo_grid, fit_weight, d.light) if refit and fit_weight.sum() > 50 else d.light
    return FaceLayer(box, normals, weight, transport, photo_floor(d), mesh,
                     np.asarray(light, np.float32))
