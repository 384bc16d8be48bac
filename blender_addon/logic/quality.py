"""Quality presets in the add-on: relight/network/quality.py's table as a Blender enum.

The table itself (model and working resolution per preset) is relight.network.quality,
the same one `relight image --quality` reads; the add-on only stores its keys
upper-cased (DRAFT, BALANCED, BEST: enum identifiers kept in .blend files), and
model_path_for finds the model file a preset runs. Plain Python (no bpy), so it is testable.
"""

from __future__ import annotations

from pathlib import Path

from relight.network import quality as core_quality

DEFAULT_QUALITY = core_quality.DEFAULT.upper()


def preset(key: str) -> core_quality.QualityPreset:
    """relight.network.quality's preset for the enum identifier `key` (any case); ValueError otherwise."""
    return core_quality.preset(key)


def enum_items() -> list[tuple[str, str, str]]:
    """(identifier, name, description) triples for a bpy EnumProperty, fastest first."""
    return [(p.key.upper(), p.label, p.description) for p in core_quality.PRESETS]


def network_options(key: str) -> dict:
    """The preset's test-time work beyond its working size: Relighter.decompose's `augment`
    (mirrored / rescaled runs averaged), `augment_until_agreed` (the rest skipped when the
    first agrees), `ensemble` (other networks averaged in) and `refine` (light refinement
    iterations): Relighter.decompose's keywords, as a hashable-valued dict."""
    p = core_quality.preset(key)
    return {"augment": p.augment, "refine": p.refine, "augment_until_agreed": p.augment_until_agreed,
            "ensemble": tuple(p.ensemble)}


def model_path_for(quality_key: str, override: str = "") -> Path:
    """The ONNX file to run: `override` when given, else the preset's registered model.

    A preset whose model is not registered falls back to the registry's
    default model (the working resolution still follows the preset).
    """
    if override:
        p = Path(override)
        if not p.is_file():
            raise ValueError(f"The model file '{override}' does not exist.")
        return p
    from relight.network import quality as core_quality

    core_quality.preset(quality_key)  # an unknown key is its own error
    try:
        p = core_quality.model_path(quality_key)  # the registry looked up now: tests point it elsewhere
    except ValueError:
        raise ValueError("No relighting model is installed: choose a model file (.onnx) in the panel.") from None
    if not p.is_file():
        raise ValueError(f"The relighting model '{p.name}' is missing from the installation.")
    return p
