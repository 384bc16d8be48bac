"""Training and evaluation samples from the farm's scene files (relight.files.dataset).

Per scene: cropped around the person and resized to `size` (a multiple of the
network's size_multiple; model.samples.data_crops), with the splits of
model.samples.data_splits. Per training sample (draws: model.samples.data_augment):
  * an input light `a` of the scene that is not held out, path-traced image as
    the input, or (with probability `extra_light_prob`) an extra light: a
    training HDR's SH (relight.lighting.presets, never a held-out map) or another
    scene light, rotated about Z at random and scaled to a reference radiance
    in [0.7, 0.9], rendered as the PRT image rho * (T . L) (free augmentation);
  * a target light `b` (another path-traced training light when the scene has
    one, else an extra PRT light) for the cross-light loss;
  * the input composited over a varied background (the rendered HDR world,
    a flat colour, smooth noise, a gradient) with the GT alpha, and with
    probability `mask_prob` multiplied by the GT alpha (the runtime's "mask
    given" case; otherwise the matte head must find the person);
  * relight.network.prt.to_network_input's encoding (sRGB, [-1, 1]);
  * with `light_tint` > 0, each of the two lights (and its image) tinted by a
    random per-channel factor of luminance 1 (exact: light transport is
    linear per colour channel), so that light colour is not tied to the few
    training maps;
  * with `exposure_jitter` > 0, the input light and its image scaled by
    2^N(0, sigma^2) (exposure; the albedo target is unchanged);
  * with probability `flip_prob` a horizontal mirror (exact: mirror_signs);
  * with `body_prior`, the unclothed body's normal and coverage (the farm's body pass,
    body_input's encoding) appended to the input's channels;
  * with `depth`, the depth pass [1, S, S] as "depth" (the depth head's target; scene_depth).
Splits: by body (validation bodies never train) and by light (held-out maps
never reach training: asserted on every training sample).
"""

from __future__ import annotations

import functools
import math
from pathlib import Path

import numpy as np
import torch

from model.samples.data_augment import (
    MIRROR_X, mirror_signs, random_background, random_light_tint, random_mixed_light, random_reference_light,
    random_sun_light,
)
from model.samples.data_crops import DEFAULT_PADDING, CroppedScene, PackedScenes, SceneCache, load_cropped
from model.samples.data_splits import held_out_light_names, is_held_out, scene_map_lights, side_sun_pairs
from model.networks.geometry import BODY_CHANNELS
from relight.lighting import sh as sh_np
from relight.files.dataset import read_sidecar, traced_lights
from relight.network.prt import render, to_network_input


def _to_tensors(sample: dict) -> dict:
    """The sample's arrays as contiguous float32 tensors (other values kept)."""
    return {k: torch.from_numpy(np.ascontiguousarray(v, dtype=np.float32)) if isinstance(v, np.ndarray) else v
            for k, v in sample.items()}


def body_input(scene: CroppedScene) -> np.ndarray:
    """[4, S, S] network input channels of the scene's body prior: the unit normal (camera
    frame) and the coverage mapped to [-1, 1]."""
    if scene.body is None:
        raise ValueError(f"scene {scene.index} has no body pass (the body prior needs the farm's body pass)")
    out = np.concatenate([scene.body[:3], scene.body[3:4] * 2.0 - 1.0]).astype(np.float32)
    assert out.shape[0] == BODY_CHANNELS
    return out


def scene_depth(scene: CroppedScene) -> np.ndarray:
    """[1, S, S] the scene's depth pass (metres, 0 off the person): the depth head's target."""
    if scene.depth is None:
        raise ValueError(f"scene {scene.index} has no depth pass (the depth head needs the farm's depth; "
                         "a pack made before issue 45's depth head must be made again)")
    return scene.depth


def network_input(linear_chw: np.ndarray, alpha: np.ndarray | None) -> np.ndarray:
    """relight.network.prt.to_network_input of a channels-first linear image, masked by alpha [1, H, W] when given."""
    hwc = linear_chw.transpose(1, 2, 0)
    mask = None if alpha is None else alpha[0]
    return to_network_input(hwc, mask).transpose(2, 0, 1)


