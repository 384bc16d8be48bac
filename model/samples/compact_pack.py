"""A compact training pack: a training pack's scenes coded lossily in a few tens of kB each, so that
thousands travel to a GPU machine whose carried files are capped at 64 MiB (issue 45).

`write_compact_pack(pack, out, quality, rank)` codes each scene of a model.samples.training_pack
pack (format 1, exact float16) into three image streams and a few floats:
- one greyscale JPEG (Pillow, 4:4:4) holding side by side every plane that tolerates a lossy code:
  the albedo (gamma 1/2.2), the normal and the body normal (octahedral, two planes each), the
  transport on the scene's own principal axes over the person (all 25 unless `rank` says fewer),
  coded with one step for every axis, and the traced images (log2 over their top 12 stops, so an
  error is a fraction of the value in shadow as in sun);
- one 8-bit PNG of the masks (alpha and body coverage): they decide what is person;
- one 16-bit PNG of the depth pass over the person's own depth range (0 off the person);
- float32: the lights (exact), the PCA's mean and basis, and each plane's code range;
and once per pack the bundled HDR presets' SH (the extra training lights), so that training from it
reads no EXR (a GPU machine has no OpenEXR).
The JPEG's tiles are the crop's size (128 for the release: a multiple of 8), so no 8 x 8 block
spans two planes.
`read_compact_pack(path)` decodes every scene to the CroppedScene the exact pack gives, within the
code's error (docs/model.md, "A compact training pack for a GPU machine", measures it and what
training on it costs). Every scene's bytes and the presets are checked against the manifest's
SHA-256 before they are used; nothing is pickled.
"""

from __future__ import annotations

import hashlib
import io
import json
import sys
import zipfile
from pathlib import Path

import numpy as np
from PIL import Image

from model.samples.data_augment import preset_training_lights
from model.samples.data_crops import CroppedScene
from model.samples.training_pack import COMPACT_FORMAT, TrainingPack, iter_training_pack, read_manifest
from relight.files.fileio import atomic_path

FORMAT = COMPACT_FORMAT
PASSES = ("depth", "body")  # the passes a run may leave out (model.train --depth-head, --body-prior)
LOG_STOPS = 12.0  # the traced images' code range below their brightest pixel
GAMMA = 2.2  # the albedo's code curve (reflectance is seen through a display curve)


def _sha256(b: bytes) -> str:
    return hashlib.sha256(b).hexdigest()



def octahedral(normal: np.ndarray) -> np.ndarray:
    """Unit normals [3, S, S] to the octahedral square [2, S, S] in [-1, 1] (0 where the normal is 0)."""
    n = normal / np.maximum(np.abs(normal).sum(axis=0, keepdims=True), 1e-12)
    x, y, z = n
    fold = z < 0
    fx = np.where(fold, (1 - np.abs(y)) * np.sign(x + (x == 0)), x)
    fy = np.where(fold, (1 - np.abs(x)) * np.sign(y + (y == 0)), y)
    return np.stack([fx, fy]).astype(np.float32)


def from_octahedral(code: np.ndarray) -> np.ndarray:
    """octahedral's inverse: [2, S, S] to unit normals [3, S, S]."""
    x, y = code.astype(np.float64)
    z = 1 - np.abs(x) - np.abs(y)
    shift = np.clip(-z, 0, None)
    x = x - shift * np.sign(x + (x == 0))
    y = y - shift * np.sign(y + (y == 0))
    n = np.stack([x, y, z])
    return (n / np.maximum(np.linalg.norm(n, axis=0, keepdims=True), 1e-12)).astype(np.float32)


