"""Quality presets in the add-on: relight/quality.py's table as a Blender enum.

The table itself (model and working resolution per preset) is relight.quality,
the same one `relight image --quality` reads; the add-on only stores its keys
upper-cased (DRAFT, BALANCED, BEST: enum identifiers kept in .blend files).
Plain Python (no bpy), so it is testable.
"""

from __future__ import annotations

from relight import quality as core_quality

DEFAULT_QUALITY = core_quality.DEFAULT.upper()


def preset(key: str) -> core_quality.QualityPreset:
    """relight.quality's preset for the enum identifier `key` (any case); ValueError otherwise."""
    return core_quality.preset(key)


def enum_items() -> list[tuple[str, str, str]]:
    """(identifier, name, description) triples for a bpy EnumProperty, fastest first."""
    return [(p.key.upper(), p.label, p.description) for p in core_quality.PRESETS]


def network_options(key: str) -> dict:
    """The preset's test-time work beyond its working size: Relighter.decompose's `augment`
    (mirrored / rescaled runs averaged) and `refine` (light refinement iterations)."""
    p = core_quality.preset(key)
    return {"augment": p.augment, "refine": p.refine}
