"""The face's own 3D mesh in a photo (issue 37): MediaPipe's face landmark network (468 points with
depth, Apache-2.0, relight/models/NOTICE.md) on a square crop around the head, its points mapped
back to photo pixels, and the mesh's per-pixel camera-frame normals rasterized over the face.

The geometry network sees a full-body person at 128-180 px, where a face is about 10 px wide;
the mesh gives the face's shape at the photo's own resolution. relight.network.face_relight turns these
normals into the face's transport and relit pixels.

Pipeline (MediaPipe's face mesh, without its face detector: the first crop is the head of the
person matte, the later ones come from the landmarks themselves, as MediaPipe's tracking does):

* the crop: a square of side `side` about (cx, cy), turned by `angle` (radians; the eye line's
  angle in the image), sampled bilinearly into 192 x 192 sRGB in [0, 1] (zero outside the photo);
* the network: 468 points (u, v, z) in pixels of the crop, z the depth relative to the head's
  centre on the scale of u (MediaPipe: "the magnitude of z uses roughly the same scale as x";
  smaller is nearer), and a face probability;
* back to the photo: (x, y) = centre + side * R(angle) ((u, v) / 192 - 1/2), depth = z * side / 192
  in photo pixels (orthographic: a face is far from the camera against its own depth);
* the next crop: the points' bounding box in the eye line's frame (points 33 and 263, the outer
  eye corners), grown 1.5 x, square (MediaPipe's face_landmark_landmarks_to_roi).

Camera frame (docs/conventions.md): X right, Y away from the camera, Z up; a photo point
(x, y, depth) is (x, depth, -y) there, and a normal that faces the camera has Y < 0.
"""

from __future__ import annotations

import json
import math
import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relight.imaging.colour import srgb_encode
from relight.models import REGISTRY_PATH
from relight.imaging.resample import sample_points

MODEL_NAME = "face-landmark"              # registry entry of the landmark network
MODEL_FILE = "face_landmark.onnx"
TRIANGLES_FILE = (Path(__file__).resolve().parent.parent / "models") / "face_mesh_triangles.json"
TRIANGLES_SHA256 = "b6f3eaf37ce6a4eb509b3272cdedc9aef553bf0b048a4f969f075934f8a8e1ba"
SIDE = 192                                # the network's input, square
LANDMARKS = 468
EYES = (33, 263)                          # outer corners of the right and left eye (MediaPipe's ROI)
ROI_SCALE = 1.5                           # landmarks' box -> the next crop (MediaPipe)
HEAD_SCALE = 1.1                          # the matte's head square -> the first crop
PASSES = 3                                # crops: the head's, then twice from the landmarks
MIN_SCORE = 0.5                           # face probability below which there is no face
SUPERSAMPLE_MAX = 4                       # samples per crop pixel and axis when the face is large


@dataclass(frozen=True)
class Roi:
    cx: float       # centre, photo pixels (continuous: pixel centres at +0.5)
    cy: float
    side: float     # square's side, photo pixels
    angle: float    # radians, the crop's x axis turned from the photo's toward +y (down)


@dataclass
class FaceMesh:
    points: np.ndarray      # [468, 3] float64: x, y (photo pixels), depth (photo pixels, larger = farther)
    score: float            # the network's face probability on the last crop
    roi: Roi                # the last crop

    @property
    def width(self) -> float:
        """The face's width in photo pixels: the extent of the points across the eye line."""
        ax = self.points[EYES[1], :2] - self.points[EYES[0], :2]
        ax = ax / max(float(np.linalg.norm(ax)), 1e-9)
        across = self.points[:, :2] @ ax
        return float(across.max() - across.min())

    def camera_points(self) -> np.ndarray:
        """[468, 3] in the camera frame (X right, Y away, Z up), photo pixels as the unit."""
        x, y, d = self.points.T
        return np.stack([x, d, -y], axis=-1)


_LOCK = threading.Lock()
_SESSIONS: dict = {}
_TRIANGLES: list = []


