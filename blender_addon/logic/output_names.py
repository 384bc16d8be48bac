"""The add-on's names: the image datablocks a photo's layers go to, in the order they are
handed to Blender, and where a photo's decomposition is saved beside the .blend. Plain Python."""

from __future__ import annotations

import os


LAYERS = ("relit", "albedo", "shading", "residual", "alpha", "preview", "matte")
LAYER_ORDER = ("relit", "alpha", "albedo", "shading", "residual", "matte")  # relit first: what the user sees
# preview: screen-sized relit; matte: the photo cut out by the person matte (to check it)


def output_name(source: str, layer: str) -> str:
    """Name of the image datablock holding `layer` of `source`: '<source>.<layer>'."""
    if layer not in LAYERS:
        raise ValueError(f"unknown layer {layer!r}; expected one of {', '.join(LAYERS)}")
    return f"{source}.{layer}"


def source_of(name: str, existing: set[str] | frozenset[str] = frozenset()) -> str:
    """The photo an output image belongs to ('p.png.relit' -> 'p.png'); `name` when it is no output."""
    for layer in LAYERS:
        suffix = "." + layer
        if name.endswith(suffix) and name[: -len(suffix)] in existing:
            return name[: -len(suffix)]
    return name


def layers_in_order(buffers) -> list[str]:
    """The layers of `buffers` in the order they are handed to Blender (LAYER_ORDER)."""
    return [layer for layer in LAYER_ORDER if layer in buffers]


def saved_relight_path(blend_path: str, photo_id: str) -> str:
    """Where the decomposition of photo `photo_id` is kept for the .blend at `blend_path`:
    a folder next to it, '<name>_relight/<photo id>.npz'."""
    folder, name = os.path.split(blend_path)
    stem = os.path.splitext(name)[0]
    return os.path.join(folder, f"{stem}_relight", f"{photo_id}.npz")
