"""Training and evaluation samples from the farm's scene files (relight.dataset).

Per scene: crop a square around the person's mask bounding box (+ padding,
zero-extended past the borders), resize it to `size` (a multiple of the
network's size_multiple) and keep it in a small cache. Per training sample:
  * an input light `a` of the scene that is not held out, path-traced image as
    the input, or (with probability `extra_light_prob`) an extra light: a
    training HDR's SH (relight.presets, never a held-out map) or another
    scene light, rotated about Z at random and scaled to a reference radiance
    in [0.7, 0.9], rendered as the PRT image rho * (T . L) (free augmentation);
  * a target light `b` (another path-traced training light when the scene has
    one, else an extra PRT light) for the cross-light loss;
  * the input composited over a varied background (the rendered HDR world,
    a flat colour, smooth noise, a gradient) with the GT alpha, and with
    probability `mask_prob` multiplied by the GT alpha (the runtime's "mask
    given" case; otherwise the matte head must find the person);
  * relight.prt.to_network_input's encoding (sRGB, [-1, 1]);
  * with `light_tint` > 0, each of the two lights (and its image) tinted by a
    random per-channel factor of luminance 1 (exact: light transport is
    linear per colour channel), so that light colour is not tied to the few
    training maps;
  * with `exposure_jitter` > 0, the input light and its image scaled by
    2^N(0, sigma^2) (exposure; the albedo target is unchanged);
  * with probability `flip_prob` a horizontal mirror (exact: mirror_signs).
Splits: by body (validation bodies never train) and by light (held-out maps
never reach training: asserted on every training sample).
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
from torch.nn import functional as F

from relight import sh as sh_np
from relight.colour import LUMINANCE_WEIGHTS
from relight.dataset import light_map_name, list_finished_scenes, read_scene, read_sidecar, traced_lights
from relight.light import rotate_and_normalise
from relight.prt import render, to_network_input

DEFAULT_PADDING = 20  # pixels around the mask bbox, as in the paper
REFERENCE_RADIANCE = (0.7, 0.9)  # paper: lights scaled to a reference radiance in this range


def held_out_light_names() -> frozenset[str]:
    """Names of the HDR maps reserved for evaluation (relight.presets.HELD_OUT)."""
    from relight import presets

    return frozenset(str(n).lower() for n in presets.HELD_OUT)


light_name = light_map_name  # the HDR map a scene light came from (relight.dataset)


def is_held_out(light: dict, held_out: frozenset[str]) -> bool:
    return light_name(light) in held_out or str(light.get("name", "")).lower() in held_out


def body_key(meta: dict) -> str:
    """Identity of the scene's body (clothed model), used for the body split."""
    body = meta.get("body")
    if isinstance(body, dict) and "id" in body:
        return str(body["id"])
    if body is None:
        return f"scene-{meta.get('index')}"
    return json.dumps(body, sort_keys=True, default=str)


def split_by_body(json_paths: list[Path], val_fraction: float, seed: int = 0) -> tuple[list[Path], list[Path]]:
    """Deterministic body split: a body goes to validation when its hash falls below val_fraction.

    With at least two bodies, both sides get at least one body.
    """
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")
    keys = {p: body_key(read_sidecar(p)) for p in json_paths}

    def rank(key: str) -> float:
        digest = hashlib.sha256(f"{seed}:{key}".encode()).digest()
        return int.from_bytes(digest[:8], "big") / 2.0**64

    bodies = sorted(set(keys.values()), key=rank)
    n_val = int(round(val_fraction * len(bodies)))
    if val_fraction > 0 and len(bodies) >= 2:
        n_val = min(max(n_val, 1), len(bodies) - 1)
    val_bodies = set(bodies[:n_val])
    train = [p for p in json_paths if keys[p] not in val_bodies]
    val = [p for p in json_paths if keys[p] in val_bodies]
    return train, val


# ---------------------------------------------------------------- cropping


def crop_box(alpha: np.ndarray, padding: int) -> tuple[int, int, int]:
    """(top, left, side): a square around the mask bbox plus padding (may leave the image)."""
    rows = np.flatnonzero(alpha.max(axis=1) > 0)
    cols = np.flatnonzero(alpha.max(axis=0) > 0)
    if rows.size == 0:
        raise ValueError("scene has an empty alpha mask: no person to crop")
    top, bottom = rows[0] - padding, rows[-1] + 1 + padding
    left, right = cols[0] - padding, cols[-1] + 1 + padding
    side = max(bottom - top, right - left)
    top -= (side - (bottom - top)) // 2
    left -= (side - (right - left)) // 2
    return int(top), int(left), int(side)


