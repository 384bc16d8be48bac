"""Appearance: skin tone, clothing shells, a hair mesh and their Principled materials.

Clothing regions come from the skin weights (dominant bone per vertex) cut
by heights measured on the rest (A-)pose, so hems stay put whatever the
pose. Each garment is an offset shell: the body faces of its region,
pushed out along the vertex normals. Hair is a shell over the scalp with a
smoothly varying thickness, so it gets a transport bake like everything
else. Materials are plain parameter dicts (recorded in the sidecar);
`build_material` turns one into Cycles nodes.
"""

from __future__ import annotations

import colorsys
import math
from dataclasses import dataclass

import numpy as np

from farm.bake import vertex_normals
from farm.bodies import Body

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


def submesh(faces: np.ndarray, vertex_mask: np.ndarray):
    """Faces whose three vertices are all selected, reindexed; (faces, old vertex ids)."""
    keep = vertex_mask[faces].all(axis=1)
    sub = faces[keep]
    ids = np.unique(sub)
    remap = np.full(len(vertex_mask), -1, dtype=np.int64)
    remap[ids] = np.arange(len(ids))
    return remap[sub], ids


def smooth_noise(points: np.ndarray, rng: np.random.Generator, octaves: int = 3, base_freq: float = 6.0) -> np.ndarray:
    """A smooth scalar field in [-1, 1]: sum of random plane waves (deterministic given rng)."""
    total = np.zeros(len(points))
    norm = 0.0
    for o in range(octaves):
        for _ in range(3):
            k = rng.standard_normal(3)
            k *= base_freq * (2.0 ** o) / np.linalg.norm(k)
            phase = rng.uniform(0, 2 * math.pi)
            amp = 0.5 ** o
            total += amp * np.sin(points @ k + phase)
            norm += amp
    return total / norm


def shell(body: Body, body_normals: np.ndarray, mask: np.ndarray, thickness) -> tuple:
    """Offset shell over the selected vertices: (vertices, rest, faces, normals)."""
    faces, ids = submesh(body.faces, mask)
    if len(faces) == 0:
        raise ValueError("garment region selects no faces")
    t = np.broadcast_to(np.asarray(thickness, dtype=np.float64), (len(body.vertices),))[ids]
    verts = body.vertices[ids] + t[:, None] * body_normals[ids]
    rest = body.rest_vertices[ids]
    return verts, rest, faces, vertex_normals(verts, faces)


# ------------------------------------------------------------------ colours

# Linear-RGB skin reflectance anchors, very light to very dark (roughly the
# range of measured skin albedos).
_SKIN_ANCHORS = np.array([
    [0.66, 0.47, 0.38],
    [0.52, 0.33, 0.24],
    [0.33, 0.19, 0.12],
    [0.17, 0.09, 0.055],
    [0.07, 0.038, 0.025],
])


def sample_skin(rng: np.random.Generator) -> list[float]:
    t = rng.uniform(0.0, 1.0) * (len(_SKIN_ANCHORS) - 1)
    i = min(int(t), len(_SKIN_ANCHORS) - 2)
    rgb = (1 - (t - i)) * _SKIN_ANCHORS[i] + (t - i) * _SKIN_ANCHORS[i + 1]
    rgb = rgb * rng.uniform(0.9, 1.1, size=3) ** 0.5  # small per-channel (hue) jitter
    return np.clip(rgb, 0.01, 0.9).tolist()


def _hsv_linear(h: float, s: float, v: float) -> list[float]:
    srgb = np.array(colorsys.hsv_to_rgb(h % 1.0, s, v))
    lin = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    return np.clip(lin, 0.005, 0.95).tolist()


