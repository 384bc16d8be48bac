"""Human bodies from the `anny` parametric model (MakeHuman topology, 104-bone rig).

The first `anny.Anny()` on a machine builds a large cache (about 40 s to
minutes, 790 MB) in $ANNY_CACHE_DIR, which defaults here to
~/.cache/relight/anny; later processes load it in about a second. One model
is kept per process, posed on one torch thread with anny's original phenotype
blendshapes, so that a seed gives the same vertex bytes whatever the worker
count or the cache build (docs/farm.md, "Determinism").
"""

from __future__ import annotations

import contextlib
import os
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

_MODEL = None


def anny_cache_dir() -> Path:
    return Path(os.environ.get("ANNY_CACHE_DIR") or Path.home() / ".cache" / "relight" / "anny")


def body_model():
    """The process-wide anny model (built on first use)."""
    global _MODEL
    if _MODEL is None:
        cache = anny_cache_dir()
        cache.mkdir(parents=True, exist_ok=True)
        os.environ["ANNY_CACHE_DIR"] = str(cache)
        import anny
        import anny.paths

        anny.paths.set_anny_cache_path(cache)
        # "original" blendshapes, not anny's default "compact" basis: the compact basis comes from
        # a factorisation whose result depends on the threads that built the cache, so two
        # machines (or two cache builds) posed the same seed into different vertex bytes
        with one_torch_thread():
            _MODEL = anny.Anny(phenotype_blendshapes="original")
    return _MODEL


@contextlib.contextmanager
def one_torch_thread():
    """torch on one thread inside, the caller's count restored after: anny's posing sums in
    another order on more threads, so `--workers 1` and `--workers 2` (one core each) gave the
    same seed different vertex bytes. One thread also keeps a pinned worker off its
    neighbours' cores. Posing costs about 0.02 s either way."""
    import torch

    before = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        yield
    finally:
        torch.set_num_threads(before)


@dataclass(frozen=True)
class BodyParams:
    """anny phenotype values, each in [0, 1] (age: 1/3 child, 2/3 young adult, 1 old)."""

    gender: float  # 0 male .. 1 female
    age: float
    muscle: float
    weight: float
    height: float
    proportions: float

    def as_dict(self) -> dict:
        return asdict(self)


def sample_body(rng: np.random.Generator) -> BodyParams:
    """Mostly adults, a wide spread of build."""
    age = rng.uniform(0.62, 1.0) if rng.random() < 0.9 else rng.uniform(0.4, 0.62)
    return BodyParams(
        gender=float(rng.uniform(0.0, 1.0)),
        age=float(age),
        muscle=float(np.clip(rng.normal(0.5, 0.2), 0.0, 1.0)),
        weight=float(np.clip(rng.normal(0.5, 0.22), 0.0, 1.0)),
        height=float(rng.uniform(0.0, 1.0)),
        proportions=float(rng.uniform(0.0, 1.0)),
    )


@dataclass
class Body:
    """A posed body, Z up, metres, feet on z = 0, facing -Y before the global turn."""

    vertices: np.ndarray  # [V, 3] float64 posed
    rest_vertices: np.ndarray  # [V, 3] float64 (texture space for patterns)
    faces: np.ndarray  # [F, 3] int64
    bone_labels: list[str]
    bone_weights: np.ndarray  # [V, B] dense skin weights
    joints: np.ndarray  # [B, 3] posed bone heads


def bone_weight_matrix(model) -> np.ndarray:
    """Dense [V, B] skin weights from anny's sparse (index, weight) pairs."""
    idx = model.vertex_bone_indices.cpu().numpy()
    w = model.vertex_bone_weights.cpu().numpy()
    dense = np.zeros((idx.shape[0], len(model.bone_labels)))
    rows = np.repeat(np.arange(idx.shape[0]), idx.shape[1])
    np.add.at(dense, (rows, idx.ravel()), w.ravel())
    return dense


def build_body(params: BodyParams, pose_deltas: np.ndarray | None) -> Body:
    """Run anny for a phenotype and per-bone 4x4 deltas [B, 4, 4] ('local-ref')."""
    import torch

    model = body_model()
    kwargs = {k: torch.tensor([v], dtype=model.dtype) for k, v in params.as_dict().items()}
    pose = None
    if pose_deltas is not None:
        pose = torch.as_tensor(np.asarray(pose_deltas)[None], dtype=model.dtype)
    with torch.no_grad(), one_torch_thread():
        out = model(pose_parameters=pose, phenotype_kwargs=kwargs)
    verts = out["vertices"][0].double().cpu().numpy()
    rest = out["rest_vertices"][0].double().cpu().numpy()
    joints = out["bone_poses"][0, :, :3, 3].double().cpu().numpy()
    if not np.all(np.isfinite(verts)):
        raise ValueError(f"anny produced non-finite vertices for {params}")
    floor = verts[:, 2].min()
    verts[:, 2] -= floor
    joints[:, 2] -= floor
    return Body(
        vertices=verts,
        rest_vertices=rest,
        faces=model.faces.cpu().numpy().astype(np.int64),
        bone_labels=list(model.bone_labels),
        bone_weights=bone_weight_matrix(model),
        joints=joints,
    )