def scene_prt(scene: CroppedScene, light: np.ndarray) -> np.ndarray:
    """A cropped scene's albedo * (T . L) under `light`, channels first (relight.network.prt.render)."""
    chw = lambda a: np.moveaxis(a, 0, -1)
    return np.moveaxis(render(chw(scene.albedo), chw(scene.transport), None, light), -1, 0)


class TrainingScenes(torch.utils.data.Dataset):
    """Random training samples (see module docstring); one item per scene per epoch."""

    def __init__(self, json_paths: list[Path], size: int, order: int, *, padding: int = DEFAULT_PADDING,
                 extra_lights: list[tuple[str, np.ndarray]] | None = None, extra_light_prob: float = 0.5,
                 mask_prob: float = 0.5, flip_prob: float = 0.5, lambertian: bool = False, seed: int = 0,
                 cache_size: int = 64, held_out: frozenset[str] | None = None, light_tint: float = 0.0,
                 pack: Path | None = None, exposure_jitter: float = 0.0, capture: bool = False,
                 body_prior: bool = False, light_mix: float = 0.0, light_maps: frozenset[str] | None = None,
                 scenes=None, depth: bool = False, sun_light: bool = False):
        # `scenes`: scenes already cropped (model.samples.training_pack.PackScenes), json_paths then unused
        if not (json_paths or (scenes is not None and scenes.paths)):
            raise ValueError("no training scenes")
        if scenes is not None and light_maps is not None:
            raise ValueError("light_maps needs the scenes' sidecars: not with a training pack")
        self.size, self.order, self.n = size, order, sh_np.num_coeffs(order)
        self.held_out = held_out_light_names() if held_out is None else held_out
        # the maps that may light a sample (None: every training map); a study of how the light
        # estimate grows with the number of maps (model.train --light-maps)
        self.light_maps = None if light_maps is None else frozenset(str(m).lower() for m in light_maps)
        if self.light_maps is not None and not self.light_maps:
            raise ValueError("light_maps must name at least one map")
        self.extra_lights = [(name, l[: self.n]) for name, l in (extra_lights or []) if self._allowed(name)]
        # with light_maps, every scene draws from all instances of the allowed maps (the bank's and
        # every training scene's), a map first, uniformly, so that K maps weigh alike
        self.map_bank: dict[str, list[np.ndarray]] = {}
        if self.light_maps is not None:
            for name, light in self.extra_lights:
                self.map_bank.setdefault(name, []).append(light)
            for name, lights in scene_map_lights(json_paths, self.held_out).items():
                if self._allowed(name):
                    self.map_bank.setdefault(name, []).extend(np.asarray(sh[: self.n], np.float32) for sh in lights)
            if not self.map_bank:
                raise ValueError(f"none of the maps {sorted(self.light_maps)} lights a training scene")
        self.map_names = sorted(self.map_bank)
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
        if not (math.isfinite(light_mix) and 0.0 <= light_mix <= 1.0):
            raise ValueError(f"light_mix must be a probability in [0, 1], got {light_mix}")
        # chance that a bank light is two lights mixed and tilted (random_mixed_light); 0: never
        # (and no extra random draws)
        self.light_mix = light_mix
        # photo-like capture (model/samples/capture.py); off by default: with the same budget it cost
        # 0.5-0.8 dB on held-out scenes and did not lessen the colour cast on real photos
        # (docs/EVALUATION.md, "Training people like the people in photos")
        self.capture = capture
        self.body_prior = bool(body_prior)
        self.depth = bool(depth)  # samples carry the depth pass (model.train --depth-head)
        # samples carry a hard sun for the sun-response loss (--loss-weight sun_response=W), drawn
        # from its own stream so that every other draw stays as it was
        self.sun_light = bool(sun_light)
        self.signs = mirror_signs(order)
        self.lambertian = lambertian  # Kanamori-Endo-style baseline: PRT images only, no path tracing
        self.seed = seed
        # functools.partial, not a lambda: DataLoader workers may need to pickle the dataset
        if scenes is not None:
            self.cache = scenes
        elif pack is not None:  # every scene cropped once, in memory (pack_scenes)
            self.cache = PackedScenes(pack, list(json_paths), size, order, padding)
        else:
            self.cache = SceneCache(list(json_paths), functools.partial(
                load_cropped, size=size, order=order, padding=padding, held_out=self.held_out), cache_size)

    def __len__(self) -> int:
        return len(self.cache.paths)

    def _allowed(self, name: str) -> bool:
        return self.light_maps is None or name.lower() in self.light_maps

    def _bank_light(self, scene: CroppedScene, rng) -> tuple[str, np.ndarray]:
        if self.map_bank:
            def draw():
                name = self.map_names[rng.integers(len(self.map_names))]
                return name, self.map_bank[name][rng.integers(len(self.map_bank[name]))]
        else:
            pool = list(self.extra_lights) + [(name, l) for name, l, h in
                                              zip(scene.light_names, scene.lights, scene.held_out) if not h]
            if not pool:
                raise ValueError(f"scene {scene.index}: no training light to sample from")

            def draw():
                return pool[rng.integers(len(pool))]
        name, base = draw()
        if self.light_mix > 0 and rng.uniform() < self.light_mix:
            other, second = draw()
            return f"{name}+{other}", random_mixed_light(base.astype(np.float64), second.astype(np.float64), rng)
        return name, random_reference_light(base.astype(np.float64), rng)


    def __getitem__(self, i: int) -> dict:
        """Sample i of epoch 0; training takes other epochs through model.training.train_data.EpochIndexed."""
        return self.item(i, 0)

    def item(self, i: int, epoch: int) -> dict:
        """Sample i with the augmentation of `epoch` (deterministic in seed, epoch, i)."""
        rng = np.random.default_rng([self.seed, epoch, i])
        scene = self.cache(i)
        traced = [k for k, (img, h, name) in enumerate(zip(scene.images, scene.held_out, scene.light_names))
                  if img is not None and not h and self._allowed(name)]
        if self.lambertian:
            traced = []

        def pick(exclude: int | None):
            options = [k for k in traced if k != exclude]
            if options and rng.uniform() >= self.extra_light_prob:
                k = options[rng.integers(len(options))]
                return k, scene.light_names[k], scene.lights[k], scene.images[k], True
            name, light = self._bank_light(scene, rng)
            return None, name, light, scene_prt(scene, light), False

        k_a, name_a, light_a, image_a, traced_a = pick(None)
        _, name_b, light_b, image_b, _ = pick(k_a)
        for name in (name_a, name_b):
            # the split guarantee: held-out maps never reach training (a mix names both its maps)
            assert not set(name.split("+")) & self.held_out, f"held-out light {name!r} reached a training sample"
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
            from model.samples.capture import photo_like

            composite, image_a, light_a, _ = photo_like(composite, image_a, alpha, light_a,
                                                        np.random.default_rng([self.seed, epoch, i, 20]))
        masked = rng.uniform() < self.mask_prob
        network_in = network_input(composite, alpha if masked else None)
        if self.body_prior:
            network_in = np.concatenate([network_in, body_input(scene)])
        sample = {
            "input": network_in,
            "image": image_a, "albedo": scene.albedo, "transport": scene.transport, "alpha": alpha,
            "normal": scene.normal, "light": light_a, "target_light": light_b, "target_image": image_b,
            "light_name": name_a, "target_light_name": name_b,
        }
        if self.depth:
            sample["depth"] = scene_depth(scene)
        if self.sun_light:
            sample["sun_light"] = random_sun_light(np.random.default_rng([self.seed, epoch, i, 30]), self.order)
        if rng.uniform() < self.flip_prob:  # horizontal mirror, exact for T and L (mirror_signs)
            for key in ("input", "image", "albedo", "transport", "alpha", "target_image", "normal") + (
                    ("depth",) if self.depth else ()):
                sample[key] = sample[key][..., ::-1]
            sample["transport"] = sample["transport"] * self.signs[:, None, None]
            sample["normal"] = sample["normal"] * MIRROR_X[:, None, None]
            if self.body_prior:  # the body normal's x flips too (input channel 3)
                sample["input"] = sample["input"] * np.array([1, 1, 1, -1, 1, 1, 1], np.float32)[:, None, None]
            sample["light"] = sample["light"] * self.signs[:, None]
            sample["target_light"] = sample["target_light"] * self.signs[:, None]
            if self.sun_light:
                sample["sun_light"] = sample["sun_light"] * self.signs[:, None]
        return _to_tensors(sample)


