"""Scenes cropped for the network: a square around the person's mask bounding box (+ padding,
zero-extended past the borders) resized to the training size, channels first; a small LRU
cache of them, and packs (every scene cropped once into one .npz, read into memory)."""

from __future__ import annotations

import json
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from model.samples.data_splits import held_out_light_names, is_held_out, light_name
from relight.lighting import sh as sh_np
from relight.imaging.box import Box
from relight.files.dataset import read_scene, read_sidecar

DEFAULT_PADDING = 20  # pixels around the mask bbox, as in the paper


def crop_box(alpha: np.ndarray, padding: int) -> Box:
    """A square around the mask's box plus padding, centred on it (may leave the image): a
    relight.imaging.box.Box, rows then columns."""
    found = Box.around(alpha, 0.0)
    if found is None:
        raise ValueError("scene has an empty alpha mask: no person to crop")
    top, bottom = found.y0 - padding, found.y1 + padding
    left, right = found.x0 - padding, found.x1 + padding
    side = max(bottom - top, right - left)
    top -= (side - (bottom - top)) // 2
    left -= (side - (right - left)) // 2
    return Box(top, top + side, left, left + side)


def crop_resize(planes: np.ndarray, box: Box, size: int) -> np.ndarray:
    """Crop [H, W, C] to the square `box` (zeros outside the image), resize to [C, size, size]."""
    side = box.height
    if box.width != side:
        raise ValueError(f"crop box must be square, got {box.height} x {box.width}")
    h, w, c = planes.shape
    out = np.zeros((side, side, c), dtype=np.float32)
    y0, x0 = max(box.y0, 0), max(box.x0, 0)
    y1, x1 = min(box.y1, h), min(box.x1, w)
    out[y0 - box.y0:y1 - box.y0, x0 - box.x0:x1 - box.x0] = planes[y0:y1, x0:x1]
    t = torch.from_numpy(out).permute(2, 0, 1)[None]
    if side != size:
        # antialiased bilinear keeps thin structures when shrinking; linear in the values,
        # so T, albedo and images stay consistent (T.L of resized T = resized T.L)
        t = F.interpolate(t, size=(size, size), mode="bilinear", align_corners=False,
                          antialias=side > size)
    return t[0].contiguous().numpy()


@dataclass
class CroppedScene:
    """A scene cropped and resized to the training size, channels first."""

    index: int
    alpha: np.ndarray  # [1, S, S]
    albedo: np.ndarray  # [3, S, S]
    transport: np.ndarray  # [n, S, S]  (truncated to the model's order)
    normal: np.ndarray  # [3, S, S] unit on the person (camera frame), 0 outside
    images: list[np.ndarray | None]  # per light: path-traced [3, S, S] or None
    lights: list[np.ndarray]  # per light: [n, 3] (camera frame)
    light_names: list[str]
    held_out: list[bool]
    body: np.ndarray | None = None  # [4, S, S]: the unclothed body's unit normal and coverage (farm body pass)
    depth: np.ndarray | None = None  # [1, S, S]: the depth pass (metres along the view axis), 0 off the person


def load_cropped(json_path: Path, size: int, order: int, padding: int,
                 held_out: frozenset[str], verify_hash: bool = False) -> CroppedScene:
    scene = read_scene(json_path, verify_hash=verify_hash)
    if scene.transport is None:
        raise ValueError(f"{json_path.name}: scene has no transport pass (needed for training)")
    if scene.sh_order < order:
        raise ValueError(f"{json_path.name}: scene SH order {scene.sh_order} < model order {order}")
    n = sh_np.num_coeffs(order)
    box = crop_box(scene.alpha[..., 0], padding)  # padding in the scene's own pixels
    stacked = [scene.alpha, scene.albedo, scene.transport[..., :n], scene.normal]
    widths = [1, 3, n, 3]
    if scene.body_normal is not None:
        stacked += [scene.body_normal, scene.body_alpha]
        widths += [3, 1]
    has_depth = scene.depth is not None
    if has_depth:  # premultiplied by alpha: divided by the resized alpha below, edges mix no zeros in
        stacked.append(scene.depth * scene.alpha)
        widths.append(1)
    if scene.images is not None:
        stacked += list(scene.images)
        widths += [3] * len(scene.images)
    planes = crop_resize(np.concatenate(stacked, axis=-1), box, size)
    k = 0
    parts = []
    for width in widths:
        parts.append(planes[k:k + width])
        k += width
    body = None
    if scene.body_normal is not None:
        body = np.concatenate([unit_normals(parts[4]), np.clip(parts[5], 0.0, 1.0)])
        parts = parts[:4] + parts[6:]
    depth = None
    if has_depth:
        depth = np.where(parts[0] > 1e-3, parts[4] / np.maximum(parts[0], 1e-3), 0.0).astype(np.float32)
        parts = parts[:4] + parts[5:]
    n_lights = len(scene.lights)
    images = parts[4:] if scene.images is not None else [None] * n_lights
    normal = unit_normals(parts[3])
    return CroppedScene(
        index=scene.index,
        alpha=np.clip(parts[0], 0.0, 1.0),
        albedo=np.clip(parts[1], 0.0, 1.0),
        transport=parts[2],
        normal=normal,
        images=list(images),
        lights=[np.asarray(l["sh"][:n], dtype=np.float32) for l in scene.lights],
        light_names=[light_name(l) for l in scene.lights],
        held_out=[is_held_out(l, held_out) for l in scene.lights],
        body=body,
        depth=depth,
    )


