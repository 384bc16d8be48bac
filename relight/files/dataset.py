"""Scene files: the farm writes them, the model reads them (docs/ARCHITECTURE.md).

A dataset folder holds scene_NNNNNN.exr + scene_NNNNNN.json pairs. The EXR
is written first, the JSON last, both atomically: a scene is finished exactly
when its JSON exists and names the EXR's SHA-256.
"""

from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from relight.files import scene_passes
from relight.files.exr import read_exr, write_exr
from relight.files.fileio import atomic_write_text, file_sha256
from relight.files.scene_passes import GROUPS, PASSES, PER_LIGHT, PER_PERSON, PLAIN, SH
from relight.files.sh_sizes import num_coeffs

__all__ = [
    "FORMAT",
    "Scene",
    "scene_stem",
    "write_scene",
    "read_scene",
    "read_sidecar",
    "traced_lights",
    "has_transport",
    "light_map_name",
    "list_finished_scenes",
    "transport_channel_names",
    "file_sha256",
    "PERSON_SUM_TOLERANCE",
]

FORMAT = "relight-scene/1"
_STEM_RE = re.compile(r"^scene_(\d{6,})$")
# The channel groups, the passes they belong to and what each means: relight/files/scene_passes.py.
# A group scene's per-person masks (issue 47), person.P0.A .. person.P(N-1).A, sum to alpha:
# each mask and each partial sum of up to MAX_PEOPLE of them is rounded once to float32 (a few
# 1e-7 of a coverage <= 1); the bound leaves room for readers summing in another order.
PERSON_SUM_TOLERANCE = 1e-5
_REQUIRED = [g for g in PASSES[0].groups if not g.optional]  # the geometry pass: in every scene
_REPEATED = re.compile(r"(\w+)\.([LP])(\d+)")  # image.L3, person.P0: a group repeated per light or person


@dataclass
class Scene:
    """One finished scene. `groups` holds every channel group it has (relight/files/scene_passes.py),
    float32 [H, W, C]; per-light groups as a list by light K, `transport` [H, W, (order+1)^2].
    A group reads as an attribute (`scene.alpha`, `scene.body_depth`, `scene.shading`), None when
    the scene lacks it; `images` and `people` are the `image` and `person` groups. `lights` is the
    JSON's light list with `sh`/`sh8` as float64 arrays.
    """

    index: int
    exr_path: Path
    json_path: Path
    meta: dict
    groups: dict = field(default_factory=dict)
    lights: list[dict] = field(default_factory=list)

    def __getattr__(self, name: str):
        if name in GROUPS:
            return self.__dict__.get("groups", {}).get(name)
        raise AttributeError(f"{type(self).__name__} has no attribute {name!r}")

    @property
    def images(self) -> list[np.ndarray] | None:
        """The path-traced images by light K ([H, W, 3] each), None without the pt pass."""
        return self.groups.get("image")

    @property
    def people(self) -> list[np.ndarray] | None:
        """Group scenes (issue 47): per person K, [H, W, 1] coverage summing to alpha; else None."""
        return self.groups.get("person")

    @property
    def resolution(self) -> tuple[int, int]:
        return tuple(self.alpha.shape[:2])

    @property
    def sh_order(self) -> int:
        return int(self.meta["sh_order"])


def scene_stem(folder, index: int) -> Path:
    """folder / scene_NNNNNN (no extension)."""
    if isinstance(index, bool) or not isinstance(index, (int, np.integer)) or index < 0:
        raise ValueError(f"scene index must be a non-negative integer, got {index!r}")
    return Path(folder) / f"scene_{int(index):06d}"


def transport_channel_names(n: int) -> list[str]:
    """transport.00 .. transport.(n-1), zero-padded to at least two digits."""
    return scene_passes.sh_channel_names("transport", n)


def _json_default(obj):
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"scene metadata value of type {type(obj).__name__} is not JSON-serialisable")


def _as_planes(name: str, arr, n_planes: int, hw) -> list[np.ndarray]:
    a = np.asarray(arr)
    if n_planes == 1 and a.ndim == 2:
        a = a[..., None]
    if a.ndim != 3 or a.shape[2] != n_planes:
        raise ValueError(f"scene channel {name!r} must have shape [H, W, {n_planes}], got {a.shape}")
    if hw is not None and a.shape[:2] != hw:
        raise ValueError(f"scene channel {name!r} is {a.shape[:2]}, expected {hw}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"scene channel {name!r} must be floating point, got {a.dtype}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"scene channel {name!r} contains NaN or Inf")
    return [a[..., i] for i in range(n_planes)]