def crop_resize(planes: np.ndarray, box: tuple[int, int, int], size: int) -> np.ndarray:
    """Crop [H, W, C] to the square box (zeros outside the image), resize to [C, size, size]."""
    top, left, side = box
    h, w, c = planes.shape
    out = np.zeros((side, side, c), dtype=np.float32)
    y0, x0 = max(top, 0), max(left, 0)
    y1, x1 = min(top + side, h), min(left + side, w)
    out[y0 - top:y1 - top, x0 - left:x1 - left] = planes[y0:y1, x0:x1]
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
    if scene.images is not None:
        stacked += list(scene.images)
    planes = crop_resize(np.concatenate(stacked, axis=-1), box, size)
    k = 0
    parts = []
    for width in [1, 3, n, 3] + ([3] * len(scene.images) if scene.images is not None else []):
        parts.append(planes[k:k + width])
        k += width
    n_lights = len(scene.lights)
    images = parts[4:] if scene.images is not None else [None] * n_lights
    normal = parts[3]
    length = np.sqrt((normal * normal).sum(axis=0, keepdims=True))
    # resampling shortens normals across edges: renormalise, keep 0 off the person
    normal = np.where(length > 1e-6, normal / np.maximum(length, 1e-6), 0.0).astype(np.float32)
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
    )


MIRROR_X = np.array([-1.0, 1.0, 1.0], dtype=np.float32)  # a mirrored photo's normals: x flips


def mirror_signs(order: int) -> np.ndarray:
    """Per-coefficient signs s with Y_k(-x, y, z) = s_k Y_k(x, y, z).

    Mirroring x maps azimuth phi -> pi - phi: cos(m phi) terms (m > 0) gain
    (-1)^m, sin(|m| phi) terms (m < 0) gain (-1)^(|m|+1), zonal terms stay.
    A horizontally flipped photo has transport s * T and light s * L, and
    (s T) . (s L) = T . L: an exact augmentation.
    """
    signs = []
    for l in range(order + 1):
        for m in range(-l, l + 1):
            signs.append(1.0 if m == 0 else (-1.0) ** (abs(m) + (1 if m < 0 else 0)))
    return np.asarray(signs, dtype=np.float32)


# ---------------------------------------------------------------- backgrounds


def random_background(rng: np.random.Generator, size: int) -> np.ndarray:
    """A linear RGB background [3, S, S]: flat colour, smooth noise or a gradient."""
    kind = rng.integers(3)
    if kind == 0:
        colour = rng.uniform(0.0, 1.0, 3) ** 2.2
        return np.broadcast_to(colour[:, None, None], (3, size, size)).astype(np.float32)
    if kind == 1:
        cells = int(rng.integers(2, 9))
        coarse = torch.from_numpy(rng.uniform(0.0, 1.0, (1, 3, cells, cells)).astype(np.float32))
        smooth = F.interpolate(coarse, size=(size, size), mode="bicubic", align_corners=False)
        return (smooth[0].clamp(0.0, 1.0) ** 2.2).numpy()
    a, b = rng.uniform(0.0, 1.0, (2, 3)) ** 2.2
    angle = rng.uniform(0, 2 * math.pi)
    yy, xx = np.mgrid[0:size, 0:size] / max(size - 1, 1)
    t = np.clip(0.5 + (xx - 0.5) * math.cos(angle) + (yy - 0.5) * math.sin(angle), 0.0, 1.0)
    return (a[:, None, None] * (1 - t) + b[:, None, None] * t).astype(np.float32)


# ---------------------------------------------------------------- lights