def sample_fabric_colour(rng: np.random.Generator) -> list[float]:
    kind = rng.random()
    if kind < 0.3:  # neutrals: black, grey, white
        return _hsv_linear(0.0, 0.0, rng.uniform(0.08, 0.95))
    if kind < 0.45:  # denim-like blues
        return _hsv_linear(rng.uniform(0.55, 0.64), rng.uniform(0.3, 0.7), rng.uniform(0.25, 0.7))
    return _hsv_linear(rng.uniform(0, 1), rng.uniform(0.2, 0.9), rng.uniform(0.2, 0.95))


def sample_hair_colour(rng: np.random.Generator) -> list[float]:
    kind = rng.random()
    if kind < 0.1:  # grey / white
        return _hsv_linear(0.08, rng.uniform(0.0, 0.1), rng.uniform(0.5, 0.85))
    if kind < 0.2:  # dyed
        return _hsv_linear(rng.uniform(0, 1), rng.uniform(0.5, 0.9), rng.uniform(0.3, 0.8))
    # black .. brown .. blond
    v = rng.uniform(0.06, 0.8)
    return _hsv_linear(rng.uniform(0.05, 0.11), rng.uniform(0.35, 0.75), v)


def jitter_hue(rgb: list[float], rng: np.random.Generator, amount: float = 0.03) -> list[float]:
    h, s, v = colorsys.rgb_to_hsv(*np.clip(rgb, 0, 1))
    return list(colorsys.hsv_to_rgb((h + rng.uniform(-amount, amount)) % 1.0, s, v))


def material(
    kind: str,
    rng: np.random.Generator,
    colour: list[float],
    roughness: tuple[float, float],
    diffuse_only: bool,
    pattern_p: float = 0.0,
    metallic_p: float = 0.0,
    transmission_p: float = 0.0,
) -> dict:
    """Principled parameters; `diffuse_only` gives a pure Lambert surface."""
    rough = float(rng.uniform(*roughness))
    spec = {
        "kind": kind,
        "base_color": [float(c) for c in colour],
        "second_color": [float(c) for c in jitter_hue(sample_fabric_colour(rng), rng)],
        "pattern": "none",
        "pattern_scale": float(rng.uniform(4.0, 30.0)),
        "pattern_axis": int(rng.integers(3)),
        "roughness": rough,
        "metallic": float(rng.uniform(0.5, 1.0)) if rng.random() < metallic_p else 0.0,
        "transmission": float(rng.uniform(0.05, 0.3)) if rng.random() < transmission_p else 0.0,
        "specular_level": float(rng.uniform(0.3, 0.6)),
        "diffuse_roughness": rough,
    }
    if rng.random() < pattern_p:
        spec["pattern"] = str(rng.choice(["stripes", "checks", "noise"]))
    if diffuse_only:
        spec.update(roughness=1.0, metallic=0.0, transmission=0.0, specular_level=0.0, diffuse_roughness=0.0)
    return spec


def is_diffuse(spec: dict) -> bool:
    """True when the material is a pure Lambertian (no specular, metal, glass, or roughness)."""
    return (
        spec["specular_level"] == 0.0
        and spec["metallic"] == 0.0
        and spec["transmission"] == 0.0
        and spec["diffuse_roughness"] == 0.0
    )


# ------------------------------------------------------------------ outfit


