"""Quality presets: the one table that maps Draft/Balanced/Best to a model and a working resolution.

Plain Python (no bpy) so the mapping is testable and the trade-off study can
edit one place. `working_long_side` is the longest side of the crop around
the person that the network sees; relight.runtime resamples to it and brings
the layers back to the photo's own size.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class QualityPreset:
    key: str                 # enum identifier used by the add-on's property
    label: str               # what the UI shows
    model: str | None        # name in relight.models' registry; None: its default model
    working_long_side: int   # pixels on the longest side given to the network
    description: str


# Ordered from fastest to best; the sizes are relight.runtime.QUALITY_SIZES.
# Until several trained models ship, every preset runs the registry's default
# model and only the working size differs (docs/addon.md has the timings).
QUALITY_PRESETS: tuple[QualityPreset, ...] = (
    QualityPreset("DRAFT", "Draft", None, 256,
                  "Fast preview: the network sees the person at 256 px"),
    QualityPreset("BALANCED", "Balanced", None, 512,
                  "The network sees the person at 512 px"),
    QualityPreset("BEST", "Best", None, 1024,
                  "The network sees the person at 1024 px (slowest)"),
)

DEFAULT_QUALITY = "BALANCED"


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