def random_reference_light(base: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """Rotate an SH light [n, 3] about Z at random, scale to a reference radiance in [0.7, 0.9]."""
    rotation = rng.uniform(0.0, 360.0)
    target = rng.uniform(*REFERENCE_RADIANCE)
    scaled, _ = rotate_and_normalise(base, rotation, target)  # relight.light's recipe for maps
    return scaled.astype(np.float32)


def random_light_tint(rng: np.random.Generator, sigma: float) -> np.ndarray:
    """Per-channel factors exp(N(0, sigma^2)) rescaled to Rec.709 luminance 1.

    Multiplying a light by it changes the light's colour, never its reference
    radiance; the image under it is multiplied by the same factors.
    """
    tint = np.exp(rng.normal(0.0, sigma, 3))
    return (tint / float(LUMINANCE_WEIGHTS @ tint)).astype(np.float32)


def preset_training_lights(order: int) -> list[tuple[str, np.ndarray]]:
    """SH [n, 3] of every bundled HDR preset that is not held out."""
    from relight import presets
    from relight.light import sh_light

    held_out = held_out_light_names()
    out = []
    for name in presets.training_presets():
        assert name.lower() not in held_out, f"relight.presets offered held-out map {name}"
        out.append((name.lower(), np.asarray(sh_light(name, order, normalize=False), dtype=np.float32)))
    return out


# ---------------------------------------------------------------- datasets


class _SceneCache:
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


PACK_FORMAT = "relight-pack/1"


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
    from relight.fileio import atomic_path

    held_out = held_out_light_names() if held_out is None else held_out
    arrays: dict[str, np.ndarray] = {}
    records = []
    for i, path in enumerate(json_paths):
        c = load_cropped(Path(path), size, order, padding, held_out)
        maps = [c.alpha, c.albedo, c.transport, c.normal] + [img for img in c.images if img is not None]
        arrays[f"s{i}"] = np.concatenate(maps, axis=0).astype(np.float16)
        arrays[f"l{i}"] = np.stack(c.lights).astype(np.float32)
        records.append({"index": c.index, "names": c.light_names, "held_out": c.held_out,
                        "traced": [img is not None for img in c.images]})
    key = _pack_key(list(json_paths), size, order, padding)
    arrays["meta"] = np.frombuffer(json.dumps({"key": key, "scenes": records}).encode(), dtype=np.uint8)
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(out, ".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
    return out


class PackedScenes:
    """CroppedScene i of a pack (pack_scenes), all held in memory; same call as _SceneCache."""

    def __init__(self, path, json_paths: list[Path], size: int, order: int, padding: int = DEFAULT_PADDING):
        with np.load(path, allow_pickle=False) as z:
            meta = json.loads(bytes(z["meta"]).decode())
            if meta["key"] != _pack_key(list(json_paths), size, order, padding):
                raise ValueError(f"{path}: the pack was made from other scenes or crop settings")
            self.items = []
            n = sh_np.num_coeffs(order)
            for i, rec in enumerate(meta["scenes"]):
                maps = z[f"s{i}"].astype(np.float32)
                k = 1 + 3 + n + 3
                images, j = [], k
                for traced in rec["traced"]:
                    images.append(maps[j:j + 3] if traced else None)
                    j += 3 if traced else 0
                self.items.append(CroppedScene(
                    index=rec["index"], alpha=maps[0:1], albedo=maps[1:4], transport=maps[4:4 + n],
                    normal=maps[4 + n:k], images=images, lights=list(z[f"l{i}"]),
                    light_names=rec["names"], held_out=rec["held_out"]))
        self.paths = list(json_paths)

    def __call__(self, i: int) -> CroppedScene:
        return self.items[i]


def _to_tensors(sample: dict) -> dict:
    return {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)) if isinstance(v, np.ndarray) else v
            for k, v in sample.items()}


def _network_input(linear_chw: np.ndarray, alpha: np.ndarray | None) -> np.ndarray:
    hwc = linear_chw.transpose(1, 2, 0)
    mask = None if alpha is None else alpha[0]
    return to_network_input(hwc, mask).transpose(2, 0, 1)


