"""Hair with volume: a thick cap over the scalp, curtains that fall past the neck, buns and ponytails.

Every piece is a closed mesh with outward faces (see farm.synthesis.garments), so the
transport bake sees hair as the occluder it is: the cap is a slab between
the scalp (+2 mm) and an outer surface standing 0.5-8 cm off it (thinning to
nothing at the face's hairline), a curtain is a slab hanging from the head
around the back and sides, clear of the neck and shoulders (it occludes the
neck and, for long hair, the sides of the face), a ponytail is a capped
tube, a bun an ellipsoid. The cap follows the posed scalp vertex by vertex;
the other pieces are built in the rest frame and carried by a blend of the
head's and the upper torso's rigid motions (by rest height), so long hair
bends with the neck.

Volume classes (recorded as `volume`): none (bald), shell (buzz cut),
short, medium, long, updo (bun, ponytail), big (afro / curly).
"""

from __future__ import annotations

import math

import numpy as np

from farm.synthesis import garments as g
from farm.synthesis.meshops import smooth_noise, submesh, vertex_normals

STYLES = ("bald", "buzz", "short", "medium", "long", "ponytail", "bun", "afro")
STYLE_P = (0.07, 0.10, 0.24, 0.20, 0.21, 0.07, 0.05, 0.06)
# styles only farm.synthesis.looks' held-out pool draws: a chin-length bob, two side pigtails, two buns
HELDOUT_STYLES = ("bob", "pigtails", "space_buns")
VOLUME = {"bald": "none", "buzz": "shell", "short": "short", "medium": "medium", "long": "long",
          "ponytail": "updo", "bun": "updo", "afro": "big", "bob": "medium", "pigtails": "updo", "space_buns": "updo"}
# Cap thickness range (m) per style.
CAP = {"buzz": (0.003, 0.006), "short": (0.012, 0.025), "medium": (0.015, 0.03), "long": (0.012, 0.025),
       "ponytail": (0.006, 0.012), "bun": (0.006, 0.012), "afro": (0.04, 0.075),
       "bob": (0.018, 0.032), "pigtails": (0.006, 0.012), "space_buns": (0.006, 0.012)}
# Curtain (length below the eyes, spread either side of the back, thickness) per style.
CURTAIN = {"medium": ((0.1, 0.17), (95.0, 115.0), (0.012, 0.025)), "long": ((0.24, 0.45), (100.0, 130.0), (0.015, 0.035)),
           "bob": ((0.04, 0.08), (120.0, 140.0), (0.022, 0.038))}


def volumetric(style: str) -> bool:
    return VOLUME.get(style, "none") not in ("none", "shell")


def head_frames(body, groups: dict):
    """Rigid (rest -> posed) fits of the head and of the upper torso."""
    head = groups["head"] & ~groups["eyes"]
    rest = body.rest_vertices
    h = (rest[:, 2] - rest[:, 2].min()) / max(np.ptp(rest[:, 2]), 1e-9)
    chest = groups["torso"] & (h > 0.68) & (h < 0.8)
    return g.rigid_fit(rest[head], body.vertices[head]), g.rigid_fit(rest[chest], body.vertices[chest])


def _carry(points: np.ndarray, frames, z_head: float, z_torso: float) -> np.ndarray:
    """Rest-frame points to the posed frame: head motion above z_head, torso below z_torso."""
    w = g.smoothstep(z_torso, z_head, points[:, 2])
    return g.blend_rigid(points, list(frames), np.stack([w, 1 - w], axis=1))


def _cap(body, normals, groups, rng, style, layout):

    rest = body.rest_vertices
    head, eyes = groups["head"], groups["eyes"]
    eye_z, eye_y, centre_y = layout["eye_z"], layout["eye_y"], layout["centre_y"]
    hairline = eye_z + rng.uniform(0.05, 0.08)
    low = eye_z - (0.01 if style in ("buzz", "short", "afro") else 0.04)
    back = rest[:, 1] > centre_y - 0.02
    sides = rest[:, 1] > eye_y + rng.uniform(0.04, 0.06)
    mask = head & ~eyes & (rest[:, 2] > low) & (
        (rest[:, 2] > hairline) | (sides & (rest[:, 2] > eye_z - 0.02)) | back)

    faces, ids = submesh(body.faces, mask)
    lo, hi = CAP[style]
    base = float(rng.uniform(lo, hi))
    freq = 60.0 if style == "afro" else 25.0
    noise = smooth_noise(rest[ids], rng, base_freq=freq)
    t = base * (1.0 + 0.35 * noise)
    # Thin to 2 mm toward the face's hairline (front boundary), full at the back.
    edge = np.unique(g.boundary_edges(faces).ravel())
    front_edge = edge[rest[ids][edge, 1] < centre_y - 0.01]
    if len(front_edge):
        d = np.min(np.linalg.norm(rest[ids][:, None, :] - rest[ids][front_edge][None, :, :], axis=2), axis=1)
        t = 0.002 + (t - 0.002) * g.smoothstep(0.0, 0.03 + 0.3 * base, d)
    centre = body.vertices[head].mean(axis=0)
    n = normals[ids]
    radial = g.unit(body.vertices[ids] - centre)
    direction = g.unit(n + radial)
    inner = body.vertices[ids] + 0.002 * n
    outer = body.vertices[ids] + t[:, None] * direction
    v = np.concatenate([outer, inner])
    f = g.slab(outer, inner, faces)
    return v, np.concatenate([rest[ids], rest[ids]]), f, mask, base