def _to_u8(x: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return np.clip(np.rint((x - lo) / max(hi - lo, 1e-12) * 255.0), 0, 255).astype(np.uint8)


def _mask_u8(mask: np.ndarray) -> np.ndarray:
    """A mask in 8 bits that keeps its support: a faint edge (under half a code) codes 1, not 0,
    since what is person is decided by mask > 0."""
    return np.where(mask > 0, np.maximum(_to_u8(mask, 0.0, 1.0), 1), 0).astype(np.uint8)


def _from_u8(q: np.ndarray, lo: float, hi: float) -> np.ndarray:
    return (lo + q.astype(np.float32) / 255.0 * (hi - lo)).astype(np.float32)


def fill_outside(plane: np.ndarray, known: np.ndarray) -> np.ndarray:
    """`plane` [S, S] with the pixels outside `known` filled from the known ones by a masked
    pyramid (push-pull), so that a code's blocks see no step at the silhouette."""
    if known.all() or not known.any():
        return plane if known.all() else np.zeros_like(plane)
    h, w = plane.shape
    if h % 2 or w % 2:
        return np.where(known, plane, plane[known].mean())
    weight = known.astype(np.float64)
    sums = (plane * weight).reshape(h // 2, 2, w // 2, 2).sum(axis=(1, 3))
    counts = weight.reshape(h // 2, 2, w // 2, 2).sum(axis=(1, 3))
    coarse = fill_outside(sums / np.maximum(counts, 1), counts > 0)
    return np.where(known, plane, np.repeat(np.repeat(coarse, 2, axis=0), 2, axis=1)).astype(np.float32)


def _image_bytes(plane: np.ndarray, fmt: str, **options) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(plane).save(buf, fmt, **options)
    return buf.getvalue()


def _decode_image(data: bytes) -> np.ndarray:
    with Image.open(io.BytesIO(data)) as im:
        im.load()
        return np.asarray(im)


def _transport_pca(transport: np.ndarray, person: np.ndarray, rank: int):
    """The scene's transport [n, S, S] as mean [n], basis [n, r] and components [r, S, S] (0 off
    the person, where the transport is 0)."""
    x = transport[:, person].T.astype(np.float64)  # [P, n]
    mean = x.mean(axis=0)
    _, _, vt = np.linalg.svd(x - mean, full_matrices=False)
    basis = vt[:rank].T  # [n, r]
    comps = np.zeros((basis.shape[1],) + person.shape, np.float32)
    comps[:, person] = ((x - mean) @ basis).T
    return mean.astype(np.float32), basis.astype(np.float32), comps


def encode_scene(scene: CroppedScene, quality: int, rank: int = 25) -> tuple[bytes, np.ndarray, dict]:
    """One scene coded: its bytes (the three streams back to back), its floats, and the record
    (stream lengths, float layout) that decode_scene reads them with."""
    alpha = scene.alpha[0]
    person = alpha > 0
    if not person.any():
        raise ValueError(f"scene {scene.index}: empty alpha, nothing to code")
    maps = [scene.albedo, scene.normal, scene.transport, scene.alpha, *scene.lights] + [
        m for m in (*scene.images, scene.body, scene.depth) if m is not None]
    if not all(np.isfinite(m).all() for m in maps):
        raise ValueError(f"scene {scene.index}: NaN or infinite values in its maps or lights")
    planes, ranges, floats, layout = [], [], [], []

    def add_floats(name, a):
        a = np.asarray(a, np.float32)
        floats.append(a.ravel())
        layout.append([name, list(a.shape)])

    def add_plane(x, lo, hi, known=person):
        planes.append(_to_u8(x if known is None else fill_outside(x, known), lo, hi))
        ranges.append((lo, hi))

    add_floats("lights", np.stack(scene.lights))
    for a in np.clip(scene.albedo, 0, 1) ** (1 / GAMMA):
        add_plane(a, 0.0, 1.0)
    for a in octahedral(scene.normal):
        add_plane(a, -1.0, 1.0)
    mean, basis, comps = _transport_pca(scene.transport, person, rank)
    add_floats("transport_mean", mean)
    add_floats("transport_basis", basis)
    # one step for every component (transform coding's rule: the same error bought at the least
    # rate), so the faint, noisy high components take few codes
    step = max(float(np.abs(comps[:, person]).max()), 1e-12) / 127.0
    for c in comps:
        add_plane(c, -128.0 * step, 127.0 * step)
    for img in (i for i in scene.images if i is not None):
        top = float(np.log2(max(float(img.max()), 1e-12)))
        for c in np.log2(np.maximum(img, 2.0 ** (top - LOG_STOPS))):
            add_plane(c, top - LOG_STOPS, top, known=None)  # the world behind the person trains too
    masks = [alpha]
    if scene.body is not None:
        for a in octahedral(scene.body[:3]):
            add_plane(a, -1.0, 1.0, known=scene.body[3] > 0)
        masks.append(scene.body[3])
    add_floats("ranges", np.array(ranges, np.float32))
    streams = [_image_bytes(np.concatenate(planes, axis=1), "JPEG", quality=quality, subsampling=0,
                            optimize=True),
               _image_bytes(_mask_u8(np.concatenate(masks, axis=1)), "PNG", optimize=True)]
    if scene.depth is not None:
        depth = scene.depth[0]
        near, far = float(depth[person].min()), float(depth[person].max())
        code = np.where(person, 1 + np.rint((depth - near) / max(far - near, 1e-12) * 65534), 0)
        streams.append(_image_bytes(code.astype(np.uint16), "PNG", optimize=True))
        add_floats("depth_range", [near, far])
    record = {"streams": [len(s) for s in streams], "floats": layout, "rank": int(basis.shape[1])}
    return b"".join(streams), np.concatenate(floats), record


def decode_scene(blob: bytes, floats: np.ndarray, rec: dict) -> CroppedScene:
    """encode_scene's inverse, float32 as the exact pack gives (within the code's error)."""
    streams, start = [], 0
    for n in rec["streams"]:
        streams.append(blob[start:start + n])
        start += n
    values, k = {}, 0
    for name, shape in rec["floats"]:
        size = int(np.prod(shape))
        values[name] = floats[k:k + size].reshape(shape)
        k += size
    tiles = _decode_image(streams[0])
    side = tiles.shape[0]
    ranges = values["ranges"]
    planes = [_from_u8(tiles[:, j * side:(j + 1) * side], *ranges[j]) for j in range(len(ranges))]
    masks = _decode_image(streams[1]).astype(np.float32) / 255.0
    alpha = masks[:, :side]
    person = alpha > 0
    on = person[None].astype(np.float32)
    albedo = np.stack(planes[0:3]) ** GAMMA * on
    normal = from_octahedral(np.stack(planes[3:5])) * on
    j = 5 + rec["rank"]
    comps = np.stack(planes[5:j])
    transport = (values["transport_mean"][:, None, None]
                 + np.einsum("nr,rhw->nhw", values["transport_basis"], comps)) * on
    images = []
    for traced in rec["traced"]:
        if traced:
            # code 0 is everything 12 stops or more below the brightest pixel: black
            code = np.stack([tiles[:, c * side:(c + 1) * side] for c in range(j, j + 3)])
            images.append(np.where(code == 0, 0.0, 2.0 ** np.stack(planes[j:j + 3])).astype(np.float32))
            j += 3
        else:
            images.append(None)
    body = None
    if rec.get("body"):
        coverage = masks[:, side:2 * side]
        body = np.concatenate([from_octahedral(np.stack(planes[j:j + 2])) * (coverage > 0)[None],
                               coverage[None]]).astype(np.float32)
    depth = None
    if len(streams) > 2:
        near, far = values["depth_range"]
        code = _decode_image(streams[2]).astype(np.float64)
        depth = np.where(code > 0, near + (code - 1) / 65534 * (far - near), 0.0)[None].astype(np.float32)
    return CroppedScene(index=rec["index"], alpha=alpha[None].astype(np.float32), albedo=albedo.astype(np.float32),
                        transport=transport.astype(np.float32), normal=normal, images=images,
                        lights=list(values["lights"]), light_names=rec["names"], held_out=rec["held_out"],
                        body=body, depth=depth)


def write_compact_pack(pack, out, quality: int = 90, rank: int = 25, max_scenes: int | None = None,
                       without: tuple[str, ...] = (), first: int = 0) -> Path:
    """The exact pack `pack`'s scenes from `first` on (`max_scenes` of them, all without it) coded
    into `out`, read one at a time; `without` names passes to leave out (PASSES). Returns out."""
    if not 1 <= quality <= 95:
        raise ValueError(f"JPEG quality must be 1-95, got {quality}")
    if unknown := set(without) - set(PASSES):
        raise ValueError(f"unknown pass {sorted(unknown)}: one of {', '.join(PASSES)}")
    manifest = dict(read_manifest(pack))
    arrays, scenes = {}, []
    for i, (scene, rec) in enumerate(iter_training_pack(pack, max_scenes, first)):
        if "depth" in without:
            scene.depth = None
        if "body" in without:
            scene.body = None
        try:
            blob, floats, coded = encode_scene(scene, quality, rank)
        except ValueError as exc:
            raise ValueError(f"{pack}: {rec['name']}: {exc}") from None
        arrays[f"b{i}"], arrays[f"f{i}"] = np.frombuffer(blob, np.uint8), floats
        kept = {k: v for k, v in rec.items() if not k.endswith("_sha256") or k == "exr_sha256"}
        scenes.append({**kept, **coded, "depth": scene.depth is not None, "body": scene.body is not None,
                       "blob_sha256": _sha256(blob), "floats_sha256": _sha256(floats.tobytes())})
    if not scenes:
        raise ValueError(f"{pack}: no scene to code")
    # the bundled maps' SH, the extra training lights: a GPU machine without OpenEXR reads no map
    presets = preset_training_lights(manifest["order"])
    arrays["presets"] = np.stack([sh for _, sh in presets]).astype(np.float32)
    manifest.update(format=FORMAT, scenes=scenes, presets=[name for name, _ in presets],
                    presets_sha256=_sha256(arrays["presets"].tobytes()), coding={"quality": quality, "rank": rank,
                                                         "without": sorted(without), "from": Path(pack).name,
                                                         "first": first})
    arrays["manifest"] = np.frombuffer(json.dumps(manifest, sort_keys=True).encode(), dtype=np.uint8)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, ".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)  # stored, not deflated: the streams are coded already
    return out


def read_compact_pack(path, max_scenes: int | None = None) -> TrainingPack:
    """The compact pack at `path` (its first `max_scenes` scenes when given), each scene's bytes
    checked against its SHA-256, then decoded."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            manifest = json.loads(bytes(z["manifest"]).decode())
            if manifest.get("format") != FORMAT:
                raise ValueError(f"unknown format {manifest.get('format')!r} (expected {FORMAT})")
            scenes = []
            for i, rec in enumerate(manifest["scenes"][:max_scenes]):
                blob, floats = z[f"b{i}"].tobytes(), z[f"f{i}"]
                if _sha256(blob) != rec["blob_sha256"] or _sha256(floats.tobytes()) != rec["floats_sha256"]:
                    raise ValueError(f"scene {rec['name']}: its bytes do not match the manifest's SHA-256")
                scenes.append(decode_scene(blob, floats, rec))
            if _sha256(z["presets"].tobytes()) != manifest["presets_sha256"]:
                raise ValueError("its preset lights do not match the manifest's SHA-256")
            presets = list(zip(manifest["presets"], z["presets"]))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile) as exc:
        raise ValueError(f"{path}: not a readable compact training pack ({exc})") from None
    return TrainingPack(path, manifest, scenes, presets)


def main(argv=None) -> int:
    import argparse

    p = argparse.ArgumentParser(prog="python -m model.samples.compact_pack",
                                description="Code an exact training pack into a compact one (lossy JPEG/PNG "
                                            "streams) that a GPU machine carries; model.train --from-pack reads it.")
    p.add_argument("pack", help="an exact training pack (model.campaign's pack.npz)")
    p.add_argument("out", help="the compact pack to write (.npz)")
    p.add_argument("--quality", type=int, default=90, help="JPEG quality of the lossy planes, 1-95 (default 90)")
    p.add_argument("--first", type=int, default=0, metavar="K",
                   help="start at the pack's scene K (0-based): a part of a pack too large to carry at once")
    p.add_argument("--max-scenes", type=int, default=None, metavar="N", help="N scenes only")
    p.add_argument("--without", nargs="+", default=[], choices=PASSES,
                   help="leave these passes out (a run without --depth-head / --body-prior needs neither)")
    args = p.parse_args(argv)
    if args.max_scenes is not None and args.max_scenes < 1:
        p.error("--max-scenes must be >= 1")
    if args.first < 0:
        p.error("--first must be >= 0")
    try:
        out = write_compact_pack(args.pack, args.out, args.quality, max_scenes=args.max_scenes,
                                 without=tuple(args.without), first=args.first)
    except ValueError as exc:
        print(f"model.samples.compact_pack: {exc}", file=sys.stderr)
        return 1
    n = len(read_manifest(out)["scenes"])
    size = out.stat().st_size
    print(f"{out}: {n} scenes, {size / 2**20:.1f} MiB ({size / n / 1024:.1f} kB per scene)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
