"""Short ground-truth clips: one person moving in front of a fixed camera, frame by frame.

    python -m farm --out clips/ --scenes 96 --seed 7 --clip-frames 32 --motion turn \\
                   --res 128 --lights 2 --light-pool heldout

A job module for the farm's executors (like farm.scene: SceneOptions and
render_scene): scene index i is frame i mod F of clip i // F (F = --clip-frames),
written as the ordinary scene file scene_{i:06d} with every per-frame buffer,
so resume, validation, retries and Ray work as for stills. A clip is the
scene that farm.scene draws for index i // F (body, clothes, camera, lights
and the bake's random directions: the same for every frame) with the whole
person moved rigidly per frame:

* ``turn``: turning in place about the vertical through the body's centre,
  TURN_DEGREES over the clip;
* ``sway``: shifting weight, a roll about the axis through the feet along the
  camera's view, SWAY_DEGREES either way, one period per clip.

Rigid motion keeps the clothes on the body and the texture on the clothes
(pattern space is the rest pose). The lights stay fixed in the world, so
light 0 of every frame is one shot's light and light k > 0 the truth of
relighting that shot. The sidecar's "clip" record says which clip, frame and
motion. A worker keeps the last clip's drawn scene (drawing the body costs
about 3 s, a 128 px frame about 1 s), so frames of one clip sent to one worker
draw it once.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from farm import scene as scene_module
from farm.synthesis.scene_options import SceneOptions as _BaseOptions

MOTIONS = ("turn", "sway")
TURN_DEGREES = 60.0   # a slow turn: 2 degrees a frame over 30 frames (48 degrees/s at 24 fps)
SWAY_DEGREES = 3.0    # roll amplitude of the weight shift
MAX_CLIP_FRAMES = 1000


@dataclass(frozen=True)
class SceneOptions(_BaseOptions):
    """farm.synthesis.scene_options.SceneOptions plus the clip's length and motion (recorded in every sidecar)."""

    clip_frames: int = 32
    motion: str = "turn"

    def validate(self) -> None:
        super().validate()
        if isinstance(self.clip_frames, bool) or not isinstance(self.clip_frames, (int, np.integer)) \
                or not 2 <= self.clip_frames <= MAX_CLIP_FRAMES:
            raise ValueError(f"SceneOptions.clip_frames must be an integer in [2, {MAX_CLIP_FRAMES}], "
                             f"got {self.clip_frames!r}")
        if self.motion not in MOTIONS:
            raise ValueError(f"SceneOptions.motion must be one of {MOTIONS}, got {self.motion!r}")
        if self.people != "1":  # a clip moves one person (a group's clips: issue 47, item 5)
            raise ValueError(f"SceneOptions.people must be '1' for clips, got {self.people!r}")

    @classmethod
    def from_json(cls, settings: dict) -> "SceneOptions":
        return cls(**dict(settings, passes=frozenset(settings["passes"])))

    def scene_options(self) -> _BaseOptions:
        """The options of the still scene a clip is drawn from."""
        fields = {k: v for k, v in self.__dict__.items() if k not in ("clip_frames", "motion")}
        return _BaseOptions(**fields)


def clip_frame(index: int, frames: int) -> tuple[int, int]:
    """(clip, frame) of scene index `index` in clips of `frames` frames."""
    return index // frames, index % frames


def motion_transform(motion: str, frame: int, frames: int) -> tuple[np.ndarray, float]:
    """(rotation [3, 3] applied about the pivot, angle in degrees) of `frame` of a clip."""
    t = frame / max(1, frames - 1)
    if motion == "turn":
        angle = TURN_DEGREES * t
        c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
        return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]), angle
    angle = SWAY_DEGREES * math.sin(2.0 * math.pi * t)
    c, s = math.cos(math.radians(angle)), math.sin(math.radians(angle))
    return np.array([[c, 0.0, -s], [0.0, 1.0, 0.0], [s, 0.0, c]]), angle  # roll about world Y


def _axes_in_world(rotation: np.ndarray, camera) -> np.ndarray:
    """The roll of "sway" is about the camera's viewing direction projected on the ground, so
    the person leans left and right in the image whatever the camera's heading."""
    forward = camera.world_to_camera.T @ np.array([0.0, 1.0, 0.0])  # camera looks along its +Y
    heading = math.atan2(forward[1], forward[0]) - math.pi / 2
    c, s = math.cos(heading), math.sin(heading)
    turn = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
    return turn @ rotation @ turn.T


@dataclass
class ClipSample(scene_module.SceneSample):
    """A frame of a clip: the clip's scene with its person moved, recorded as scene `frame_index`."""

    frame_index: int = 0
    clip: dict | None = None

    def record(self) -> dict:
        return {**super().record(), "index": int(self.frame_index), "clip": self.clip}


_LAST: dict = {}  # the last clip's drawn scene in this process: {"key": ..., "sample": SceneSample}


def _clip_scene(clip: int, seed: int, options: _BaseOptions, render_sky):
    """(the clip's drawn scene, whether it was drawn now rather than kept from the last frame)."""
    key = (clip, seed, options)
    if _LAST.get("key") == key:
        return _LAST["sample"], False
    _LAST.clear()
    _LAST.update(key=key, sample=scene_module.draw_scene(clip, seed, options, render_sky=render_sky))
    return _LAST["sample"], True


def sample_frame(index: int, seed: int, options: SceneOptions, render_sky=None) -> ClipSample:
    """The scene of clip index // F with its person posed for frame index % F (no bpy)."""
    scene_module.check_request(index, seed, options)
    return draw_frame(index, seed, options, render_sky)


def draw_frame(index: int, seed: int, options: SceneOptions, render_sky=None) -> ClipSample:
    """sample_frame for a request already checked (farm.scene.check_request)."""
    clip, frame = clip_frame(index, options.clip_frames)
    base, drawn = _clip_scene(clip, seed, options.scene_options(), render_sky)
    rotation, angle = motion_transform(options.motion, frame, options.clip_frames)
    body = next((p for p in base.parts if p.name == "body"), base.parts[0])
    if options.motion == "turn":
        pivot = np.array([*body.vertices[:, :2].mean(axis=0), 0.0])
    else:
        rotation = _axes_in_world(rotation, base.camera)
        pivot = np.array([*body.vertices[:, :2].mean(axis=0), float(body.vertices[:, 2].min())])
    parts = [replace(p, vertices=(p.vertices - pivot) @ rotation.T + pivot, normals=p.normals @ rotation.T)
             for p in base.parts]
    fields = {f: getattr(base, f) for f in scene_module.SceneSample.__dataclass_fields__}
    # the drawing's timings belong to the frame that drew the scene; later frames kept it
    fields.update(parts=parts, options=options, timings=dict(base.timings) if drawn else {"clip_scene_kept": 0.0})
    if base.body_mesh is not None:  # the unclothed body moves with the clothes
        fields["body_mesh"] = ((base.body_mesh[0] - pivot) @ rotation.T + pivot, base.body_mesh[1])
    return ClipSample(**fields, frame_index=int(index),
                      clip={"clip": clip, "frame": frame, "frames": options.clip_frames,
                            "motion": options.motion, "angle_deg": round(angle, 6)})


def render_scene(index: int, seed: int, options: SceneOptions, out_dir: Path) -> Path:
    """Render frame index % F of clip index // F as scene `index`; returns its JSON path."""
    return scene_module.render_scene(index, seed, options, out_dir, sample_fn=draw_frame)
