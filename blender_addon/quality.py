"""Quality presets of the add-on: Draft/Balanced/Best as Blender enum items.

The table itself (model and working resolution per preset) is
relight/quality.py, shared with `relight image --quality`; this module only
gives it the add-on's upper-case enum identifiers (stored in .blend files).
Plain Python (no bpy), so it is testable. `working_long_side` is the longest
side of the crop around the person that the network sees; relight.runtime
resamples to it and brings the layers back to the photo's own size.
"""

from __future__ import annotations

from dataclasses import dataclass

from relight import quality as core_quality


@dataclass(frozen=True)
class QualityPreset:
    key: str                 # enum identifier used by the add-on's property
    label: str               # what the UI shows
    model: str | None        # name in relight.models' registry; None: its default model
    working_long_side: int   # pixels on the longest side given to the network
    description: str


# Ordered from fastest to best, as in relight.quality.PRESETS.
QUALITY_PRESETS: tuple[QualityPreset, ...] = tuple(
    QualityPreset(p.key.upper(), p.label, p.model, p.working_size, p.description) for p in core_quality.PRESETS)

DEFAULT_QUALITY = core_quality.DEFAULT.upper()


def preset(key: str) -> QualityPreset:
    """The preset called `key` (DRAFT, BALANCED or BEST); ValueError otherwise."""
    for p in QUALITY_PRESETS:
        if p.key == key:
            return p
    names = ", ".join(p.key for p in QUALITY_PRESETS)
    raise ValueError(f"unknown quality preset {key!r}; expected one of {names}")


def enum_items() -> list[tuple[str, str, str]]:
    """(identifier, name, description) triples for a bpy EnumProperty."""
    return [(p.key, p.label, p.description) for p in QUALITY_PRESETS]