def dress(
    body: Body, rng: np.random.Generator, diffuse_only: bool = False, skirt_allowed: bool = True
) -> tuple[list[Part], dict]:
    """Body + clothing shells + hair; returns the parts and an appearance record."""
    normals = vertex_normals(body.vertices, body.faces)
    groups = vertex_groups(body)
    h = rest_height_fraction(body)
    parts: list[Part] = []
    record: dict = {"diffuse_only": bool(diffuse_only)}

    skin = material("skin", rng, sample_skin(rng), (0.35, 0.6), diffuse_only)
    record["skin"] = skin
    body_mask = ~groups["eyes"]
    faces, ids = submesh(body.faces, body_mask)
    parts.append(Part("body", body.vertices[ids], body.rest_vertices[ids], faces, normals[ids], skin, source_ids=ids))
    faces, ids = submesh(body.faces, groups["eyes"])
    if len(faces):
        eye = material("eyes", rng, [0.55, 0.52, 0.5], (0.05, 0.15), diffuse_only)
        parts.append(Part("eyes", body.vertices[ids], body.rest_vertices[ids], faces, normals[ids], eye))

    garments = []
    # Top: torso with a hem, and sleeves of some length.
    top_kind = str(rng.choice(["tank", "tshirt", "longsleeve"], p=[0.2, 0.45, 0.35]))
    hem = rng.uniform(0.5, 0.57)
    top_mask = groups["torso"] & (h > hem)
    if top_kind in ("tshirt", "longsleeve"):
        top_mask |= groups["upperarm"]
    if top_kind == "longsleeve":
        top_mask |= groups["forearm"]
    garments.append(("top", top_kind, top_mask, rng.uniform(0.006, 0.012)))

    bottom_kind = str(rng.choice(["trousers", "capri", "shorts", "skirt"], p=[0.45, 0.15, 0.25, 0.15]))
    if bottom_kind == "skirt" and not skirt_allowed:
        bottom_kind = "shorts"  # legs apart or bent would cut through a skirt
    waist = rng.uniform(0.56, 0.6)
    cut = {"trousers": rng.uniform(0.035, 0.06), "capri": rng.uniform(0.15, 0.22), "shorts": rng.uniform(0.33, 0.42),
           "skirt": rng.uniform(0.25, 0.42)}[bottom_kind]
    if bottom_kind == "skirt":
        # Only the waistband follows the body; the skirt itself is a flared tube.
        bottom_mask = groups["torso"] & (h < waist) & (h > waist - 0.04)
        skirt = skirt_mesh(body, h, groups, waist - 0.03, cut, rng.uniform(0.0, 0.12))
    else:
        bottom_mask = (groups["torso"] | groups["thigh"] | groups["shin"]) & (h < waist) & (h > cut)
        skirt = None
    garments.append(("bottom", bottom_kind, bottom_mask, rng.uniform(0.004, 0.008)))

    shoe_kind = str(rng.choice(["shoes", "boots", "barefoot"], p=[0.7, 0.2, 0.1]))
    if shoe_kind != "barefoot":
        shoe_mask = groups["foot"] | (groups["shin"] & (h < (0.12 if shoe_kind == "boots" else 0.045)))
        garments.append(("shoes", shoe_kind, shoe_mask, rng.uniform(0.008, 0.015)))

    record["garments"] = {}
    covered_faces = np.zeros(len(body.faces), dtype=bool)
    for slot, kind, mask, thickness in garments:
        covered_faces |= mask[body.faces].all(axis=1)
        colour = jitter_hue(sample_fabric_colour(rng), rng)
        if slot == "shoes":
            spec = material("shoe", rng, colour, (0.2, 0.8), diffuse_only, pattern_p=0.0, metallic_p=0.05)
        else:
            spec = material("cloth", rng, colour, (0.55, 1.0), diffuse_only, pattern_p=0.5, metallic_p=0.04, transmission_p=0.04)
        verts, rest, faces, nrm = shell(body, normals, mask, thickness)
        if slot == "bottom" and skirt is not None:
            sv, srest, sf = skirt
            faces = np.concatenate([faces, sf + len(verts)])
            verts = np.concatenate([verts, sv])
            rest = np.concatenate([rest, srest])
            nrm = vertex_normals(verts, faces)
        parts.append(Part(slot, verts, rest, faces, nrm, spec))
        record["garments"][slot] = {"kind": kind, "thickness_m": float(thickness), "material": spec}

    hair = _hair(body, normals, groups, rng, diffuse_only)
    if hair is not None:
        parts.append(hair[0])
        record["hair"] = hair[1]
        covered_faces |= hair[2][body.faces].all(axis=1)
    else:
        record["hair"] = {"style": "bald"}
    # A body vertex is hidden when every face around it is under a shell.
    exposed = np.zeros(len(body.vertices), dtype=bool)
    exposed[body.faces[~covered_faces].ravel()] = True
    body_ids = parts[0].source_ids
    parts[0].hidden = ~exposed[body_ids]
    return parts, record


