"""A training pack: the scenes a run trains on, cropped at the training size, in one compressed file
that trains without the farm, its scene files or Blender (a GPU machine carries it; issue 45).

`write_training_pack(json_paths, out, size, order, ...)` crops every scene once
(model.samples.data_crops: float16 maps, float32 lights) and writes them with np.savez_compressed,
atomically, beside a manifest (JSON): the crop settings, where the scenes came from (the farm's
seed and settings, given by the caller), and per scene its name, index, the SHA-256 of its EXR, its
body key (the body split, model.samples.data_splits.split_by_key) and the SHA-256 of each of its
packed arrays. `read_training_pack(path)` checks the format and every array's hash and returns the
scenes as they were packed, bit for bit; a damaged or foreign file raises ValueError naming it.
Nothing in it is pickled (np.load with allow_pickle=False).
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from model.samples.data_crops import DEFAULT_PADDING, CroppedScene, load_cropped, scene_arrays, scene_from_arrays
from model.samples.data_splits import body_key, held_out_light_names
from relight.files.dataset import read_sidecar
from relight.files.fileio import atomic_path

FORMAT = "relight-training-pack/1"
COMPACT_FORMAT = "relight-training-pack-compact/1"  # model.samples.compact_pack's lossy coding


def _sha256(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


def write_training_pack(json_paths, out, size: int, order: int, padding: int = DEFAULT_PADDING,
                        source: dict | None = None, held_out: frozenset[str] | None = None) -> Path:
    """Crop `json_paths`' scenes into the pack `out` (.npz); returns its path. `source` (JSON-able)
    says where the scenes came from (the campaign records the farm's seed and settings there)."""
    held_out = held_out_light_names() if held_out is None else held_out
    arrays: dict[str, np.ndarray] = {}
    scenes = []
    for i, path in enumerate(json_paths):
        path = Path(path)
        meta = read_sidecar(path)
        maps, lights, record, depth = scene_arrays(load_cropped(path, size, order, padding, held_out,
                                                               verify_hash=True))
        arrays[f"s{i}"], arrays[f"l{i}"] = maps, lights
        if depth is not None:  # the depth pass (issue 45's depth head), float32
            arrays[f"d{i}"] = depth
            record["depth_sha256"] = _sha256(depth)
        scenes.append({**record, "name": path.stem, "exr_sha256": meta["exr_sha256"], "body_key": body_key(meta),
                       "maps_sha256": _sha256(maps), "lights_sha256": _sha256(lights)})
    if not scenes:
        raise ValueError("a training pack needs at least one scene")
    manifest = {"format": FORMAT, "size": size, "order": order, "padding": padding,
                "held_out": sorted(held_out), "source": source or {}, "scenes": scenes}
    arrays["manifest"] = np.frombuffer(json.dumps(manifest, sort_keys=True).encode(), dtype=np.uint8)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, ".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, **arrays)
    return out


@dataclass
class TrainingPack:
    """A pack read back: its manifest and its scenes (CroppedScene, float32 as the loader gives;
    the manifest's first len(scenes) records when it was read in part)."""

    path: Path
    manifest: dict
    scenes: list[CroppedScene]
    presets: list[tuple[str, np.ndarray]] | None = None  # the bundled maps' SH, when the pack carries them

    @property
    def size(self) -> int:
        return int(self.manifest["size"])

    @property
    def order(self) -> int:
        return int(self.manifest["order"])

    @property
    def body_keys(self) -> list[str]:
        return [s["body_key"] for s in self.manifest["scenes"][:len(self.scenes)]]

    @property
    def names(self) -> list[str]:
        return [s["name"] for s in self.manifest["scenes"][:len(self.scenes)]]


def read_manifest(path) -> dict:
    """The pack's manifest alone (its arrays are not read or checked)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            return _manifest(z, path)
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable training pack ({exc})") from None


def _manifest(z, path: Path) -> dict:
    manifest = json.loads(bytes(z["manifest"]).decode())
    if manifest.get("format") not in (FORMAT, COMPACT_FORMAT):
        raise ValueError(f"unknown format {manifest.get('format')!r} (expected {FORMAT} or {COMPACT_FORMAT})")
    return manifest


def read_training_pack(path, max_scenes: int | None = None) -> TrainingPack:
    """The exact pack at `path` (its first `max_scenes` scenes only, when given), every array
    checked against its recorded SHA-256 (model.samples.packs reads compact ones and parts too)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"training pack not found: {path}")
    with _exact_pack(path) as (z, manifest):
        scenes = [scene for scene, _ in _checked_scenes(z, manifest, max_scenes, 0)]
    return TrainingPack(path, manifest, scenes)


def iter_training_pack(path, max_scenes: int | None = None, first: int = 0):
    """(CroppedScene, its manifest record) of an exact pack, one at a time and checked as read,
    from scene `first` on: a pack larger than memory (the campaign's 5,000 scenes are 14 GB as
    float32) streams."""
    with _exact_pack(Path(path)) as (z, manifest):
        yield from _checked_scenes(z, manifest, max_scenes, first)


@contextmanager
def _exact_pack(path: Path):
    """The open exact pack and its manifest, read once; any failure inside is one ValueError naming it."""
    try:
        with np.load(path, allow_pickle=False) as z:
            manifest = _manifest(z, path)
            if manifest["format"] != FORMAT:
                raise ValueError(f"a {manifest['format']} pack, not an exact one ({FORMAT})")
            yield z, manifest
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable training pack ({exc})") from None


def _checked_scenes(z, manifest: dict, max_scenes: int | None, first: int):
    last = None if max_scenes is None else first + max_scenes
    for i, rec in enumerate(manifest["scenes"][first:last], start=first):
        maps, lights = z[f"s{i}"], z[f"l{i}"]
        depth = z[f"d{i}"] if rec.get("depth") else None  # packs from before it have none
        if _sha256(maps) != rec["maps_sha256"] or _sha256(lights) != rec["lights_sha256"] or (
                depth is not None and _sha256(depth) != rec.get("depth_sha256")):
            raise ValueError(f"scene {rec['name']}: its arrays do not match the manifest's SHA-256")
        yield scene_from_arrays(maps, lights, rec, manifest["order"], depth), rec


class PackScenes:
    """A pack's scenes, called as model.samples.data_crops.SceneCache is (TrainingScenes' cache)."""

    def __init__(self, scenes: list[CroppedScene], names: list[str]):
        self.items, self.paths = list(scenes), list(names)

    def __call__(self, i: int) -> CroppedScene:
        return self.items[i]
