"""Named HDR light presets.

Plain names ("venice", "studio", ...) are the 18 CC0 Poly Haven maps bundled
in relight/data/hdri (from @pmndrs/assets 1.7.0). Names "blender:<name>" are
the 8 studio-light worlds inside Blender's data files, available only where
Blender is: the folder is found through the bpy module a host (Blender, the
farm) has already loaded, or else in the installed bpy wheel's data files;
this module never imports bpy.
"""

from __future__ import annotations

import importlib.util
import sys
from pathlib import Path

__all__ = [
    "HDRI_DIR",
    "HELD_OUT",
    "BLENDER_PREFIX",
    "list_presets",
    "list_blender_presets",
    "training_presets",
    "preset_path",
    "is_preset_name",
    "preset_file",
]

HDRI_DIR = Path(__file__).resolve().parent.parent / "data" / "hdri"
# the lights of the held-out evaluation: never used for training
HELD_OUT = frozenset({"venice", "esplanade", "workshop", "lobby"})
BLENDER_PREFIX = "blender:"


def list_presets() -> list[str]:
    """Names of the bundled maps, sorted."""
    return sorted(p.stem for p in HDRI_DIR.glob("*.exr"))


_WORLDS = Path("datafiles") / "studiolights" / "world"


def _blender_world_dir() -> Path | None:
    """Blender's studiolights/world folder, or None where there is no Blender."""
    bpy = sys.modules.get("bpy")  # loaded by the host (Blender, the farm): ask it
    if bpy is not None and hasattr(bpy, "utils"):
        folder = bpy.utils.system_resource("DATAFILES", path="studiolights/world")
        return Path(folder) if folder and Path(folder).is_dir() else None
    spec = importlib.util.find_spec("bpy")  # the bpy wheel, found without importing it
    for root in (spec.submodule_search_locations or []) if spec is not None else []:
        found = sorted(p for p in Path(root).glob(f"*/{_WORLDS}") if p.is_dir())
        if found:
            return found[-1]
    return None


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


def is_preset_name(name) -> bool:
    """True when `name` is a bundled preset's name or a "blender:" name (which
    preset_path then checks); the one test for "is this a preset?"."""
    return isinstance(name, str) and (name in list_presets() or name.startswith(BLENDER_PREFIX))


def preset_file(name) -> Path | None:
    """The EXR a preset name names, None when `name` names no preset (the light's "file or
    preset?" question, relight.lighting.light.map_file): a bundled map's file, or for a
    "blender:" name preset_path's (which refuses one Blender does not have)."""
    if not isinstance(name, str) or not name:
        return None
    if name.startswith(BLENDER_PREFIX):
        return preset_path(name)
    # a bundled map by its exact name (a case-insensitive file system would find "Venice.exr" too)
    return HDRI_DIR / f"{name}.exr" if name in list_presets() else None


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