class TrainingScenes(torch.utils.data.Dataset):
    """Random training samples (see module docstring); one item per scene per epoch."""

    def __init__(self, json_paths: list[Path], size: int, order: int, *, padding: int = DEFAULT_PADDING,
                 extra_lights: list[tuple[str, np.ndarray]] | None = None, extra_light_prob: float = 0.5,
                 mask_prob: float = 0.5, flip_prob: float = 0.5, lambertian: bool = False, seed: int = 0,
                 cache_size: int = 64, held_out: frozenset[str] | None = None, light_tint: float = 0.0,
                 pack: Path | None = None, exposure_jitter: float = 0.0, capture: bool = False):
        if not json_paths:
            raise ValueError("no training scenes")
        self.size, self.order, self.n = size, order, sh_np.num_coeffs(order)
        self.held_out = held_out_light_names() if held_out is None else held_out
        self.extra_lights = [(name, l[: self.n]) for name, l in (extra_lights or [])]
        for name, _ in self.extra_lights:
            assert name.lower() not in self.held_out, f"held-out light {name} in the training light bank"
        self.extra_light_prob, self.mask_prob, self.flip_prob = extra_light_prob, mask_prob, flip_prob
        if not (math.isfinite(light_tint) and light_tint >= 0):
            raise ValueError(f"light_tint must be finite and >= 0, got {light_tint}")
        self.light_tint = light_tint  # sigma of the log tint; 0: no tint (and no extra random draws)
        if not (math.isfinite(exposure_jitter) and exposure_jitter >= 0):
            raise ValueError(f"exposure_jitter must be finite and >= 0, got {exposure_jitter}")
        # sigma of the input light's log2 scale; 0: none (and no extra random draws)
        self.exposure_jitter = exposure_jitter
        # photo-like capture (model/capture.py); off by default: with the same budget it cost
        # 0.5-0.8 dB on held-out scenes and did not lessen the colour cast on real photos
        # (docs/EVALUATION.md, "Training people like the people in photos")
        self.capture = capture
        self.signs = mirror_signs(order)
        self.lambertian = lambertian  # Kanamori-Endo-style baseline: PRT images only, no path tracing
        self.seed = seed
        # functools.partial, not a lambda: DataLoader workers may need to pickle the dataset
        if pack is not None:  # every scene cropped once, in memory (pack_scenes)
            self.cache = PackedScenes(pack, list(json_paths), size, order, padding)
        else:
            self.cache = _SceneCache(list(json_paths), functools.partial(
                load_cropped, size=size, order=order, padding=padding, held_out=self.held_out), cache_size)

    def __len__(self) -> int:
        return len(self.cache.paths)

    def _bank_light(self, scene: CroppedScene, rng) -> tuple[str, np.ndarray]:
        pool = list(self.extra_lights) + [(name, l) for name, l, h in
                                          zip(scene.light_names, scene.lights, scene.held_out) if not h]
        if not pool:
            raise ValueError(f"scene {scene.index}: no training light to sample from")
        name, base = pool[rng.integers(len(pool))]
        return name, random_reference_light(base.astype(np.float64), rng)

    def _prt(self, scene: CroppedScene, light: np.ndarray) -> np.ndarray:
        """albedo * (T . L), channels first (relight.prt.render)."""
        chw = lambda a: np.moveaxis(a, 0, -1)  # noqa: E731
        return np.moveaxis(render(chw(scene.albedo), chw(scene.transport), None, light), -1, 0)

    def __getitem__(self, i: int) -> dict:
        """Sample i of epoch 0; training takes other epochs through model.train.EpochIndexed."""
        return self.item(i, 0)

    def item(self, i: int, epoch: int) -> dict:
        """Sample i with the augmentation of `epoch` (deterministic in seed, epoch, i)."""
        rng = np.random.default_rng([self.seed, epoch, i])
        scene = self.cache(i)
        traced = [k for k, (img, h) in enumerate(zip(scene.images, scene.held_out)) if img is not None and not h]
        if self.lambertian:
            traced = []

        def pick(exclude: int | None):
            options = [k for k in traced if k != exclude]
            if options and rng.uniform() >= self.extra_light_prob:
                k = options[rng.integers(len(options))]
                return k, scene.light_names[k], scene.lights[k], scene.images[k], True
            name, light = self._bank_light(scene, rng)
            return None, name, light, self._prt(scene, light), False

        k_a, name_a, light_a, image_a, traced_a = pick(None)
        _, name_b, light_b, image_b, _ = pick(k_a)
        for name in (name_a, name_b):
            # the split guarantee: held-out maps never reach training
            assert name not in self.held_out, f"held-out light {name!r} reached a training sample"
        if self.exposure_jitter > 0:
            # the input light (and so its image) brighter or darker; the albedo target is the same,
            # so the network cannot read the albedo's level off the photo's brightness (exact:
            # radiance is linear in the light)
            gain = np.float32(2.0 ** rng.normal(0.0, self.exposure_jitter))
            light_a, image_a = light_a * gain, image_a * gain
        if self.light_tint > 0:
            tint_a, tint_b = random_light_tint(rng, self.light_tint), random_light_tint(rng, self.light_tint)
            light_a, image_a = light_a * tint_a, image_a * tint_a[:, None, None]
            light_b, image_b = light_b * tint_b, image_b * tint_b[:, None, None]

        alpha = scene.alpha
        background_kind = rng.integers(4)
        if traced_a and background_kind == 0:
            composite = image_a  # the rendered HDR world behind the person
        else:
            composite = alpha * image_a + (1 - alpha) * random_background(rng, self.size)
        if self.capture:  # real background, white balance, exposure, blur, noise, JPEG; image and light gained alike
            from model.capture import photo_like

            composite, image_a, light_a, _ = photo_like(composite, image_a, alpha, light_a,
                                                        np.random.default_rng([self.seed, epoch, i, 20]))
        masked = rng.uniform() < self.mask_prob
        sample = {
            "input": _network_input(composite, alpha if masked else None),
            "image": image_a, "albedo": scene.albedo, "transport": scene.transport, "alpha": alpha,
            "normal": scene.normal, "light": light_a, "target_light": light_b, "target_image": image_b,
            "light_name": name_a, "target_light_name": name_b,
        }
        if rng.uniform() < self.flip_prob:  # horizontal mirror, exact for T and L (mirror_signs)
            for key in ("input", "image", "albedo", "transport", "alpha", "target_image", "normal"):
                sample[key] = sample[key][..., ::-1]
            sample["transport"] = sample["transport"] * self.signs[:, None, None]
            sample["normal"] = sample["normal"] * MIRROR_X[:, None, None]
            sample["light"] = sample["light"] * self.signs[:, None]
            sample["target_light"] = sample["target_light"] * self.signs[:, None]
        return _to_tensors(sample)