class EvaluationPairs(torch.utils.data.Dataset):
    """Deterministic (scene, light a -> light b) pairs of path-traced images.

    Input: image under a over its rendered background, masked by the GT alpha;
    target: the path-traced image of the same scene under b. With
    `held_out_only`, b is restricted to held-out lights when the scene has any. With `side_sun`,
    only a map -> a hard side sun (model.samples.data_splits.side_sun_pairs; issue 45), and scenes
    without such a pair give none.
    """

    def __init__(self, json_paths: list[Path], size: int, order: int, *, padding: int = DEFAULT_PADDING,
                 held_out_only: bool = False, held_out: frozenset[str] | None = None, max_pairs_per_scene: int = 4,
                 body_prior: bool = False, depth: bool = False, side_sun: bool = False):
        self.size, self.order, self.body_prior, self.depth = size, order, bool(body_prior), bool(depth)
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
            if side_sun:
                pairs = [(s, a, b) for a, b in side_sun_pairs(meta) if a in traced and b in traced]
            else:
                pairs = [(s, a, b) for b in targets for a in traced if a != b]
            self.pairs += pairs[:max_pairs_per_scene]
        if not self.pairs:
            raise ValueError("no evaluation pairs: scenes need at least two path-traced lights"
                             + (" and a map with a hard side sun" if side_sun else ""))
        self._cache = SceneCache(self.paths, self.load, capacity=8)

    @classmethod
    def from_scenes(cls, scenes: list[CroppedScene], size: int, order: int, *, max_pairs_per_scene: int = 4,
                    body_prior: bool = False, depth: bool = False) -> "EvaluationPairs":
        """The pairs of scenes already cropped (a training pack's validation scenes), as the
        constructor makes them from scene files (every traced light as a target)."""
        self = cls.__new__(cls)
        self.size, self.order, self.body_prior, self.depth = size, order, bool(body_prior), bool(depth)
        self.paths, self.pairs = None, []
        for s, scene in enumerate(scenes):
            traced = [k for k, image in enumerate(scene.images) if image is not None]
            self.pairs += [(s, a, b) for b in traced for a in traced if a != b][:max_pairs_per_scene]
        if not self.pairs:
            raise ValueError("no evaluation pairs: scenes need at least two path-traced lights")
        self._cache = scenes.__getitem__
        return self

    def __len__(self) -> int:
        return len(self.pairs)

    def __getitem__(self, i: int) -> dict:
        s, a, b = self.pairs[i]
        scene = self._cache(s)
        network_in = network_input(scene.images[a], scene.alpha)
        if self.body_prior:
            network_in = np.concatenate([network_in, body_input(scene)])
        sample = {
            "input": network_in,
            "input_linear": scene.images[a],
            "image": scene.images[a], "albedo": scene.albedo, "transport": scene.transport,
            "normal": scene.normal, "alpha": scene.alpha, "light": scene.lights[a], "target_light": scene.lights[b],
            "target_image": scene.images[b],
        }
        if self.depth:
            sample["depth"] = scene_depth(scene)
        out = _to_tensors(sample)
        out.update(scene_index=scene.index, light_a=scene.light_names[a], light_b=scene.light_names[b])
        return out


