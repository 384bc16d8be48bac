"""Which mask the network gets: the person matte, the network's own, the photo's alpha or
another image, as the panel's mask mode says. Plain Python."""

from __future__ import annotations

import numpy as np


MASK_MODES = ("AUTO", "NETWORK", "IMAGE_ALPHA", "IMAGE")
EMPTY_MASK_LEVEL = 1e-3  # a mask whose largest value is below this selects nothing


def choose_mask(mode: str, photo_shape: tuple[int, int], photo_alpha: np.ndarray | None,
                mask_rgb: np.ndarray | None = None, mask_alpha: np.ndarray | None = None,
                mask_name: str = "") -> np.ndarray | None:
    """The mask [H, W] in [0, 1] given to the network, or None when it is made otherwise.

    IMAGE_ALPHA uses the photo's alpha; IMAGE uses another image of the same
    size: its alpha when it has a non-constant one, else its grey level (mean
    of R, G, B as stored, as relight.files.photo.read_mask reads mask files).
    """
    if mode in ("AUTO", "NETWORK"):
        return None  # AUTO: the person matte, made by the worker; NETWORK: the relighting network's own
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


def mask_channels(stored: np.ndarray) -> tuple[np.ndarray, np.ndarray | None]:
    """(rgb [H, W, 3], alpha [H, W] or None) of a mask image's stored pixels [H, W, C]:
    one channel is repeated to three; alpha only when there are four."""
    rgb = stored[..., :3] if stored.shape[2] >= 3 else np.repeat(stored[..., :1], 3, axis=2)
    return rgb, stored[..., 3] if stored.shape[2] == 4 else None


def saved_mask_inputs(mask_key) -> dict:
    """The mask inputs of a saved decomposition's mask key (mode, name); an IMAGE mask's
    pixels are filled in by the caller, which reads them from Blender."""
    mode, name = mask_key
    return dict(mode=mode, rgb=None, alpha=None, name=name, use_photo_alpha=mode == "IMAGE_ALPHA",
                person=int(name) if mode == "AUTO" else 1)
