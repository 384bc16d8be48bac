"""Small numpy mesh helpers shared by the clothing, hair and appearance modules, the bake and the body pass."""

from __future__ import annotations

import math

import numpy as np


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


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals; isolated vertices get +Z."""
    v = np.asarray(vertices, dtype=np.float64)
    f = np.asarray(faces, dtype=np.int64)
    face_n = np.cross(v[f[:, 1]] - v[f[:, 0]], v[f[:, 2]] - v[f[:, 0]])
    n = np.zeros_like(v)
    for k in range(3):
        np.add.at(n, f[:, k], face_n)
    length = np.linalg.norm(n, axis=1, keepdims=True)
    out = np.where(length > 1e-20, n / np.maximum(length, 1e-20), np.array([0.0, 0.0, 1.0]))
    return out
