"""Any training pack read for training: exact (model.samples.training_pack) or compact
(model.samples.compact_pack), one file or several parts read as one."""

from __future__ import annotations

from pathlib import Path

from model.samples.compact_pack import read_compact_pack
from model.samples.training_pack import COMPACT_FORMAT, TrainingPack, read_manifest, read_training_pack


def read_any_pack(path, max_scenes: int | None = None) -> TrainingPack:
    """The pack at `path`, exact or compact by its manifest's format."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"training pack not found: {path}")
    if read_manifest(path)["format"] == COMPACT_FORMAT:
        return read_compact_pack(path, max_scenes)
    return read_training_pack(path, max_scenes)


def read_training_packs(paths, max_scenes: int | None = None) -> TrainingPack:
    """Several packs read as one, their scenes one after another (the first `max_scenes` in all):
    a pack too large to carry in one piece travels in parts (compact_pack --first). They must
    share the crop size, the SH order and the held-out maps; the first names the whole."""
    paths = [Path(p) for p in paths]
    packs = []
    for path in paths:
        left = None if max_scenes is None else max_scenes - sum(len(p.scenes) for p in packs)
        if left is not None and left <= 0:
            break
        pack = read_any_pack(path, left)
        if packs and [pack.manifest[k] for k in ("size", "order", "held_out")] != [
                packs[0].manifest[k] for k in ("size", "order", "held_out")]:
            raise ValueError(f"{path}: packed at another size, order or held-out maps than {paths[0]}")
        packs.append(pack)
    if len(packs) == 1:
        return packs[0]
    manifest = {**packs[0].manifest, "scenes": [rec for p in packs for rec in p.manifest["scenes"][:len(p.scenes)]],
                "parts": [str(p.path) for p in packs]}
    return TrainingPack(paths[0], manifest, [s for p in packs for s in p.scenes], packs[0].presets)