def skirt_mesh(body: Body, h: np.ndarray, groups: dict, top: float, hem: float, flare: float, segments: int = 48):
    """A flared tube from rest height `top` down to `hem` around the hips and both thighs.

    Each ring is centred on the posed body vertices at that rest height and
    encloses all of them (plus a margin), widening by `flare` (m per m of
    drop); returns (vertices, rest positions, faces), normals facing out.
    """
    rings = 8
    levels = np.linspace(top, hem, rings)
    legs = groups["torso"] | groups["thigh"]
    angle = np.linspace(0.0, 2 * math.pi, segments, endpoint=False)
    circle = np.stack([np.cos(angle), np.sin(angle)], axis=1)
    verts, rest = [], []
    z_top = None
    for level in levels:
        near = legs & (np.abs(h - level) < 0.012)
        if near.sum() < 8:
            raise ValueError("skirt ring found no body vertices at its height")
        pts = body.vertices[near]
        centre = pts[:, :2].mean(axis=0)
        z = float(pts[:, 2].mean())
        z_top = z if z_top is None else z_top
        radius = np.linalg.norm(pts[:, :2] - centre, axis=1).max() + 0.012 + flare * (z_top - z)
        ring = np.concatenate([centre + radius * circle, np.full((segments, 1), z)], axis=1)
        verts.append(ring)
        rest_centre = body.rest_vertices[near].mean(axis=0)
        rest.append(np.concatenate([rest_centre[:2] + radius * circle,
                                    np.full((segments, 1), rest_centre[2])], axis=1))
    verts = np.concatenate(verts)
    rest = np.concatenate(rest)
    faces = []
    for r in range(rings - 1):
        for i in range(segments):
            a, b = r * segments + i, r * segments + (i + 1) % segments
            c, d = a + segments, b + segments
            faces += [[a, c, b], [b, c, d]]
    faces = np.array(faces, dtype=np.int64)
    # Orient outward: the first face's normal must point away from its ring centre.
    n0 = np.cross(verts[faces[0, 1]] - verts[faces[0, 0]], verts[faces[0, 2]] - verts[faces[0, 0]])
    if np.dot(n0[:2], verts[faces[0, 0], :2] - verts[:segments, :2].mean(axis=0)) < 0:
        faces = faces[:, ::-1]
    return verts, rest, faces


def _hair(body: Body, normals: np.ndarray, groups: dict, rng: np.random.Generator, diffuse_only: bool):
    style = str(rng.choice(["bald", "short", "medium", "long"], p=[0.1, 0.4, 0.3, 0.2]))
    if style == "bald":
        return None
    rest = body.rest_vertices
    head = groups["head"]
    eyes = groups["eyes"]
    eye_z = rest[eyes, 2].mean()
    eye_y = rest[eyes, 1].mean()  # front of the face (the body faces -Y)
    centre_y = rest[head, 1].mean()
    hairline = eye_z + rng.uniform(0.05, 0.08)
    low = {"short": eye_z - 0.01, "medium": eye_z - 0.05, "long": eye_z - 0.14}[style]
    back = rest[:, 1] > centre_y - 0.02
    sides = rest[:, 1] > eye_y + rng.uniform(0.04, 0.06)
    above = rest[:, 2] > low
    mask = head & above & ((rest[:, 2] > hairline) | (sides & (rest[:, 2] > eye_z - 0.02)) | back)
    record = {"style": style}
    if style == "long":
        # Long hair falls over the back of the neck onto the upper back.
        torso = groups["torso"]
        neck_base = rest[head, 2].min()
        drop = float(rng.uniform(0.06, 0.2))
        behind = rest[:, 1] > rest[torso, 1].mean() + 0.02
        mask |= (head & behind) | (torso & behind & (rest[:, 2] > neck_base - drop))
        record["drop_m"] = drop
    base = {"short": 0.008, "medium": 0.014, "long": 0.02}[style]
    noise = smooth_noise(rest, rng, base_freq=25.0)
    thickness = base * (1.0 + 0.35 * noise)
    verts, rest_v, faces, nrm = shell(body, normals, mask, thickness)
    # Hair strands scatter broadly; a smooth GGX cap would read as a helmet.
    spec = material("hair", rng, sample_hair_colour(rng), (0.5, 0.85), diffuse_only)
    record.update(thickness_m=base, material=spec)
    return Part("hair", verts, rest_v, faces, nrm, spec), record, mask