def unit_normals(normal: np.ndarray) -> np.ndarray:
    """[3, S, S] normals renormalized after resampling (which shortens them across edges), 0 where
    there was none."""
    length = np.sqrt((normal * normal).sum(axis=0, keepdims=True))
    return np.where(length > 1e-6, normal / np.maximum(length, 1e-6), 0.0).astype(np.float32)


class SceneCache:
    """CroppedScene i of `paths`, loaded on demand; the `capacity` most recently used are kept."""

    def __init__(self, paths: list[Path], loader, capacity: int):
        self.paths, self.loader, self.capacity = paths, loader, capacity
        self.items: OrderedDict[int, CroppedScene] = OrderedDict()

    def __call__(self, i: int) -> CroppedScene:
        if i in self.items:
            self.items.move_to_end(i)
            return self.items[i]
        scene = self.loader(self.paths[i])
        self.items[i] = scene
        if len(self.items) > self.capacity:
            self.items.popitem(last=False)
        return scene


PACK_FORMAT = "relight-pack/2"  # 2: light names are the maps' (relight.files.dataset.light_map_name)


def _pack_key(json_paths: list[Path], size: int, order: int, padding: int) -> dict:
    """What a pack was made from: scene files (by their EXR's SHA-256) and crop settings."""
    scenes = []
    for p in json_paths:
        scenes.append([Path(p).name, read_sidecar(p)["exr_sha256"]])
    return {"format": PACK_FORMAT, "size": size, "order": order, "padding": padding, "scenes": scenes}


def pack_scenes(json_paths: list[Path], out, size: int, order: int, padding: int = DEFAULT_PADDING,
                held_out: frozenset[str] | None = None) -> Path:
    """Crop every scene once and write them to one .npz (float16 maps), atomically.

    Training then reads one file instead of decoding an EXR per scene: the
    EXR decode and crop cost more than a CPU training step.
    """
    from relight.files.fileio import atomic_path

    held_out = held_out_light_names() if held_out is None else held_out
    arrays: dict[str, np.ndarray] = {}
    records = []
    for i, path in enumerate(json_paths):
        arrays[f"s{i}"], arrays[f"l{i}"], record, depth = scene_arrays(
            load_cropped(Path(path), size, order, padding, held_out))
        if depth is not None:
            arrays[f"d{i}"] = depth
        records.append(record)
    key = _pack_key(list(json_paths), size, order, padding)
    arrays["meta"] = np.frombuffer(json.dumps({"key": key, "scenes": records}).encode(), dtype=np.uint8)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, ".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return out


def scene_arrays(c: CroppedScene) -> tuple[np.ndarray, np.ndarray, dict, np.ndarray | None]:
    """A cropped scene as a pack holds it: its maps stacked as float16 [C, S, S] (alpha, albedo,
    transport, normal, the traced images, the body prior), its lights float32 [K, n, 3], and the
    record that scene_from_arrays reads them back with. The depth pass, when the scene has it, goes
    in a separate float32 array (None without one): float16 would keep 2-4 mm of a person 2-5 m
    away, a tenth of a nose's relief."""
    maps = [c.alpha, c.albedo, c.transport, c.normal] + [img for img in c.images if img is not None]
    if c.body is not None:
        maps.append(c.body)
    record = {"index": c.index, "names": c.light_names, "held_out": c.held_out,
              "traced": [img is not None for img in c.images], "body": c.body is not None}
    depth = None
    if c.depth is not None:
        record["depth"] = True  # absent in packs from before the depth head: they read as before
        depth = np.asarray(c.depth, np.float32)
    return np.concatenate(maps, axis=0).astype(np.float16), np.stack(c.lights).astype(np.float32), record, depth


def scene_from_arrays(packed: np.ndarray, lights: np.ndarray, rec: dict, order: int,
                      depth: np.ndarray | None = None) -> CroppedScene:
    """scene_arrays' inverse, in float32 (the body prior's normals made unit again)."""
    maps = packed.astype(np.float32)
    n = sh_np.num_coeffs(order)
    k = 1 + 3 + n + 3
    images, j = [], k
    for traced in rec["traced"]:
        images.append(maps[j:j + 3] if traced else None)
        j += 3 if traced else 0
    body = unit_normals_and_coverage(maps[j:j + 4]) if rec.get("body") else None
    return CroppedScene(index=rec["index"], alpha=maps[0:1], albedo=maps[1:4], transport=maps[4:4 + n],
                        normal=maps[4 + n:k], images=images, lights=list(lights), light_names=rec["names"],
                        held_out=rec["held_out"], body=body,
                        depth=None if depth is None else np.asarray(depth, np.float32))


class PackedScenes:
    """CroppedScene i of a pack (pack_scenes), all held in memory; called as SceneCache is."""

    def __init__(self, path, json_paths: list[Path], size: int, order: int, padding: int = DEFAULT_PADDING):
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            if meta["key"] != _pack_key(list(json_paths), size, order, padding):
                raise ValueError(f"{path}: the pack was made from other scenes or crop settings")
            self.items = [scene_from_arrays(z[f"s{i}"], z[f"l{i}"], rec, order, z[f"d{i}"] if rec.get("depth") else None)
                          for i, rec in enumerate(meta["scenes"])]
        self.paths = list(json_paths)

    def __call__(self, i: int) -> CroppedScene:
        return self.items[i]


def unit_normals_and_coverage(body: np.ndarray) -> np.ndarray:
    """A packed [4, S, S] body prior after float16: normals unit again, coverage in [0, 1]."""
    return np.concatenate([unit_normals(body[:3]), np.clip(body[3:4], 0.0, 1.0)])