def _curtain(body, rng, style, layout, frames, cap_t):
    """Slab hanging around the back and sides of the head from ear height to the tips."""
    rest = body.rest_vertices
    c = layout["head_centre"]
    lengths, spreads, thicknesses = CURTAIN[style]
    length = float(rng.uniform(*lengths))
    spread = float(rng.uniform(*spreads))
    thick = float(rng.uniform(*thicknesses))
    z_top = c[2] + 0.01
    z_end = layout["eye_z"] - length
    rows, cols = 12, 17
    zs = np.linspace(z_top, z_end, rows)
    thetas = np.radians(np.linspace(-spread, spread, cols))  # 0 = straight back (+Y)
    # Angle and horizontal distance of every rest vertex about the head's vertical axis.
    rel = rest[:, :2] - c[:2]
    ang = np.arctan2(rel[:, 0], rel[:, 1])
    dist = np.linalg.norm(rel, axis=1)
    reach = np.zeros((rows, cols))
    half = (thetas[1] - thetas[0]) * 0.75
    arms = layout["arms"]
    for i, z in enumerate(zs):
        slab_sel = (np.abs(rest[:, 2] - z) < 0.02) & ~arms
        for j, th in enumerate(thetas):
            d_ang = np.abs((ang[slab_sel] - th + math.pi) % (2 * math.pi) - math.pi)
            near = dist[slab_sel][d_ang < half]
            reach[i, j] = near.max() if len(near) else 0.0
    reach = np.maximum.accumulate(np.maximum(reach, 0.06), axis=0) + cap_t + 0.008
    # Smooth across the columns so the curtain is a drape, not a cast of the shoulders.
    for _ in range(2):
        reach[:, 1:-1] = 0.25 * reach[:, :-2] + 0.5 * reach[:, 1:-1] + 0.25 * reach[:, 2:]
    wave = 1.0 + 0.08 * np.sin(thetas[None, :] * rng.uniform(6, 12) + rng.uniform(0, 6.3))
    taper = np.linspace(1.0, 0.35, rows)[:, None]
    inner_r = reach
    outer_r = reach + thick * taper * wave
    def grid(r):
        x = c[0] + r * np.sin(thetas)[None, :]
        y = c[1] + r * np.cos(thetas)[None, :]
        z = np.broadcast_to(zs[:, None], r.shape)
        return np.stack([x, y, z], axis=-1).reshape(-1, 3)
    outer, inner = grid(outer_r), grid(inner_r)
    faces = []
    for i in range(rows - 1):
        for j in range(cols - 1):
            a, b = i * cols + j, i * cols + j + 1
            faces += [[a, b, b + cols], [a, b + cols, a + cols]]
    faces = np.array(faces, dtype=np.int64)
    n0 = np.cross(outer[faces[0, 1]] - outer[faces[0, 0]], outer[faces[0, 2]] - outer[faces[0, 0]])
    if np.dot(n0[:2], outer[faces[0, 0], :2] - c[:2]) < 0:
        faces = faces[:, ::-1]
    rest_v = np.concatenate([outer, inner])
    f = g.slab(outer, inner, faces)
    posed = _carry(rest_v, frames, layout["chin_z"], layout["shoulder_z"])
    return posed, rest_v, f, {"length_m": length, "spread_deg": spread, "thickness_m": thick}


def _ponytail(body, rng, layout, frames):
    c = layout["head_centre"]
    length = float(rng.uniform(0.15, 0.32))
    start = np.array([c[0], c[1] + layout["head_radius"] + 0.005, c[2] + rng.uniform(-0.01, 0.04)])
    k = np.linspace(0.0, 1.0, 8)
    path = start + np.stack([np.zeros_like(k), 0.05 * np.sin(k * 2.0), -length * k], axis=1)
    radii = float(rng.uniform(0.02, 0.035)) * (1.0 - 0.65 * k)
    v, f = g.tube(path, radii, segments=10)
    posed = _carry(v, frames, layout["chin_z"], layout["shoulder_z"])
    return posed, v, f, {"length_m": length}


