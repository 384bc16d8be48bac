"""What the add-on remembers between operator runs: plain Python, no bpy datablocks.

Photos are keyed by their stable id (a custom property on the image, see
bl_images), never by bpy ID references, so undo, file reload, renaming or
deleting an image cannot leave a dangling pointer here.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import numpy as np

WORLD_CACHE_SIZE = 4  # lights of recent World node states (an environment map can be large)


@dataclass
class PhotoSession:
    """A photo decomposed once; relighting it again needs no network run."""

    photo_id: str               # the photo's stable id (bl_images.PHOTO_ID)
    source: str                 # the photo's name when last seen (for messages)
    photo: np.ndarray           # linear RGB [H, W, 3] at the photo's size, upright (as the network saw it)
    decomposition: Any          # relight.network.runtime.Decomposition
    model_path: str
    quality: str
    mask_key: tuple             # what mask it was run with (mode, image name)
    digest: str = ""            # hash of the photo's pixel values (the saved decomposition's key)
    preview: Any = None         # the decomposition over a screen-sized photo (large photos only)
    saved_to: str = ""          # the file this decomposition was last saved to
    dial_generation: int = 0    # bumped on every dial change: a late full-size result is dropped
    people: int = 0             # people the person matte found (AUTO mask), else 0
    orientation: int = 1        # the photo file's EXIF orientation: outputs are turned back by it (pixel_buffers)
    provisional: bool = False   # reopening: only the saved preview so far (photo and decomposition at preview size)
    photo_missing: str = ""     # reopened without its photo (why): the saved preview stays, the dials work on it
    advice: str = ""            # with photo_missing: what brings the full-size photo back, in the artist's words
    extras: dict = field(default_factory=dict)


SESSIONS: dict[str, PhotoSession] = {}        # photo id -> session
LIGHT_SOURCES: dict[tuple, Any] = {}          # (photo id, model, quality) -> Decomposition
WORLDS: OrderedDict = OrderedDict()           # World node-state hash -> (WorldLight, {order: SH})
RUNNING: dict[str, Any] = {}                  # "job": the network job; "dial": full size; "restore"
NOTICES: dict[str, str] = {}                  # photo id -> what reopening could not bring back (bl_session)


def remember_world(key: str, value: tuple) -> None:
    WORLDS[key] = value
    WORLDS.move_to_end(key)
    while len(WORLDS) > WORLD_CACHE_SIZE:
        WORLDS.popitem(last=False)


def clear() -> None:
    from ..logic import pixel_buffers

    pixel_buffers.BUFFERS.clear()
    SESSIONS.clear()
    NOTICES.clear()
    LIGHT_SOURCES.clear()
    WORLDS.clear()
    for key in list(RUNNING):
        job = RUNNING.pop(key)
        if hasattr(job, "cancel"):  # "restore_plans", "layers_queue": lists waiting for a worker
            job.cancel()
