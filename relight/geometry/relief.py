"""The person's relief: normals read off the transport, and a depth map integrated from them.

Both in the photo camera's frame of docs/conventions.md (X right, Y away from the camera, Z up;
a surface facing the camera has a normal with Y < 0). The depth is orthographic and in pixels of
the grid it is computed on: a surface point of pixel (row r, column c) with depth d sits at
(c, d, -r). Its normal is then proportional to (d_c, -1, -d_r) (d_c, d_r the depth's slopes along
the columns and down the rows), so the slopes of the surface with normal n are

    d_c = -n_x / n_y        d_r = n_z / n_y

and the depth is the least-squares surface with those slopes over the matte (a Poisson problem
with free boundary, solved matrix-free by conjugate gradients: numpy only). It is a relief, not a
measurement: depth jumps at silhouettes inside the person (an arm in front of the chest) are
smoothed over, as the normals cannot tell them.

A network's depth (the depth head, issue 45) keeps those jumps but has no scale: one photo gives
depth only up to scale and shift. `scaled_to_normals` gives it the normals' scale: the median, over
neighbouring pixels, of the slope the normals give (their mean) over the depth's difference, where
the normals slope at least MIN_FIT_SLOPE (a direction the ratio can be read from) and at most
MAX_SLOPE / 2 (never a clamped slope). The median, not least squares: the depth's jumps (an arm in
front of the chest) are differences the slopes do not explain, and least squares let them pull the
scale down (0.05-0.62 of the true scale over the true depth and normals of farm scenes; the median
0.92-1.03). Its unit is then the relief's (pixels of the grid: orthographic);
metres would be pixels times the person's height in metres over their height in pixels.
"""

from __future__ import annotations

import numpy as np

__all__ = ["MAX_SLOPE", "depth_from_normals", "normals_from_transport", "scaled_to_normals"]

MAX_SLOPE = 4.0   # a normal within ~14 degrees of grazing reads as this slope (its depth step per pixel)
TIE = 1e-3        # weight of the pull of the depth toward 0: fixes each separate part's free constant
CG_TOLERANCE = 1e-4   # relative residual of the normal equations at which the solve stops
CG_MAX_ITERATIONS = 400
MIN_FIT_SLOPE = 0.3   # scaled_to_normals reads the scale where the normals slope at least this much
MIN_FIT_PAIRS = 16    # and from at least this many neighbour pairs


def normals_from_transport(transport: np.ndarray) -> np.ndarray:
    """Unit camera-frame normals [h, w, 3] from SH transport [h, w, n >= 4]: band 1 of a
    Lambertian transport is (A_1 / pi) V (Y_1,-1, Y_10, Y_11)(n) ∝ V (y, z, x) (docs/conventions.md),
    so its direction is the normal (the bent normal for a transport with occlusion). Where band 1
    vanishes (outside the person), the normal faces the camera: (0, -1, 0)."""
    t = np.asarray(transport, np.float32)
    if t.ndim != 3 or t.shape[2] < 4:
        raise ValueError(f"transport must be [h, w, n >= 4], got {t.shape}")
    n = np.stack([t[..., 3], t[..., 1], t[..., 2]], axis=-1)
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    facing = np.array([0.0, -1.0, 0.0], np.float32)
    return np.where(length > 1e-8, n / np.maximum(length, 1e-30), facing).astype(np.float32)