def triangles() -> np.ndarray:
    """[852, 3] int: the mesh's triangles over the 468 landmarks (hash-checked once)."""
    with _LOCK:
        if not _TRIANGLES:
            from relight.files.fileio import file_sha256

            digest = file_sha256(TRIANGLES_FILE)
            if digest != TRIANGLES_SHA256:
                raise ValueError(f"{TRIANGLES_FILE}: SHA-256 {digest} is not the shipped {TRIANGLES_SHA256}")
            data = json.loads(TRIANGLES_FILE.read_text(encoding="utf-8"))
            tri = np.asarray(data["triangles"], np.int64)
            if tri.ndim != 2 or tri.shape[1] != 3 or tri.min() < 0 or tri.max() >= LANDMARKS:
                raise ValueError(f"{TRIANGLES_FILE}: not triangles over {LANDMARKS} landmarks")
            _TRIANGLES.append(tri)
        return _TRIANGLES[0]


def session(threads: int | None = None, registry_path=REGISTRY_PATH):
    """The landmark network's onnxruntime session (hash-checked by relight.models.session), shared."""
    from relight.models import load_registry
    from relight.models.session import open_session

    entry = load_registry(registry_path)["models"].get(MODEL_NAME)
    path = Path(registry_path).parent / (entry.get("file", MODEL_FILE) if isinstance(entry, dict) else MODEL_FILE)
    key = (str(path.resolve()), threads, str(Path(registry_path).resolve()))
    with _LOCK:
        if key not in _SESSIONS:
            sess, _ = open_session(path, threads=threads, registry_path=registry_path)
            if [i.name for i in sess.get_inputs()] != ["image"] or list(sess.get_inputs()[0].shape) != [1, 3, SIDE, SIDE] \
                    or [o.name for o in sess.get_outputs()] != ["landmarks", "face_flag"]:
                raise ValueError(f"{path}: not the face landmark network (image [1, 3, {SIDE}, {SIDE}] -> "
                                 "landmarks, face_flag)")
            _SESSIONS[key] = sess
        return _SESSIONS[key]


# ------------------------------------------------------------------ crops and landmarks


