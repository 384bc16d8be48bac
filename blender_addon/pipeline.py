"""The add-on's logic without bpy: masks, light resolution, model lookup, compositing.

Everything here takes and returns numpy arrays and plain values, so it is
tested without Blender; the bpy layer only moves pixels in and out.
Messages of the ValueErrors raised here are shown to the user as they are:
one sentence each.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from . import quality

LAYERS = ("relit", "albedo", "shading", "residual", "alpha")
EMPTY_MASK_LEVEL = 1e-3  # a mask whose largest value is below this selects nothing


# ------------------------------------------------------------------ names

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


# ------------------------------------------------------------------ masks

MASK_MODES = ("AUTO", "IMAGE_ALPHA", "IMAGE")


def choose_mask(mode: str, photo_shape: tuple[int, int], photo_alpha: np.ndarray | None,
                mask_rgb: np.ndarray | None = None, mask_alpha: np.ndarray | None = None,
                mask_name: str = "") -> np.ndarray | None:
    """The mask [H, W] in [0, 1] given to the network, or None for the model's own matte.

    IMAGE_ALPHA uses the photo's alpha; IMAGE uses another image of the same
    size: its alpha when it has a non-constant one, else its grey level (mean
    of R, G, B as stored, as relight.photo.read_mask reads mask files).
    """
    if mode == "AUTO":
        return None
    if mode == "IMAGE_ALPHA":
        if photo_alpha is None:
            raise ValueError("The photo has no alpha channel to use as the mask.")
        mask = photo_alpha
    elif mode == "IMAGE":
        if mask_rgb is None:
            raise ValueError("Choose a mask image, or set the mask to Automatic.")
        if mask_rgb.shape[:2] != tuple(photo_shape):
            raise ValueError(f"The mask image '{mask_name}' is {mask_rgb.shape[1]}x{mask_rgb.shape[0]} "
                             f"but the photo is {photo_shape[1]}x{photo_shape[0]}.")
        if mask_alpha is not None and np.ptp(mask_alpha) > 0:
            mask = mask_alpha
        else:
            mask = mask_rgb[..., :3].mean(axis=2)
    else:
        raise ValueError(f"Unknown mask mode {mode!r}.")
    mask = np.clip(np.asarray(mask, dtype=np.float32), 0.0, 1.0)
    if not np.all(np.isfinite(mask)) or float(mask.max(initial=0.0)) < EMPTY_MASK_LEVEL:
        raise ValueError("The mask is empty: it selects no pixel of the photo.")
    return mask


# ------------------------------------------------------------------ lights

LIGHT_KINDS = ("WORLD", "HDR", "PRESET", "IMAGE")


def hdr_file_light(path: str, order: int) -> str:
    """The HDR file as a light for relight.runtime, after checking it reads as an equirect map."""
    from relight.runtime import resolve_light

    if not path:
        raise ValueError("Choose an HDR file for the light.")
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"The HDR file '{path}' does not exist.")
    try:
        resolve_light(str(p), order)  # projected once, then cached by the runtime
    except (ValueError, OSError) as exc:
        raise ValueError(f"The HDR file '{p.name}' cannot be read as an equirectangular map "
                         f"({_first_line(exc)}).") from None
    return str(p)


def preset_light(name: str, order: int) -> str:
    """The preset name as a light for relight.runtime, after checking it loads."""
    from relight.runtime import resolve_light

    try:
        resolve_light(name, order)
    except (ValueError, OSError) as exc:
        raise ValueError(f"The light preset '{name}' is not available ({_first_line(exc)}).") from None
    return name


def equirect_light(pixels: np.ndarray, order: int) -> np.ndarray:
    """SH light [n, 3] of an equirect map given as pixels (the World), scaled like HDR files.

    relight.runtime scales every map to the reference mean luminance; the
    World gets the same treatment so World, HDR file and preset agree.
    """
    from relight import envmap

    h, w = pixels.shape[:2]
    if w != 2 * h:
        raise ValueError(f"The World's environment image is {w}x{h}; an equirectangular map "
                         "is twice as wide as high.")
    try:
        return envmap.light_from_map(np.ascontiguousarray(pixels[..., :3]), order, normalize=True)
    except ValueError as exc:
        raise ValueError(f"The World gives no usable light ({_first_line(exc)}).") from None


def preset_names() -> list[str]:
    """Bundled presets, then Blender's own studio worlds when bpy is there."""
    from relight import presets

    return presets.list_presets() + presets.list_blender_presets()


def _first_line(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()
    return text[0].rstrip(".") if text else type(exc).__name__


# ------------------------------------------------------------------ model

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
    from relight import models
    from relight import quality as core_quality

    registry = models.load_registry(models.REGISTRY_PATH)  # looked up now: tests point it elsewhere
    name = core_quality.model_name(quality.preset(quality_key).key, registry)
    if name is None:
        raise ValueError("No relighting model is installed: choose a model file (.onnx) in the panel.")
    p = models.REGISTRY_PATH.parent / registry["models"][name]["file"]
    if not p.is_file():
        raise ValueError(f"The relighting model '{p.name}' is missing from the installation.")
    return p


# ------------------------------------------------------------------ compositing

def blend(relit: np.ndarray, photo: np.ndarray, strength: float) -> np.ndarray:
    """photo + strength * (relit - photo), float32 [H, W, 3].

    `relit` is the runtime's full frame (relit person composited over the
    untouched background), so strength 0 gives the photo back, 1 the relit
    photo, and the background never changes.
    """
    if relit.shape != photo.shape:
        raise ValueError(f"relit image {relit.shape} and photo {photo.shape} differ in size")
    s = float(np.clip(strength, 0.0, 1.0))
    if s == 1.0:
        return np.asarray(relit, dtype=np.float32)
    if s == 0.0:
        return np.array(photo, dtype=np.float32)
    out = np.subtract(relit, photo, dtype=np.float32)
    out *= np.float32(s)
    out += photo
    return out


def env_flag(name: str) -> bool:
    """True when environment variable `name` is set to 1/true/yes/on."""
    return os.environ.get(name, "").strip().lower() in {"1", "true", "yes", "on"}