def _group_of(name: str):
    """A channels key -> (its ChannelGroup, light or person K or None); None when the table lacks it."""
    group = GROUPS.get(name)
    if group is not None:
        return (group, None) if group.kind in (PLAIN, SH) else None
    m = _REPEATED.fullmatch(name)
    group = GROUPS.get(m.group(1)) if m else None
    if group is None or group.kind != {"L": PER_LIGHT, "P": PER_PERSON}[m.group(2)]:
        return None
    return group, int(m.group(3))


def _check_passes_come_together(present: set) -> None:
    """A pass's own groups come together; its per-light groups need them (shading needs transport)."""
    for render_pass in PASSES[1:]:
        own = [g.name for g in render_pass.groups if g.kind != PER_LIGHT and not g.optional]
        lit = [g.name for g in render_pass.groups if g.kind == PER_LIGHT]
        found = [n for n in own + lit if n in present]
        missing = [n for n in own if n not in present]
        if found and missing and (len(missing) < len(own) or any(n in present for n in lit)):
            raise ValueError(f"scene {render_pass.name} passes must come together ({', '.join(own + lit)}): "
                             f"{found[0]} needs the {missing[0]} pass")


def write_scene(path_stem, channels: dict, meta: dict) -> tuple[Path, Path]:
    """Write scene_NNNNNN.exr then scene_NNNNNN.json; returns their paths.

    `channels` maps each channel group of relight/files/scene_passes.py to [H, W, C] (or [H, W]
    for one plane): the geometry pass's always (head and the person masks optional); a
    per-light group as `<group>.LK` for every light K = 0..len(meta["lights"])-1; transport with
    (sh_order+1)^2 planes; `person.PK` for people K = 0..N-1 of a group, summing to alpha (and
    N = meta["people"]["count"] when meta has "people"). A pass's groups come together.
    `meta` needs `index`, `sh_order`, `lights`; other keys (seed, camera, body, pose,
    appearance, passes, versions, timings) are stored as given. This function fills
    `format`, `resolution`, `channels`, `exr_sha256`.
    """
    stem = Path(path_stem)
    if stem.suffix in (".exr", ".json"):
        stem = stem.with_suffix("")
    m = _STEM_RE.match(stem.name)
    if not m:
        raise ValueError(f"scene path must end in scene_NNNNNN, got {stem.name!r}")
    if not isinstance(meta, dict):
        raise ValueError("scene metadata must be a dict")
    for key in ("index", "sh_order", "lights"):
        if key not in meta:
            raise ValueError(f"scene metadata lacks {key!r}")
    if int(meta["index"]) != int(m.group(1)):
        raise ValueError(f"scene metadata index {meta['index']} != file name {stem.name}")
    order = int(meta["sh_order"])
    n = num_coeffs(order)
    lights = meta["lights"]
    if not isinstance(lights, list):
        raise ValueError("scene metadata 'lights' must be a list")
    for k, light in enumerate(lights):
        _check_light_meta(light, k, order)
    if not isinstance(channels, dict):
        raise ValueError("scene channels must be a dict of pass name -> array")

    planes: dict[str, np.ndarray] = {}
    hw = None
    for group in _REQUIRED:
        if group.name not in channels:
            raise ValueError(f"scene channels lack the required pass {group.name!r}")
        for suffix, plane in zip(group.suffixes, _as_planes(group.name, channels[group.name], len(group.suffixes), hw)):
            planes[f"{group.name}.{suffix}"] = plane
            hw = plane.shape
    keys = {}
    for name in channels:
        keys[name] = _group_of(name)
        if keys[name] is None:
            raise ValueError(f"unknown scene pass {name!r}")
    _check_passes_come_together({group.name for group, _ in keys.values()})
    for name, arr in channels.items():
        group, k = keys[name]
        if group in _REQUIRED:
            continue
        if group.kind == SH:
            for cname, plane in zip(transport_channel_names(n), _as_planes(name, arr, n, hw)):
                planes[cname] = plane
            continue
        if group.kind == PER_LIGHT and k >= len(lights):
            raise ValueError(f"pass {name!r} names light {k} but meta has {len(lights)} lights")
        for suffix, plane in zip(group.suffixes, _as_planes(name, arr, len(group.suffixes), hw)):
            planes[f"{name}.{suffix}"] = plane
    for group in GROUPS.values():
        present = {k for g, k in keys.values() if g is group and g.kind == PER_LIGHT}
        if present and present != set(range(len(lights))):
            raise ValueError(f"{group.name} passes cover lights {sorted(present)}, expected 0..{len(lights) - 1}")

    _check_people(planes, meta, f"scene {stem.name}")

    exr_path = stem.with_suffix(".exr")
    json_path = stem.with_suffix(".json")
    write_exr(exr_path, planes, compression="zip")
    sidecar = dict(meta)
    sidecar.update(
        format=FORMAT,
        index=int(meta["index"]),
        sh_order=order,
        resolution=[int(hw[0]), int(hw[1])],
        channels=sorted(planes),
        exr_sha256=file_sha256(exr_path),
    )
    try:
        text = json.dumps(sidecar, default=_json_default, allow_nan=False, indent=1)
    except ValueError as exc:
        raise ValueError(f"scene metadata has a non-finite number: {exc}") from None
    atomic_write_text(json_path, text + "\n")
    return exr_path, json_path