def _crop_to_photo(roi: Roi, u: np.ndarray, v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Photo coordinates of crop coordinates (u, v) in [0, SIDE] (continuous)."""
    a, b = (u / SIDE - 0.5) * roi.side, (v / SIDE - 0.5) * roi.side
    c, s = math.cos(roi.angle), math.sin(roi.angle)
    return roi.cx + a * c - b * s, roi.cy + a * s + b * c


def crop(srgb: np.ndarray, roi: Roi) -> np.ndarray:
    """The network's input [SIDE, SIDE, 3] for an sRGB photo [H, W, 3] in [0, 1]: bilinear samples
    (averaged over up to SUPERSAMPLE_MAX^2 per pixel when the square is larger than the input)."""
    k = int(min(SUPERSAMPLE_MAX, max(1, math.ceil(roi.side / SIDE))))
    offsets = (np.arange(k) + 0.5) / k
    grid = (np.arange(SIDE)[:, None] + offsets[None, :]).reshape(-1)        # [SIDE * k]
    u, v = np.meshgrid(grid, grid)
    x, y = _crop_to_photo(roi, u, v)
    out = sample_points(srgb, x, y)                                          # [SIDE k, SIDE k, 3]
    return out.reshape(SIDE, k, SIDE, k, 3).mean(axis=(1, 3)).astype(np.float32)


def landmarks(srgb: np.ndarray, roi: Roi, sess) -> tuple[np.ndarray, float]:
    """([468, 3] photo x, y, depth; face probability) of the crop `roi` of an sRGB photo."""
    x = crop(srgb, roi).transpose(2, 0, 1)[None]
    pts, flag = sess.run(["landmarks", "face_flag"], {"image": np.ascontiguousarray(x)})
    pts = pts.reshape(LANDMARKS, 3).astype(np.float64)
    px, py = _crop_to_photo(roi, pts[:, 0], pts[:, 1])
    return np.stack([px, py, pts[:, 2] * roi.side / SIDE], axis=-1), float(np.ravel(flag)[0])


def roi_from_points(points: np.ndarray) -> Roi:
    """The next crop from landmarks (MediaPipe's rule): turned to the eye line, the points' box
    in that frame grown ROI_SCALE x and made square."""
    d = points[EYES[1], :2] - points[EYES[0], :2]
    angle = math.atan2(d[1], d[0])
    c, s = math.cos(angle), math.sin(angle)
    a = points[:, 0] * c + points[:, 1] * s             # along the eye line
    b = -points[:, 0] * s + points[:, 1] * c            # across it
    ma, mb = 0.5 * (a.min() + a.max()), 0.5 * (b.min() + b.max())
    side = ROI_SCALE * max(a.max() - a.min(), b.max() - b.min())
    return Roi(ma * c - mb * s, ma * s + mb * c, float(side), angle)


def head_roi(matte: np.ndarray, threshold: float = 0.5) -> Roi | None:
    """A first crop from a person matte [H, W]: the head is the matte from its top row down to the
    neck, the row of the matte's top half narrowest against the widest row above it (the head
    narrows into the neck, the shoulders widen past it); a square HEAD_SCALE x the head's larger
    side about its centre. For upright people; None for an empty matte."""
    m = np.asarray(matte)
    m = (m[..., 0] if m.ndim == 3 else m) > threshold
    rows = np.flatnonzero(m.any(axis=1))
    if rows.size == 0:
        return None
    top, bottom = int(rows[0]), int(rows[-1]) + 1
    widths = m.sum(axis=1).astype(np.float64)
    k = max(1, (bottom - top) // 40)
    smooth = np.convolve(widths, np.ones(2 * k + 1) / (2 * k + 1), mode="same")
    start, stop = top + max(3, (bottom - top) // 20), top + (bottom - top) // 2
    if stop > start:
        ratio = smooth[start:stop] / np.maximum(np.maximum.accumulate(smooth[top:stop])[start - top:], 1e-9)
        neck = start + int(np.argmin(ratio))
    else:
        neck = bottom
    cols = np.flatnonzero(m[top:neck].any(axis=0))
    side = HEAD_SCALE * max(neck - top, cols[-1] + 1 - cols[0])
    return Roi(0.5 * (cols[0] + cols[-1] + 1), 0.5 * (top + neck), float(side), 0.0)


def find_face(photo: np.ndarray, matte: np.ndarray | None = None, roi: Roi | None = None, *,
              threads: int | None = None, registry_path=REGISTRY_PATH) -> FaceMesh | None:
    """The face mesh of the person in a linear photo [H, W, 3]: from `roi`, else the head of
    `matte` [H, W] (relight.person.matte's person matte); None when the network sees no face."""
    if roi is None:
        if matte is None:
            raise ValueError("find_face needs a person matte or a first crop (roi)")
        roi = head_roi(matte)
        if roi is None:
            return None
    # sRGB of the part of the photo the crops can reach (the first crop's square, twice as large)
    H, W = photo.shape[:2]
    reach = roi.side * 1.5
    y0, y1 = max(int(roi.cy - reach), 0), min(int(roi.cy + reach) + 1, H)
    x0, x1 = max(int(roi.cx - reach), 0), min(int(roi.cx + reach) + 1, W)
    if y1 <= y0 or x1 <= x0:
        return None
    srgb = srgb_encode(np.clip(photo[y0:y1, x0:x1], 0.0, 1.0)).astype(np.float32)
    roi = Roi(roi.cx - x0, roi.cy - y0, roi.side, roi.angle)
    sess = session(threads, registry_path)
    best = None
    for _ in range(PASSES):
        points, score = landmarks(srgb, roi, sess)
        if score < MIN_SCORE:
            break
        best = FaceMesh(points, score, roi)
        roi = roi_from_points(points)
    if best is None:
        return None
    shift = np.array([x0, y0, 0.0])                  # back to the whole photo's pixels
    return FaceMesh(best.points + shift, best.score, Roi(best.roi.cx + x0, best.roi.cy + y0, best.roi.side,
                                                         best.roi.angle))


# ------------------------------------------------------------------ normals over the face


def vertex_normals(points_cam: np.ndarray, tri: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(per-vertex unit normals [468, 3], per-triangle normals [T, 3], not normalised: twice the
    area): area-weighted, the mesh's winding turned so that most of its area faces the camera."""
    a, b, c = (points_cam[tri[:, i]] for i in range(3))
    face = np.cross(b - a, c - a)
    if face[:, 1].sum() > 0:                  # facing the camera is Y < 0
        face = -face
    vn = np.zeros_like(points_cam)
    for i in range(3):
        np.add.at(vn, tri[:, i], face)
    vn /= np.maximum(np.linalg.norm(vn, axis=1, keepdims=True), 1e-12)
    return vn, face


def rasterize(mesh: FaceMesh, box: tuple[int, int, int, int], shape: tuple[int, int]):
    """(normals [h, w, 3] camera frame, coverage [h, w] bool) of the mesh on a grid of `shape`
    covering the photo box (y0, y1, x0, x1): per pixel the nearest front-facing triangle's
    vertex normals interpolated barycentrically (at the pixel centre) and normalised."""
    y0, y1, x0, x1 = box
    h, w = shape
    sy, sx = h / (y1 - y0), w / (x1 - x0)
    tri = triangles()
    pc = mesh.camera_points()
    vn, face = vertex_normals(pc, tri)
    gx = (mesh.points[:, 0] - x0) * sx                 # grid coordinates (pixel centres at +0.5)
    gy = (mesh.points[:, 1] - y0) * sy
    depth = mesh.points[:, 2]
    normals = np.zeros((h, w, 3), np.float64)
    zbuf = np.full((h, w), np.inf)
    for t in np.flatnonzero(face[:, 1] < 0):          # front-facing triangles only
        i, j, k = tri[t]
        xs, ys = gx[[i, j, k]], gy[[i, j, k]]
        c0, c1 = max(int(math.floor(xs.min() - 0.5)), 0), min(int(math.ceil(xs.max() - 0.5)) + 1, w)
        r0, r1 = max(int(math.floor(ys.min() - 0.5)), 0), min(int(math.ceil(ys.max() - 0.5)) + 1, h)
        if c0 >= c1 or r0 >= r1:
            continue
        px, py = np.arange(c0, c1)[None, :] + 0.5, np.arange(r0, r1)[:, None] + 0.5   # broadcast, no grid
        det = (ys[1] - ys[2]) * (xs[0] - xs[2]) + (xs[2] - xs[1]) * (ys[0] - ys[2])
        if abs(det) < 1e-12:
            continue
        l0 = ((ys[1] - ys[2]) * (px - xs[2]) + (xs[2] - xs[1]) * (py - ys[2])) / det
        l1 = ((ys[2] - ys[0]) * (px - xs[2]) + (xs[0] - xs[2]) * (py - ys[2])) / det
        l2 = 1.0 - l0 - l1
        eps = -1e-9
        inside = (l0 >= eps) & (l1 >= eps) & (l2 >= eps)
        if not inside.any():
            continue
        zb = zbuf[r0:r1, c0:c1]
        z = l0 * depth[i] + l1 * depth[j] + l2 * depth[k]
        win = inside & (z < zb)
        zb[win] = z[win]
        normals[r0:r1, c0:c1][win] = l0[win][:, None] * vn[i] + l1[win][:, None] * vn[j] + l2[win][:, None] * vn[k]
    covered = np.isfinite(zbuf)
    normals /= np.maximum(np.linalg.norm(normals, axis=-1, keepdims=True), 1e-12)
    normals[~covered] = 0.0
    return normals.astype(np.float32), covered
