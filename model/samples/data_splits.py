"""Which scenes and lights may train: the held-out light maps, the body split, and the
finished scenes of a dataset folder (relight.files.dataset)."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

from relight.files.dataset import light_map_name, list_finished_scenes, read_sidecar


def held_out_light_names() -> frozenset[str]:
    """Names of the HDR maps reserved for evaluation (relight.lighting.presets.HELD_OUT)."""
    from relight.lighting import presets

    return frozenset(str(n).lower() for n in presets.HELD_OUT)


light_name = light_map_name  # the HDR map a scene light came from (relight.files.dataset)


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
    return split_by_key(list(json_paths), [body_key(read_sidecar(p)) for p in json_paths], val_fraction, seed)


def split_by_key(items: list, keys: list[str], val_fraction: float, seed: int = 0) -> tuple[list, list]:
    """split_by_body over items given with their body keys (keys[i] is items[i]'s): a training
    pack splits its scenes by the keys it recorded, without the sidecars."""
    if not 0.0 <= val_fraction < 1.0:
        raise ValueError(f"val_fraction must be in [0, 1), got {val_fraction}")

    def rank(key: str) -> float:
        digest = hashlib.sha256(f"{seed}:{key}".encode()).digest()
        return int.from_bytes(digest[:8], "big") / 2.0**64

    bodies = sorted(set(keys), key=rank)
    n_val = int(round(val_fraction * len(bodies)))
    if val_fraction > 0 and len(bodies) >= 2:
        n_val = min(max(n_val, 1), len(bodies) - 1)
    val_bodies = set(bodies[:n_val])
    train = [p for p, key in zip(items, keys) if key not in val_bodies]
    val = [p for p, key in zip(items, keys) if key in val_bodies]
    return train, val


def find_scenes(folder) -> list[Path]:
    """Finished scenes of a dataset folder (ValueError when there are none)."""
    paths = list_finished_scenes(folder)
    if not paths:
        raise ValueError(f"no finished scenes (scene_NNNNNN.json + .exr) in {folder}")
    return paths


def scene_map_lights(json_paths, held_out: frozenset[str] | None = None) -> dict[str, list[list]]:
    """{HDR map name (relight.files.dataset.light_map_name): the SH of each of its lights} over the
    sidecars of `json_paths`, held-out maps left out."""
    held_out = held_out_light_names() if held_out is None else held_out
    out: dict[str, list[list]] = {}
    for path in json_paths:
        for light in read_sidecar(path).get("lights", []):
            if not is_held_out(light, held_out):
                out.setdefault(light_name(light), []).append(light["sh"])
    return out


def training_map_names(json_paths, extra_names=(), held_out: frozenset[str] | None = None) -> list[str]:
    """Every HDR map that lights a training scene of `json_paths` (scene_map_lights), with
    `extra_names` (the preset bank's), less the held-out maps; sorted."""
    held_out = held_out_light_names() if held_out is None else held_out
    names = {str(n).lower() for n in extra_names} | set(scene_map_lights(json_paths, held_out))
    return sorted(names - held_out)


def first_maps(names, count: int, seed: int = 0) -> frozenset[str]:
    """`count` of `names` in a fixed order (SHA-256 of seed and name), so that a smaller set
    is always inside a larger one: a curve over the number of training maps adds maps, it
    never swaps them."""
    names = sorted({str(n).lower() for n in names})
    if not 1 <= count <= len(names):
        raise ValueError(f"{count} maps asked for; the training data has {len(names)}")
    rank = lambda n: hashlib.sha256(f"{seed}:{n}".encode()).digest()
    return frozenset(sorted(names, key=rank)[:count])


# issue 45: a hard sun this far off the camera's axis (degrees) lights the person from the side
SIDE_SUN_DEG = (40.0, 140.0)


def sun_off_axis_deg(light: dict) -> float | None:
    """How far a hard sun is from the camera's axis (degrees between its camera-frame direction and
    the direction toward the camera, -Y); None for any other light."""
    import numpy as np

    hard = light.get("hard")
    if not hard or hard.get("kind") != "sun":
        return None
    toward = -float(np.asarray(hard["lobes"][0]["direction_camera"], np.float64)[1])
    return float(np.degrees(np.arccos(np.clip(toward, -1.0, 1.0))))


def side_sun_pairs(meta: dict, side_deg: tuple[float, float] = SIDE_SUN_DEG) -> list[tuple[int, int]]:
    """(a, b) light indices of a scene's sidecar: a an HDR map (no hard light), b a sun `side_deg`
    off the camera axis: a photo under a map relit to a hard side sun."""
    lights = meta["lights"]
    suns = [b for b, light in enumerate(lights)
            if (angle := sun_off_axis_deg(light)) is not None and side_deg[0] <= angle <= side_deg[1]]
    return [(a, b) for b in suns for a, light in enumerate(lights) if a != b and not light.get("hard")]
