"""The output folder of a farm run: scene file names, validation, resume, cleanup, free space.

Every executor (local pool, Ray) asks these questions of the same folder: which
scenes of this range are finished, is a scene the runner was told about valid
(relight.files.dataset reads it, hash and finite pixels), which stray files of an
unfinished scene to delete, and is there room on the disk for the next one.
"""

from __future__ import annotations

import os
import re
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from farm.execution.run_config import FarmError, RunConfig

WORKER_LOG_DIR = "farm_logs"
# Any file of scene NNNNNN: finals (scene_NNNNNN.exr/.json) and the temps of
# atomic writes (.scene_NNNNNN.exr.XXXX.tmp.exr).
SCENE_FILE = re.compile(r"^\.?scene_(\d{6})(?=[._])")
# Zip-compressed float32 EXRs are at most about their raw size; the JSON
# sidecar (SH of K lights at order 8, body and pose) stays well under 1 MiB.
SIDECAR_ALLOWANCE = 1 << 20


def json_path(out: Path, index: int) -> Path:
    return Path(out) / f"scene_{index:06d}.json"


def exr_path(out: Path, index: int) -> Path:
    return Path(out) / f"scene_{index:06d}.exr"


@dataclass
class SceneCheck:
    """What the runner learns from a finished, valid scene."""

    index: int
    bytes: int
    path_traced: int
    skipped_passes: list[str]
    timings: dict


def _skipped_passes(meta: dict) -> list[str]:
    """Passes the scene code recorded as skipped (sidecar "passes"), plus a skipped
    specular bake (sidecar "bake")."""
    passes = meta.get("passes") or {}
    skipped = passes.get("skipped", []) if isinstance(passes, dict) else []
    names = {str(k) for k in skipped}
    bake = meta.get("bake")
    if isinstance(bake, dict) and str(bake.get("specular", "")).startswith("skipped"):
        names.add("specular")
    return sorted(names)


def check_scene(out: Path, index: int) -> SceneCheck:
    """Validate scene `index` in `out` with relight.files.dataset: sidecar present, EXR hash
    matches, channels as the sidecar lists them, and every pixel finite.

    Raises ValueError naming the problem.
    """
    from relight.files.dataset import read_scene

    scene = read_scene(json_path(out, index))
    if scene.index != index:
        raise ValueError(f"scene {index}: sidecar says index {scene.index}")
    for name, pixels in scene.groups.items():  # every channel group of relight/files/scene_passes.py it has
        planes = pixels if isinstance(pixels, list) else [pixels]
        if not all(np.isfinite(plane).all() for plane in planes):
            raise ValueError(f"scene {index}: {name} has NaN or Inf pixels")
    return SceneCheck(
        index=index,
        bytes=scene.exr_path.stat().st_size + scene.json_path.stat().st_size,
        path_traced=len(scene.images or []),
        skipped_passes=_skipped_passes(scene.meta),
        timings=scene.meta.get("timings") or {},
    )


def finished_indices(out: Path, indices) -> set[int]:
    """Indices of this range whose scene is finished (sidecar and EXR present; not hashed)."""
    from relight.files.dataset import list_finished_scenes

    wanted = set(indices)
    found = {int(p.stem.split("_")[1]) for p in list_finished_scenes(out)}
    return found & wanted


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def remove_partial_files(out: Path, index: int, keep_finished: bool) -> list[str]:
    """Delete the temps (and, unless keep_finished, the finals) of one scene; returns names."""
    finals = {json_path(out, index).name, exr_path(out, index).name}
    removed = []
    for path in Path(out).glob(f"*scene_{index:06d}*"):
        m = SCENE_FILE.match(path.name)
        if not m or int(m.group(1)) != index:
            continue
        if keep_finished and path.name in finals:
            continue
        _remove(path)
        removed.append(path.name)
    return removed


def clean_unfinished(out: Path, indices, finished: set[int]) -> list[str]:
    """Remove stray files of this run's scenes (temps; EXRs without sidecar); never finished ones.

    Only this run's index range is touched: other machines may be writing
    other ranges into the same folder.
    """
    wanted = set(indices)
    touched = set()
    for path in Path(out).iterdir():
        m = SCENE_FILE.match(path.name)
        if m and int(m.group(1)) in wanted:
            touched.add(int(m.group(1)))
    removed = []
    for index in sorted(touched):
        removed += remove_partial_files(out, index, keep_finished=index in finished)
    return removed


def expected_scene_bytes(config: RunConfig) -> int:
    s = config.scene
    return s.expected_channels() * s.resolution * s.resolution * 4 + SIDECAR_ALLOWANCE


def prepare_output(config: RunConfig) -> None:
    """Create the output folder and prove it is writable; FarmError otherwise."""
    out = config.out
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".farm_write_probe.{os.getpid()}"
        probe.write_bytes(b"ok")
        probe.unlink()
    except OSError as exc:
        raise FarmError(f"output folder {out} is not writable: {exc.strerror or exc}") from None



def plan_run(config: RunConfig) -> tuple[list[int], list[int], list[str]]:
    """(todo, skipped, removed stray files) after checking the output folder."""
    prepare_output(config)
    finished = finished_indices(config.out, config.indices)
    if finished and not config.resume:
        raise FarmError(
            f"{config.out} already holds {len(finished)} finished scenes of this range; "
            "pass --resume to keep them and render the rest"
        )
    removed = clean_unfinished(config.out, config.indices, finished)
    todo = [i for i in config.indices if i not in finished]
    return todo, sorted(finished), removed


def disk_room(config: RunConfig, scenes_in_flight: int, largest_seen: int) -> str | None:
    """None when the output disk has room for one more scene, else the reason."""
    need = max(expected_scene_bytes(config), largest_seen) * (scenes_in_flight + 1)
    try:
        free = shutil.disk_usage(config.out).free
    except OSError as exc:
        return f"cannot read free space of {config.out}: {exc.strerror or exc}"
    if free < need:
        return (f"output disk full: {free / 2**20:.1f} MiB free in {config.out}, "
                f"{need / 2**20:.1f} MiB needed for the next scene")
    return None