def photo_pairs(data, size: int, count: int | None = None, per_scene: int = 4, transport: bool = False):
    """EvaluationPairs of the scenes in `data` (crops of `size` px) as the runtime takes a photo,
    channels last: "photo" (the image under light a, its background kept), "alpha" [H, W],
    "target" (the path-traced image under b), "albedo", float64 "light_a" / "light_b", and with
    `transport` the baked T [H, W, n] (large: only when asked). A generator of at most `count`."""
    from model.samples.data_splits import find_scenes

    pairs = EvaluationPairs(find_scenes(data), size, 4, held_out=held_out_light_names(), max_pairs_per_scene=per_scene)
    keys = ("input_linear", "alpha", "target_image", "albedo") + (("transport",) if transport else ())
    for i in range(len(pairs) if count is None else min(count, len(pairs))):
        item = pairs[i]
        hwc = {k: np.ascontiguousarray(np.moveaxis(item[k].numpy().astype(np.float32), 0, -1)) for k in keys}
        out = {"photo": hwc["input_linear"], "alpha": hwc["alpha"][..., 0], "target": hwc["target_image"],
               "albedo": hwc["albedo"], "light_a": item["light"].numpy().astype(np.float64),
               "light_b": item["target_light"].numpy().astype(np.float64)}
        if transport:
            out["transport"] = hwc["transport"]
        yield out
