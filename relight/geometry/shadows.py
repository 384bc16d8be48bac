"""Cast shadows from a depth map: which share of a lamp each pixel of the person sees.

A screen-space march (the idea of screen-space and horizon-based shadows): from each pixel's
surface point P, along the unit direction l toward the lamp, the points Q_k = P + t_k l are
projected back into the depth map; where the surface there lies in front of Q_k (nearer the
camera by delta > 0), the ray passes behind it and is blocked. A lamp is a disc of angular radius
theta: the ray at angle beta from its centre is blocked at the angle the worst occluder subtends,

    beta_k = (delta_k - bias_k) * s / t_k        (s = sin of the angle between l and the view axis:
                                                  the part of delta perpendicular to the ray)

and the share of the disc seen is (theta - max_k beta_k) / (2 theta), clamped to [0, 1]: a
penumbra as wide as the lamp. Occluders thicker than `thickness` along the view axis are taken to
end there (a hand in front of the chest does not shadow the chest from the side). Where the lamp
is along the view axis (s -> 0) every shadow is hidden behind what casts it: nothing is shadowed.

Cameras: orthographic in pixel units (the relief of relight.geometry.relief) or a pinhole of
focal length `focal_px` about the grid's centre with depth in any unit along +Y (the farm's depth
pass, metres). Axes as docs/conventions.md (X right, Y away from the camera, Z up). numpy only.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["MIN_HALF_ANGLE_DEG", "cast_visibility", "march_steps"]

MIN_HALF_ANGLE_DEG = 2.0   # a lamp narrower than this still gets a penumbra of about a pixel
MIN_SCREEN_SINE = 0.05     # lamps within ~3 degrees of the view axis cast no visible shadow
BIAS_PIXELS = 0.75         # the depth a sample may sit in front of the ray by the grid's sampling alone, in
                           # pixels of surface slope (nearest sampling is off by up to half a pixel each way)


def march_steps(extent: float) -> np.ndarray:
    """Screen distances (pixels) the march samples, out to `extent`: every pixel for the first 8,
    every 2 to 32, then every 4 (a far occluder needs less precision for the same angle)."""
    extent = max(float(extent), 1.0)
    steps = np.concatenate([np.arange(1.0, 9.0), np.arange(10.0, 33.0, 2.0), np.arange(36.0, extent + 4.0, 4.0)])
    return steps[steps <= extent + 4.0]


def _slope(depth: np.ndarray) -> np.ndarray:
    """The depth's steepest change per pixel (central differences within the grid)."""
    gy, gx = np.gradient(depth.astype(np.float64))
    return np.hypot(gx, gy).astype(np.float32)