def _check_people(planes: dict, meta: dict, where: str) -> list[np.ndarray] | None:
    """The person masks of `planes` in order ([H, W] each), None when the scene has none;
    ValueError when they are not person.P0 .. P(N-1), disagree with meta["people"]["count"],
    leave [0, 1] or do not sum to alpha within PERSON_SUM_TOLERANCE."""
    found = sorted(int(m.group(1)) for c in planes if (m := re.fullmatch(r"person\.P(\d+)\.A", c)))
    people = meta.get("people")
    count = people.get("count") if isinstance(people, dict) else None
    if not found and count is None:
        return None
    if found != list(range(len(found))) or (count is not None and count != len(found)):
        raise ValueError(f"{where}: person masks {['P%d' % k for k in found]} are not P0..P{len(found) - 1}"
                         + (f" for the {count} people its sidecar records" if count is not None else ""))
    masks = [np.asarray(planes[f"person.P{k}.A"], dtype=np.float32) for k in found]
    low, high = min(float(m.min()) for m in masks), max(float(m.max()) for m in masks)
    if low < -PERSON_SUM_TOLERANCE or high > 1.0 + PERSON_SUM_TOLERANCE:
        raise ValueError(f"{where}: person masks leave [0, 1] (min {low:.3g}, max {high:.3g})")
    gap = float(np.max(np.abs(np.sum(masks, axis=0, dtype=np.float64) - planes["alpha.A"])))
    if gap > PERSON_SUM_TOLERANCE:
        raise ValueError(f"{where}: person masks do not sum to alpha (off by up to {gap:.3g})")
    return masks


