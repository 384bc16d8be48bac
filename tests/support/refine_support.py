"""The synthetic scene the refinement tests share (tests/relight/network/test_refine.py, tests/relight/network/test_level.py,
tests/relight/network/test_one_decomposition.py): a two-albedo Lambertian sphere under a smooth coloured lobe,
whose transport is exact and whose light estimate is given."""

from __future__ import annotations

import dataclasses

import numpy as np

from relight.network import refine as rf
from relight.lighting import sh
from relight.network.decomposition import Decomposition

ORDER = 4
SIZE = 64


def sphere(size: int = SIZE):
    """Normals [s, s, 3] and disk [s, s] of a sphere seen by the photo camera (looking along
    +Y, X right, Z up: image rows go down -Z)."""
    v, u = np.meshgrid(np.linspace(1, -1, size), np.linspace(-1, 1, size), indexing="ij")
    r2 = u * u + v * v
    disk = r2 < 0.95
    normal = np.stack([u, -np.sqrt(np.clip(1 - r2, 0, 1)), v], axis=-1)
    return normal, disk


def lambertian_transport(normal: np.ndarray, order: int = ORDER) -> np.ndarray:
    lobe = sh.clamped_cosine_coeffs(order) / np.pi
    per_coeff = np.concatenate([np.full(2 * l + 1, lobe[l]) for l in range(order + 1)])
    return (sh.sh_basis(normal, order) * per_coeff).astype(np.float32)


def lobe_light(direction, colour, ambient, order: int = ORDER) -> np.ndarray:
    """SH of a smooth coloured lobe toward `direction` plus a grey ambient term [n, 3]."""
    d = np.asarray(direction, np.float64)
    d = d / np.linalg.norm(d)
    light = np.outer(sh.sh_basis(d, order) * np.repeat(np.exp(-0.3 * np.arange(order + 1) ** 2),
                                                        2 * np.arange(order + 1) + 1), colour) * 3.0
    light[0] += ambient
    return light


def synthetic(light_true, light_start):
    """A decomposition of a two-albedo sphere lit by light_true, whose transport is right and
    whose light estimate is light_start (the network's situation, with exact geometry)."""
    normal, disk = sphere()
    transport = lambertian_transport(normal) * disk[..., None]
    albedo = np.where(np.arange(SIZE)[None, :, None] < SIZE // 2, [0.6, 0.45, 0.35], [0.25, 0.3, 0.5])
    albedo = np.broadcast_to(albedo, (SIZE, SIZE, 3)).astype(np.float32)
    photo = (albedo * np.maximum(transport @ light_true, 0.0) * disk[..., None]).astype(np.float32)
    alpha = disk.astype(np.float32)
    d = Decomposition(albedo=albedo, transport=transport, residual=np.zeros_like(transport),
                      light=light_start.astype(np.float32), alpha=alpha, box=(0, SIZE, 0, SIZE),
                      working_size=(SIZE, SIZE), photo=photo, photo_working=photo, sh_order=ORDER,
                      network_alpha=alpha)
    d = dataclasses.replace(d, albedo=rf.consistent_albedo(d, transport, light_start.astype(np.float32)))
    return d, albedo, transport, disk