# ------------------------------------------------------------------ Cycles


def build_material(name: str, spec: dict):
    """Principled BSDF material; returns (material, base-colour socket, material-params socket)."""
    import bpy

    mat = bpy.data.materials.new(name)
    nodes, links = mat.node_tree.nodes, mat.node_tree.links
    bsdf = nodes["Principled BSDF"]
    bsdf.inputs["Roughness"].default_value = spec["roughness"]
    bsdf.inputs["Metallic"].default_value = spec["metallic"]
    bsdf.inputs["Transmission Weight"].default_value = spec["transmission"]
    bsdf.inputs["Specular IOR Level"].default_value = spec["specular_level"]
    bsdf.inputs["Diffuse Roughness"].default_value = spec["diffuse_roughness"]
    bsdf.inputs["IOR"].default_value = 1.5

    colour_a = nodes.new("ShaderNodeRGB")
    colour_a.outputs[0].default_value = (*spec["base_color"], 1.0)
    base_socket = colour_a.outputs[0]
    if spec["pattern"] != "none":
        coords = nodes.new("ShaderNodeAttribute")
        coords.attribute_type = "GEOMETRY"
        coords.attribute_name = "relight_rest"
        colour_b = nodes.new("ShaderNodeRGB")
        colour_b.outputs[0].default_value = (*spec["second_color"], 1.0)
        scale = spec["pattern_scale"]
        if spec["pattern"] == "stripes":
            tex = nodes.new("ShaderNodeTexWave")
            tex.wave_type = "BANDS"
            tex.bands_direction = "XYZ"[spec["pattern_axis"]]
            tex.inputs["Scale"].default_value = scale / 4.0
            tex.inputs["Distortion"].default_value = 0.0
            fac = tex.outputs["Fac"]
            # Wave Fac is in [0, 1]; a threshold makes crisp two-colour stripes.
            step = nodes.new("ShaderNodeMath")
            step.operation = "GREATER_THAN"
            step.inputs[1].default_value = 0.5
            links.new(fac, step.inputs[0])
            fac = step.outputs[0]
        elif spec["pattern"] == "checks":
            tex = nodes.new("ShaderNodeTexChecker")
            tex.inputs["Scale"].default_value = scale
            fac = tex.outputs["Fac"]
        else:
            tex = nodes.new("ShaderNodeTexNoise")
            tex.inputs["Scale"].default_value = scale
            fac = tex.outputs["Fac"]
        links.new(coords.outputs["Vector"], tex.inputs["Vector"])
        mix = nodes.new("ShaderNodeMix")
        mix.data_type = "RGBA"
        links.new(fac, mix.inputs["Factor"])
        links.new(colour_a.outputs[0], mix.inputs[6])
        links.new(colour_b.outputs[0], mix.inputs[7])
        base_socket = mix.outputs[2]
    links.new(base_socket, bsdf.inputs["Base Color"])
    params = nodes.new("ShaderNodeCombineXYZ")
    params.inputs["X"].default_value = spec["roughness"]
    params.inputs["Y"].default_value = spec["metallic"]
    params.inputs["Z"].default_value = spec["transmission"]
    return mat, base_socket, params.outputs["Vector"]