def _check_light_meta(light, k: int, order: int) -> None:
    if not isinstance(light, dict):
        raise ValueError(f"light {k} metadata must be a dict")
    for key, rows in (("sh", num_coeffs(order)), ("sh8", 81)):
        if key not in light:
            raise ValueError(f"light {k} metadata lacks {key!r}")
        a = np.asarray(light[key], dtype=np.float64)
        if a.shape != (rows, 3):
            raise ValueError(f"light {k} {key!r} must have shape [{rows}, 3], got {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError(f"light {k} {key!r} contains NaN or Inf")


def _resolve(path) -> tuple[Path, Path]:
    p = Path(path)
    stem = p.with_suffix("") if p.suffix in (".exr", ".json") else p
    return stem.with_suffix(".exr"), stem.with_suffix(".json")


def read_sidecar(path) -> dict:
    """The JSON sidecar of a finished scene (path: the stem, its .exr or its .json),
    checked for its format and required keys; the EXR is not read."""
    _, json_path = _resolve(path)
    if not json_path.is_file():
        raise ValueError(f"scene {json_path.with_suffix('')} is not finished: {json_path.name} is missing")
    try:
        meta = json.loads(json_path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError) as exc:
        raise ValueError(f"scene sidecar {json_path} is not valid JSON: {exc}") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise ValueError(f"scene sidecar {json_path} is not {FORMAT!r}")
    for key in ("index", "sh_order", "lights", "resolution", "channels", "exr_sha256"):
        if key not in meta:
            raise ValueError(f"scene sidecar {json_path} lacks {key!r}")
    return meta


def traced_lights(meta: dict) -> list[int]:
    """Indices K of the sidecar's lights that have a path-traced image (image.LK)."""
    return [k for k in range(len(meta["lights"])) if f"image.L{k}.R" in meta["channels"]]


def has_transport(meta: dict) -> bool:
    """True when the scene holds the SH transport pass."""
    return "transport.00" in meta["channels"]


def light_map_name(light: dict) -> str:
    """The HDR map a sidecar light came from, lower case: its `name` (the farm's names tell
    maps apart, e.g. "forest" and "blender:forest"; its `source` is only the kind, "blender",
    "bundled" or "sky"), else its `source` file's stem."""
    name = light.get("name")
    if isinstance(name, str) and name:
        return name.lower()
    source = light.get("source")
    return Path(source).stem.split(".")[0].lower() if isinstance(source, str) else ""


def read_scene(path, *, verify_hash: bool = True) -> Scene:
    """Read and validate a finished scene (path: the stem, its .exr or its .json).

    ValueError when the scene is unfinished (no JSON), the EXR is missing or
    does not match the JSON's SHA-256, or channels/shapes disagree with the JSON.
    """
    exr_path, json_path = _resolve(path)
    meta = read_sidecar(json_path)
    if not exr_path.is_file():
        raise ValueError(f"scene {json_path.name} names a missing EXR {exr_path.name}")
    if verify_hash:
        digest = file_sha256(exr_path)
        if digest != meta["exr_sha256"]:
            raise ValueError(
                f"scene EXR {exr_path.name} does not match its sidecar (sha256 {digest[:12]}... "
                f"!= {str(meta['exr_sha256'])[:12]}...): partial or modified file"
            )
    order = int(meta["sh_order"])
    n = num_coeffs(order)
    lights = meta["lights"]
    for k, light in enumerate(lights):
        _check_light_meta(light, k, order)
    try:
        planes = read_exr(exr_path)
    except ValueError as exc:
        raise ValueError(f"scene EXR {exr_path.name} is unreadable: {exc}") from None
    if sorted(planes) != sorted(meta["channels"]):
        missing = sorted(set(meta["channels"]) - set(planes))
        extra = sorted(set(planes) - set(meta["channels"]))
        raise ValueError(f"scene EXR {exr_path.name} channels differ from sidecar: missing {missing}, extra {extra}")
    hw = tuple(meta["resolution"])
    for name, plane in planes.items():
        if plane.shape != hw:
            raise ValueError(f"scene channel {name} is {plane.shape}, sidecar says {hw}")

    def stack(names):
        missing = [c for c in names if c not in planes]
        if missing:
            raise ValueError(f"scene EXR {exr_path.name} lacks channels {missing}")
        return np.stack([planes[c] for c in names], axis=-1)

    groups = {}
    for render_pass in PASSES:
        own = [g for g in render_pass.groups if g.kind in (PLAIN, SH)]
        rendered = render_pass.always or any(c.startswith(f"{g.name}.") for g in own for c in planes)
        for g in own:
            if g.optional and not any(c.startswith(f"{g.name}.") for c in planes):
                continue
            if rendered and g.kind == SH:
                if sum(c.startswith(f"{g.name}.") for c in planes) != n:
                    raise ValueError(f"scene EXR {exr_path.name} has the wrong number of {g.name} channels "
                                     f"for order {order}")
                groups[g.name] = stack(scene_passes.sh_channel_names(g.name, n))
            elif rendered:
                groups[g.name] = stack([f"{g.name}.{s}" for s in g.suffixes])
        for g in render_pass.groups:
            if g.kind == PER_LIGHT and any(c.startswith(f"{g.name}.L") for c in planes):
                groups[g.name] = [stack([f"{g.name}.L{k}.{s}" for s in g.suffixes]) for k in range(len(lights))]
    masks = _check_people(planes, meta, f"scene EXR {exr_path.name}")
    if masks is not None:
        groups["person"] = [m[..., None] for m in masks]
    parsed_lights = []
    for light in lights:
        entry = dict(light)
        entry["sh"] = np.asarray(light["sh"], dtype=np.float64)
        entry["sh8"] = np.asarray(light["sh8"], dtype=np.float64)
        parsed_lights.append(entry)
    return Scene(index=int(meta["index"]), exr_path=exr_path, json_path=json_path, meta=meta, groups=groups,
                 lights=parsed_lights)


def list_finished_scenes(folder) -> list[Path]:
    """Sidecar paths of finished scenes (JSON and EXR both present), by index.

    Cheap: does not hash the EXRs (read_scene does).
    """
    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"dataset folder does not exist: {folder}")
    found = []
    for json_path in folder.glob("scene_*.json"):
        m = _STEM_RE.match(json_path.stem)
        if m and json_path.with_suffix(".exr").is_file():
            found.append((int(m.group(1)), json_path))
    return [p for _, p in sorted(found)]
