"""What the add-on remembers between operator runs: plain Python, no bpy datablocks.

Only names of images are kept (never bpy ID references), so undo, file reload
or deleting an image cannot leave a dangling pointer here.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass
class PhotoSession:
    """A photo decomposed once; relighting it again needs no network run."""

    source: str                 # name of the photo's image datablock
    photo: np.ndarray           # linear RGB [H, W, 3] at the photo's size
    decomposition: Any          # relight.runtime.Decomposition
    model_path: str
    quality: str
    mask_key: tuple             # what mask it was run with (mode, image name)


SESSIONS: dict[str, PhotoSession] = {}        # photo name -> session
LIGHT_SOURCES: dict[tuple, Any] = {}          # (image name, model, quality) -> Decomposition
WORLDS: dict[str, tuple] = {}                 # world name -> (fingerprint, WorldLight, {order: SH})
RUNNING: dict[str, Any] = {}                  # "job" -> the one BackgroundJob in flight


def clear() -> None:
    SESSIONS.clear()
    LIGHT_SOURCES.clear()
    WORLDS.clear()
    job = RUNNING.pop("job", None)
    if job is not None:
        job.cancel()
