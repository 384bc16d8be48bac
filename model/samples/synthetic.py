"""A tiny analytic dataset in the farm's scene format, for tests and benchmarks.

Each scene is a "person" made of two unoccluded spheres (head over torso) seen
by the photo camera (looking along +Y, Z up): exact normals, a striped
albedo, Lambert transport from relight.network.prt.lambert_transport, and "path-traced"
images albedo * (T . L) + 0.05 * (T . L) (a grey gloss the residual E can
learn) over a flat background of the light's mean radiance. Lights are
bundled presets scaled to reference radiance 0.8. Not a substitute for the
farm's renders: it exercises the code paths with known answers.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np

from relight.lighting import sh as sh_np
from relight.files.dataset import scene_stem, write_scene
from relight.lighting.light import sh_light
from relight.network.prt import lambert_transport, shading

GLOSS = 0.05  # the residual the analytic "path tracer" adds: E = GLOSS * T
SUPERSAMPLE = 4  # alpha is exact coverage, estimated on a 4x4 sub-grid


def _spheres(size: int, rng: np.random.Generator):
    """Coverage [H, W], unit normals [H, W, 3] of a head + torso pair of spheres."""
    head = (rng.uniform(-0.1, 0.1), rng.uniform(0.45, 0.55), rng.uniform(0.18, 0.24))
    torso = (rng.uniform(-0.1, 0.1), rng.uniform(-0.3, -0.1), rng.uniform(0.35, 0.45))
    s = size * SUPERSAMPLE
    coords = (np.arange(s) + 0.5) / s * 2.0 - 1.0  # [-1, 1], x to the right
    x = coords[None, :].repeat(s, 0)
    z = -coords[:, None].repeat(s, 1)  # image row 0 is the top: z up
    normal = np.zeros((s, s, 3))
    hit = np.zeros((s, s), dtype=bool)
    depth = np.full((s, s), np.inf)
    for cx, cz, r in (torso, head):
        u, v = (x - cx) / r, (z - cz) / r
        inside = u * u + v * v < 1.0
        front = -np.sqrt(np.clip(1.0 - u * u - v * v, 0.0, None))  # normal faces the camera (-Y)
        dist = 3.0 + front * r  # nearer surface point
        take = inside & (dist < depth)
        depth[take] = dist[take]
        normal[take] = np.stack([u, front, v], axis=-1)[take]
        hit |= inside
    blocks = lambda a: a.reshape(size, SUPERSAMPLE, size, SUPERSAMPLE, *a.shape[2:]).mean(axis=(1, 3))
    coverage = blocks(hit.astype(np.float64))
    n = blocks(normal)
    norm = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(norm > 0, n / np.maximum(norm, 1e-12), 0.0)
    return coverage, n, blocks(np.where(hit, depth, 0.0))


def write_analytic_dataset(folder, n_scenes: int = 4, size: int = 32, order: int = 4,
                           lights: tuple[str, ...] = ("studio", "city", "venice"), seed: int = 0,
                           light_cache: dict | None = None, body: bool = False) -> list[Path]:
    """Write scene_000000.. to `folder`; returns the JSON paths. One body per scene. With
    `body`, the farm's body pass too: the spheres themselves (nothing is worn over them)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    cache = {} if light_cache is None else light_cache
    for name in lights:
        if name not in cache:
            cache[name] = sh_light(name, max(order, 8))
    n = sh_np.num_coeffs(order)
    paths = []
    for index in range(n_scenes):
        rng = np.random.default_rng([seed, index])
        alpha, normal, depth = _spheres(size, rng)
        person = alpha > 0
        base = rng.uniform(0.15, 0.85, 3)
        stripes = 0.5 + 0.5 * (np.sin(np.arange(size) / size * rng.uniform(6, 14) * math.pi) > 0)
        albedo = base[None, None, :] * (0.6 + 0.4 * stripes[:, None, None]) * person[..., None]
        transport = lambert_transport(np.where(person[..., None], normal, [0.0, -1.0, 0.0]), order)
        transport = transport * alpha[..., None]
        light_meta, channels = [], {}
        for k, name in enumerate(lights):
            sh_full = cache[name]
            L = sh_full[:n]
            s = shading(transport, L)
            radiance = albedo * s + GLOSS * s
            background = sh_full[0] / (2.0 * math.sqrt(math.pi))  # mean radiance of the map
            channels[f"image.L{k}"] = (radiance + (1.0 - alpha[..., None]) * background).astype(np.float32)
            channels[f"shading.L{k}"] = s.astype(np.float32)
            channels[f"prt.L{k}"] = (albedo * s).astype(np.float32)
            light_meta.append({"name": name, "source": f"{name}.exr", "rotation_deg": 0.0, "scale": 1.0,
                               "sh": L, "sh8": sh_full[:81]})
        channels.update(
            alpha=alpha.astype(np.float32), albedo=albedo.astype(np.float32),
            normal=(normal * person[..., None]).astype(np.float32),
            material=np.zeros((size, size, 3), np.float32), depth=depth.astype(np.float32),
            transport=transport.astype(np.float32),
        )
        if body:
            channels.update(body_normal=(normal * person[..., None]).astype(np.float32),
                            body_alpha=alpha.astype(np.float32), body_depth=depth.astype(np.float32))
        meta = {"index": index, "seed": seed, "sh_order": order, "lights": light_meta,
                "body": {"id": f"analytic-{seed}-{index}"}, "camera": {"kind": "analytic"},
                "passes": {"asked": ["geometry", "transport", "image"], "skipped": []}}
        _, json_path = write_scene(scene_stem(folder, index), channels, meta)
        paths.append(json_path)
    return paths
