"""Named HDR light presets.

Plain names ("venice", "studio", ...) are the 18 CC0 Poly Haven maps bundled
in relight/data/hdri (from @pmndrs/assets 1.7.0). Names "blender:<name>" are
the 8 studio-light worlds inside Blender's data files, available only where
bpy can be imported (bpy is imported on first use, never at module import).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path

__all__ = [
    "HDRI_DIR",
    "HELD_OUT",
    "BLENDER_PREFIX",
    "list_presets",
    "list_blender_presets",
    "training_presets",
    "preset_path",
]

HDRI_DIR = Path(__file__).resolve().parent / "data" / "hdri"
# the lights of the held-out evaluation: never used for training
HELD_OUT = frozenset({"venice", "esplanade", "workshop", "lobby"})
BLENDER_PREFIX = "blender:"


def list_presets() -> list[str]:
    """Names of the bundled maps, sorted."""
    return sorted(p.stem for p in HDRI_DIR.glob("*.exr"))


def _blender_world_dir() -> Path | None:
    if importlib.util.find_spec("bpy") is None:
        return None
    import bpy  # only here: relight must not pull in bpy at import time

    folder = bpy.utils.system_resource("DATAFILES", path="studiolights/world")
    return Path(folder) if folder and Path(folder).is_dir() else None


def list_blender_presets() -> list[str]:
    """"blender:<name>" for each map in Blender's studiolights/world; [] without bpy."""
    folder = _blender_world_dir()
    if folder is None:
        return []
    return sorted(BLENDER_PREFIX + p.stem for p in folder.glob("*.exr"))


def training_presets(include_blender: bool = False) -> list[str]:
    """Preset names allowed in training sets (everything except HELD_OUT)."""
    names = [n for n in list_presets() if n not in HELD_OUT]
    if include_blender:
        names += list_blender_presets()
    return names


def preset_path(name: str) -> Path:
    """Path of a preset's EXR; ValueError naming the known presets if unknown."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"preset name must be a non-empty string, got {name!r}")
    if name.startswith(BLENDER_PREFIX):
        folder = _blender_world_dir()
        if folder is None:
            raise ValueError(f"preset {name!r} needs Blender (bpy), which is not importable here")
        path = folder / f"{name[len(BLENDER_PREFIX):]}.exr"
        if "/" in name or not path.is_file():
            raise ValueError(f"unknown Blender preset {name!r}; known: {', '.join(list_blender_presets())}")
        return path
    path = HDRI_DIR / f"{name}.exr"
    if "/" in name or "\\" in name or not path.is_file():
        raise ValueError(f"unknown preset {name!r}; known: {', '.join(list_presets())}")
    return path