def _pigtails(body, rng, layout, frames):
    """Two tubes from behind the ears, falling past the jaw and out to either side."""
    c = layout["head_centre"]
    length = float(rng.uniform(0.12, 0.25))
    r0 = float(rng.uniform(0.018, 0.028))
    k = np.linspace(0.0, 1.0, 8)
    pieces = []
    for side in (1.0, -1.0):
        start = np.array([c[0] + side * 0.85 * layout["head_radius"], c[1] + 0.3 * layout["head_radius"], c[2]])
        path = start + np.stack([side * 0.04 * np.sin(k * 1.5), 0.03 * k, -length * k], axis=1)
        pieces.append(g.tube(path, r0 * (1.0 - 0.6 * k), segments=10))
    v = np.concatenate([pieces[0][0], pieces[1][0]])
    f = np.concatenate([pieces[0][1], pieces[1][1] + len(pieces[0][0])])
    return _carry(v, frames, layout["chin_z"], layout["shoulder_z"]), v, f, {"length_m": length}


def _space_buns(body, rng, layout, frames):
    """Two buns on top of the head, either side of the parting."""
    c = layout["head_centre"]
    r = float(rng.uniform(0.03, 0.042))
    rest = body.rest_vertices
    pieces = []
    for side in (1.0, -1.0):
        x, y = c[0] + side * 0.5 * layout["head_radius"], c[1] + 0.2 * layout["head_radius"]
        near = (np.abs(rest[:, 0] - x) < 0.015) & (np.abs(rest[:, 1] - y) < 0.015) & (rest[:, 2] > layout["eye_z"])
        top = rest[near, 2].max() if near.any() else c[2] + 0.08  # the scalp under the bun
        centre = np.array([x, y, top + 0.55 * r])  # sunk into the cap a little
        pieces.append(g.ellipsoid(centre, (r, 0.9 * r, 0.85 * r)))
    v = np.concatenate([pieces[0][0], pieces[1][0]])
    f = np.concatenate([pieces[0][1], pieces[1][1] + len(pieces[0][0])])
    return v @ frames[0][0].T + frames[0][1], v, f, {"radius_m": r}


def _bun(body, rng, layout, frames):
    c = layout["head_centre"]
    r = float(rng.uniform(0.035, 0.05))
    up = float(rng.uniform(0.0, 0.07))
    centre = np.array([c[0], c[1] + layout["head_radius"] * math.cos(up / 0.09) + 0.6 * r,
                       c[2] + 0.03 + up])
    v, f = g.ellipsoid(centre, (r, 0.8 * r, 0.85 * r))
    posed = v @ frames[0][0].T + frames[0][1]
    return posed, v, f, {"radius_m": r}


def make_hair(body, normals, groups, rng, style: str):
    """(vertices, rest, faces, normals, scalp mask, record) or None for bald."""
    if style == "bald":
        return None
    rest = body.rest_vertices
    eyes, head = groups["eyes"], groups["head"]
    h = (rest[:, 2] - rest[:, 2].min()) / max(np.ptp(rest[:, 2]), 1e-9)
    layout = {
        "eye_z": rest[eyes, 2].mean(),
        "eye_y": rest[eyes, 1].mean(),
        "centre_y": rest[head, 1].mean(),
        "arms": groups["upperarm"] | groups["forearm"],
    }
    scalp = head & (rest[:, 2] > layout["eye_z"])
    layout["head_centre"] = np.array([rest[scalp, 0].mean(), rest[scalp, 1].mean(), layout["eye_z"] + 0.02])
    layout["head_radius"] = float(rest[scalp, 1].max() - layout["head_centre"][1])
    layout["chin_z"] = layout["eye_z"] - 0.1
    layout["shoulder_z"] = float(rest[groups["torso"] & (h > 0.78), 2].mean()) if (groups["torso"] & (h > 0.78)).any() \
        else layout["chin_z"] - 0.1
    frames = head_frames(body, groups)
    v, r, f, mask, cap_t = _cap(body, normals, groups, rng, style, layout)
    record = {"style": style, "volume": VOLUME[style], "thickness_m": cap_t}
    extra = None
    if style in CURTAIN:
        extra = _curtain(body, rng, style, layout, frames, cap_t)
        record["curtain"] = extra[3]
    elif style == "ponytail":
        extra = _ponytail(body, rng, layout, frames)
        record["ponytail"] = extra[3]
    elif style == "bun":
        extra = _bun(body, rng, layout, frames)
        record["bun"] = extra[3]
    elif style in ("pigtails", "space_buns"):
        extra = (_pigtails if style == "pigtails" else _space_buns)(body, rng, layout, frames)
        record[style] = extra[3]
    if extra is not None:
        ev, er, ef, _ = extra
        f = np.concatenate([f, ef + len(v)])
        v = np.concatenate([v, ev])
        r = np.concatenate([r, er])
    return v, r, f, vertex_normals(v, f), mask, record
