"""The photo as the core takes it: linear float32 RGB [H, W, 3], finite. The one check,
shared by relight.network.runtime (decompose) and relight.person.matte (person_matte)."""

from __future__ import annotations

import numpy as np

__all__ = ["PhotoTooSmall", "check_photo"]

STRIP_ROWS = 1024  # rows scanned for NaN/Inf at a time: no full-size boolean temporary


class PhotoTooSmall(ValueError):
    """The photo has fewer pixels a side than what it is for needs (a caller that knows the
    photo's file names it)."""


def check_photo(photo, min_side: int = 2, *, finite: bool = True, purpose: str = "") -> np.ndarray:
    """`photo` as float32 (not copied when it is float32 already); ValueError, saying what to
    do, when it is not linear RGB [H, W, 3] of a floating type at least `min_side` px a side,
    or (with `finite`) holds NaN or Inf; `purpose` names what needs `min_side`. finite=False
    leaves that scan to a caller that reads every pixel anyway (relight.person.matte checks its
    block average)."""
    a = np.asarray(photo)
    if a.ndim == 2 or (a.ndim == 3 and a.shape[2] == 1):
        raise ValueError(f"photo is greyscale, shape {a.shape}: give linear RGB [H, W, 3] "
                         "(relight.files.photo.read_photo expands grey files to RGB)")
    if a.ndim == 3 and a.shape[2] in (2, 4):
        raise ValueError(f"photo has {a.shape[2]} channels (an alpha channel?): give linear RGB [H, W, 3]; "
                         "an alpha channel is a mask, not part of the photo")
    if a.ndim != 3 or a.shape[2] != 3:
        raise ValueError(f"photo must be linear RGB [H, W, 3], got shape {a.shape}")
    if not np.issubdtype(a.dtype, np.floating):
        raise ValueError(f"photo must be floating-point linear radiance, got dtype {a.dtype} "
                         "(decode 8/16-bit files with relight.files.photo.read_photo)")
    if min(a.shape[:2]) < min_side:
        raise PhotoTooSmall(f"photo is too small{' for ' + purpose if purpose else ''} ({a.shape[1]}x{a.shape[0]}; "
                            f"need at least {min_side} px a side)")
    a = a.astype(np.float32, copy=False)
    if finite:
        for r0 in range(0, a.shape[0], STRIP_ROWS):
            if not np.all(np.isfinite(a[r0:r0 + STRIP_ROWS])):
                raise ValueError("photo contains NaN or Inf")
    return a