class EvaluationPairs(torch.utils.data.Dataset):
    """Deterministic (scene, light a -> light b) pairs of path-traced images.

    Input: image under a over its rendered background, masked by the GT alpha;
    target: the path-traced image of the same scene under b. With
    `held_out_only`, b is restricted to held-out lights when the scene has any.
    """

    def __init__(self, json_paths: list[Path], size: int, order: int, *, padding: int = DEFAULT_PADDING,
                 held_out_only: bool = False, held_out: frozenset[str] | None = None, max_pairs_per_scene: int = 4):
        self.size, self.order = size, order
        self.held_out = held_out_light_names() if held_out is None else held_out
        self.load = functools.partial(load_cropped, size=size, order=order, padding=padding,
                                      held_out=self.held_out, verify_hash=True)
        self.paths = list(json_paths)
        self.pairs: list[tuple[int, int, int]] = []
        for s, path in enumerate(self.paths):
            meta = read_sidecar(path)
            traced = traced_lights(meta)
            if len(traced) < 2:
                continue
            targets = traced
            if held_out_only:
                held = [k for k in traced if is_held_out(meta["lights"][k], self.held_out)]
                targets = held or traced
            pairs = [(s, a, b) for b in targets for a in traced if a != b]
            self.pairs += pairs[:max_pairs_per_scene]
        if not self.pairs:
            raise ValueError("no evaluation pairs: scenes need at least two path-traced lights")
        self._cache = _SceneCache(self.paths, self.load, capacity=8)

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, i: int) -> dict:
        s, a, b = self.pairs[i]
        scene = self._cache(s)
        sample = {
            "input": _network_input(scene.images[a], scene.alpha),
            "input_linear": scene.images[a],
            "image": scene.images[a], "albedo": scene.albedo, "transport": scene.transport,
            "normal": scene.normal, "alpha": scene.alpha, "light": scene.lights[a], "target_light": scene.lights[b],
            "target_image": scene.images[b],
        }
        out = _to_tensors(sample)
        out.update(scene_index=scene.index, light_a=scene.light_names[a], light_b=scene.light_names[b])
        return out


def find_scenes(folder) -> list[Path]:
    """Finished scenes of a dataset folder (ValueError when there are none)."""
    paths = list_finished_scenes(folder)
    if not paths:
        raise ValueError(f"no finished scenes (scene_NNNNNN.json + .exr) in {folder}")
    return paths