def _slopes(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(d_c, d_r) of the module docstring, each within +-MAX_SLOPE (a normal facing away or
    grazing has no finite slope: it is read as the steepest one in its direction)."""
    nx, ny, nz = (normals[..., k].astype(np.float64) for k in range(3))
    away = np.minimum(ny, -1.0 / np.sqrt(1.0 + MAX_SLOPE ** 2))   # n_y at most -cos(atan(MAX_SLOPE))
    return np.clip(-nx / away, -MAX_SLOPE, MAX_SLOPE), np.clip(nz / away, -MAX_SLOPE, MAX_SLOPE)


def depth_from_normals(normals: np.ndarray, inside: np.ndarray) -> np.ndarray:
    """Depth [h, w] float32 (pixels, along +Y: larger is farther) of the surface whose normals
    [h, w, 3] are given, over the pixels `inside` [h, w] (bool); 0 outside. Least squares over each
    pair of neighbouring pixels both inside, d[q] - d[p] = the mean of their two slopes along p -> q,
    plus TIE * d^2 per pixel (each separate part's mean depth then sits near 0)."""
    normals = np.asarray(normals)
    inside = np.asarray(inside, bool)
    if normals.ndim != 3 or normals.shape[2] != 3 or normals.shape[:2] != inside.shape:
        raise ValueError(f"normals must be [h, w, 3] and inside [h, w], got {normals.shape} and {inside.shape}")
    if not np.all(np.isfinite(normals)):
        raise ValueError("normals must be finite")
    h, w = inside.shape
    depth = np.zeros((h, w), np.float64)
    if not inside.any():
        return depth.astype(np.float32)
    rows = np.flatnonzero(inside.any(axis=1))
    cols = np.flatnonzero(inside.any(axis=0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    m = inside[r0:r1, c0:c1]
    dc, dr = _slopes(normals[r0:r1, c0:c1])
    # edges between horizontal and vertical neighbours, both inside; their target differences
    ec = m[:, :-1] & m[:, 1:]
    er = m[:-1, :] & m[1:, :]
    gc = np.where(ec, 0.5 * (dc[:, :-1] + dc[:, 1:]), 0.0)
    gr = np.where(er, 0.5 * (dr[:-1, :] + dr[1:, :]), 0.0)
    ecf, erf = ec.astype(np.float64), er.astype(np.float64)

    def normal_matrix(x):
        """(A^T A + TIE) x for the edge-difference operator A over the box."""
        y = TIE * x * m
        fc = (x[:, 1:] - x[:, :-1]) * ecf
        fr = (x[1:, :] - x[:-1, :]) * erf
        y[:, 1:] += fc
        y[:, :-1] -= fc
        y[1:, :] += fr
        y[:-1, :] -= fr
        return y

    b = np.zeros(m.shape)
    b[:, 1:] += gc
    b[:, :-1] -= gc
    b[1:, :] += gr
    b[:-1, :] -= gr
    # Jacobi preconditioner: the diagonal is the pixel's number of edges + TIE
    diag = TIE + np.zeros(m.shape)
    diag[:, 1:] += ecf
    diag[:, :-1] += ecf
    diag[1:, :] += erf
    diag[:-1, :] += erf
    inv = np.where(m, 1.0 / diag, 0.0)
    x = np.zeros(m.shape)
    r = b.copy()
    z = r * inv
    p = z.copy()
    rz = float((r * z).sum())
    goal = CG_TOLERANCE * np.sqrt(float((b * b).sum())) + 1e-30
    for _ in range(CG_MAX_ITERATIONS):
        if np.sqrt(float((r * r).sum())) <= goal:
            break
        q = normal_matrix(p)
        alpha = rz / float((p * q).sum())
        x += alpha * p
        r -= alpha * q
        z = r * inv
        rz_new = float((r * z).sum())
        p = z + (rz_new / rz) * p
        rz = rz_new
    depth[r0:r1, c0:c1] = np.where(m, x, 0.0)
    return depth.astype(np.float32)


def scaled_to_normals(depth: np.ndarray, normals: np.ndarray, inside: np.ndarray) -> np.ndarray | None:
    """`depth` [h, w] (any scale and offset, larger farther) in the relief's unit: times the factor
    that fits its neighbour differences to the slopes of `normals` [h, w, 3] (module docstring),
    less its mean over `inside` [h, w], 0 outside; float32. None when too few neighbours fit or the
    factor is not positive (a depth turned inside out against the normals): the caller integrates
    the normals instead."""
    depth = np.asarray(depth, np.float64)
    inside = np.asarray(inside, bool)
    if depth.shape != inside.shape or np.shape(normals) != (*inside.shape, 3):
        raise ValueError(f"depth, inside [h, w] and normals [h, w, 3] must agree, got {depth.shape}, "
                         f"{inside.shape}, {np.shape(normals)}")
    if not inside.any() or not np.all(np.isfinite(depth[inside])):
        return None
    dc, dr = _slopes(np.asarray(normals))
    gentle = inside & (np.abs(dc) <= MAX_SLOPE / 2) & (np.abs(dr) <= MAX_SLOPE / 2)
    ratios = []  # target slope over depth difference, for each pair of gentle neighbours that slope
    for g, (a, b) in ((dc, (np.s_[:, :-1], np.s_[:, 1:])), (dr, (np.s_[:-1, :], np.s_[1:, :]))):
        target, step = 0.5 * (g[a] + g[b]), depth[b] - depth[a]
        use = gentle[a] & gentle[b] & (np.abs(target) > MIN_FIT_SLOPE) & (step != 0)
        ratios.append(target[use] / step[use])
    ratios = np.concatenate(ratios)
    if ratios.size < MIN_FIT_PAIRS:
        return None
    scale = float(np.median(ratios))
    if not scale > 0.0:
        return None
    out = np.where(inside, scale * (depth - depth[inside].mean()), 0.0)
    return out.astype(np.float32)