def cast_visibility(depth: np.ndarray, inside: np.ndarray, direction, half_angle_deg: float = 0.0, *,
                    focal_px: float | None = None, thickness=math.inf,
                    where: np.ndarray | None = None) -> np.ndarray:
    """The share in [0, 1] of a lamp toward unit `direction` (camera frame), of angular radius
    `half_angle_deg`, that each pixel's surface point sees past the rest of the surface [h, w]
    float32; 1 outside `inside` and outside `where` (the pixels to compute; default: inside).

    depth [h, w]: distance along +Y of each pixel's surface (pixels when focal_px is None, the
    orthographic relief; else any unit, a pinhole of focal_px pixels centred on the grid).
    thickness: how far behind its front surface each pixel's occluder reaches along +Y, a number
    or [h, w] (same unit as depth; inf: a solid column, the heightfield's classic assumption)."""
    depth = np.asarray(depth, np.float32)
    inside = np.asarray(inside, bool)
    if depth.ndim != 2 or depth.shape != inside.shape:
        raise ValueError(f"depth and inside must be [h, w] alike, got {depth.shape} and {inside.shape}")
    l = np.asarray(direction, np.float64).reshape(3)
    norm = float(np.linalg.norm(l))
    if not math.isfinite(norm) or norm == 0.0:
        raise ValueError(f"direction must be a finite non-zero 3-vector, got {direction!r}")
    l = l / norm
    if not math.isfinite(half_angle_deg) or half_angle_deg < 0:
        raise ValueError(f"half_angle_deg must be finite and >= 0, got {half_angle_deg}")
    if focal_px is not None and not (math.isfinite(focal_px) and focal_px > 0):
        raise ValueError(f"focal_px must be finite and > 0, got {focal_px}")
    h, w = depth.shape
    vis = np.ones((h, w), np.float32)
    todo = inside if where is None else inside & np.asarray(where, bool)
    sine = math.hypot(l[0], l[2])
    if not todo.any() or sine < MIN_SCREEN_SINE:
        return vis
    if not np.all(np.isfinite(depth[inside])):
        raise ValueError("depth must be finite over the person")
    tan_theta = math.tan(math.radians(max(half_angle_deg, MIN_HALF_ANGLE_DEG)))
    rows, cols = np.nonzero(todo)
    d = depth[rows, cols].astype(np.float64)
    u, v = cols + 0.5, rows + 0.5
    if focal_px is None:
        px = np.ones_like(d)                       # one pixel of surface per pixel of screen
        P = np.stack([u, d, -v], axis=-1)
    else:
        if np.any(depth[inside] <= 0):
            raise ValueError("a pinhole's depth must be > 0 over the person")
        cx, cy = w / 2.0, h / 2.0
        px = d / focal_px                          # the surface one pixel spans at this depth
        P = np.stack([(u - cx) * px, d, -(v - cy) * px], axis=-1)
    # the march's parameter per screen pixel: the lamp's direction moves Q across the screen by
    # sine per unit of t (orthographic), or by about sine / px pixels (pinhole, locally)
    per_pixel = px / sine
    occluder = np.where(inside, depth, np.nan).astype(np.float32)  # no surface outside the person
    reach = np.broadcast_to(np.asarray(thickness, np.float32), (h, w))
    if np.any(np.isnan(reach)) or np.any(reach < 0):
        raise ValueError("thickness must be >= 0 (inf allowed)")
    slope = _slope(np.where(inside, depth, 0.0)) * inside
    own_slope = slope[rows, cols]
    worst = np.full(d.shape, -np.inf)
    for s in march_steps(math.hypot(h, w)):
        t = s * per_pixel
        Q = P + t[:, None] * l
        if focal_px is None:
            qc, qr, qy = Q[:, 0], -Q[:, 2], Q[:, 1]
        else:
            ahead = Q[:, 1] > 1e-9
            qy = np.where(ahead, Q[:, 1], np.nan)
            qc, qr = Q[:, 0] * focal_px / qy + cx, -Q[:, 2] * focal_px / qy + cy
        c = np.floor(qc).astype(np.int64)
        r = np.floor(qr).astype(np.int64)
        on = (r >= 0) & (r < h) & (c >= 0) & (c < w)
        if not on.any():
            break
        rc, cc = np.clip(r, 0, h - 1), np.clip(c, 0, w - 1)
        surface = occluder[rc, cc]
        delta = qy - surface                        # > 0: the surface there is nearer than the ray point
        pixel_here = (qy / focal_px) if focal_px is not None else 1.0
        # the receiver's own surface, sampled a pixel off, may sit in front of the ray by its slope: the
        # smaller of the two slopes (an occluder's edge is steep, the floor it shadows is not)
        bias = BIAS_PIXELS * np.minimum(slope[rc, cc], own_slope) + 0.25 * pixel_here
        beta = (delta - bias) * sine / t
        valid = on & np.isfinite(beta) & (delta < reach[rc, cc])
        np.maximum(worst, np.where(valid, beta, -np.inf), out=worst)
    share = np.clip((tan_theta - worst) / (2.0 * tan_theta), 0.0, 1.0)
    vis[rows, cols] = share.astype(np.float32)
    return vis
