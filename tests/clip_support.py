"""Small generated clips of a real person for the video tests (tests/test_clip.py,
tests/test_cli_video.py): the bundled photo of Grace Hopper (relight/data/examples)
walking across a textured background, so the person matte finds her in every frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
PHOTO = REPO / "relight" / "data" / "examples" / "grace_hopper.jpg"
H, W = 90, 160


def _person(height: int) -> np.ndarray:
    from relight.photo import read_photo
    from relight.resample import resize_linear

    img, _ = read_photo(PHOTO)
    return resize_linear(img, height, int(round(img.shape[1] * height / img.shape[0])))


def background(h: int = H, w: int = W, tint=(0.10, 0.12, 0.15)) -> np.ndarray:
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    r, g, b = tint
    return np.stack([r + 0.05 * np.sin(x / 7), g + 0.03 * np.cos(y / 5), b + 0.04 * np.sin((x + y) / 9)],
                    axis=-1).astype(np.float32)


def person_clip(n: int, h: int = H, w: int = W, step: int = 1, start: int = 30, tint=(0.10, 0.12, 0.15)):
    """n linear float32 frames [h, w, 3]: the person moved `step` px right each frame."""
    person = _person(h)
    bg = background(h, w, tint)
    frames = []
    for i in range(n):
        f = bg.copy()
        x0 = start + step * i
        span = min(person.shape[1], w - x0)
        f[:, x0:x0 + span] = person[:, :span]
        frames.append(f)
    return frames


def two_shots(n1: int, n2: int) -> list[np.ndarray]:
    """A cut: n1 frames of one shot, then n2 of another (warm background, the person further left)."""
    return person_clip(n1) + person_clip(n2, start=10, tint=(0.45, 0.30, 0.12))


def write_frames(folder: Path, frames, fmt: str = "png", prefix: str = "f_") -> Path:
    from relight.photo import write_image

    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        write_image(folder / f"{prefix}{i + 1:04d}.{fmt}", f)
    return folder


def write_video(path: Path, frames, fps=24) -> Path:
    from fractions import Fraction

    from relight.video_io import ClipInfo
    from relight.video_out import VideoWriter

    h, w = frames[0].shape[:2]
    writer = VideoWriter(path, ClipInfo(Path(path), "frames", w, h, Fraction(fps), len(frames)))
    for f in frames:
        writer.write(f)
    return writer.close()
