"""Small generated clips of a real person for the video tests (tests/relight/command/test_clip.py,
tests/relight/command/test_cli_video.py): the bundled photo of Grace Hopper (relight/data/examples)
walking across a textured background, so the person matte finds her in every frame."""

from __future__ import annotations

from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
PHOTO = REPO / "relight" / "data" / "examples" / "grace_hopper.jpg"
H, W = 90, 160


def _person(height: int) -> np.ndarray:
    from relight.files.photo import read_photo
    from relight.imaging.resample import resize_linear

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
    from relight.files.photo import write_image

    folder.mkdir(parents=True, exist_ok=True)
    for i, f in enumerate(frames):
        write_image(folder / f"{prefix}{i + 1:04d}.{fmt}", f)
    return folder


def write_video(path: Path, frames, fps=24, audio: str | None = None) -> Path:
    """A video of `frames` (linear float RGB) through relight's VideoWriter; with `audio` ("aac" or
    "libopus") a 440 Hz sine track beside it, written with PyAV directly (the source a user would have)."""
    from fractions import Fraction

    from relight.files.video_io import ClipInfo
    from relight.files.video_out import VideoWriter, encode_srgb8

    fps = Fraction(fps)
    h, w = frames[0].shape[:2]
    if audio is None:
        writer = VideoWriter(path, ClipInfo(Path(path), "frames", w, h, fps, len(frames)))
        for f in frames:
            writer.write(f)
        return writer.close()
    import av

    c = av.open(str(path), "w")
    v = c.add_stream("libx264", rate=fps)
    v.width, v.height, v.pix_fmt = w, h, "yuv420p"
    a = c.add_stream(audio, rate=48000)
    for i, f in enumerate(frames):
        frame = av.VideoFrame.from_ndarray(encode_srgb8(f), format="rgb24")
        frame.pts, frame.time_base = i, 1 / fps
        c.mux(v.encode(frame))
    total = int(48000 * len(frames) / fps)
    tone = (0.3 * np.sin(2 * np.pi * 440 * np.arange(total) / 48000)).astype(np.float32)
    for s0 in range(0, total, 960):
        chunk = tone[s0:s0 + 960]
        af = av.AudioFrame.from_ndarray(np.stack([chunk, chunk]), format="fltp", layout="stereo")
        af.sample_rate, af.pts, af.time_base = 48000, s0, Fraction(1, 48000)
        c.mux(a.encode(af))
    c.mux(a.encode(None))
    c.mux(v.encode(None))
    c.close()
    return Path(path)


# A still shot with sensor noise (issue 40, "Clips"): one photo, no motion, only noise changes
STILL_PHOTO = REPO / "relight" / "data" / "examples" / "astronaut.jpg"
STILL_MATTE = REPO / "evaluation" / "data" / "matte_eval" / "reference" / "astronaut.png"  # its person, by hand
NOISE_SIGMA = 2.0  # 8-bit sRGB codes: a clean sensor's noise, as in the issue


def noisy_still(n: int, height: int = 256, sigma: float = NOISE_SIGMA, seed: int = 0,
                photo: Path = STILL_PHOTO) -> list[np.ndarray]:
    """n linear float32 frames [height, w, 3] of one still photo: its sRGB codes (resized to
    `height`) plus independent Gaussian noise of `sigma` codes per pixel, channel and frame,
    rounded and clipped to 8 bits as a video's frames are (seeded: the same frames every run)."""
    from relight.imaging.colour import srgb_decode, srgb_encode
    from relight.files.photo import read_photo
    from relight.imaging.resample import resize_linear

    img, _ = read_photo(photo)
    codes = srgb_encode(resize_linear(img, height, int(round(img.shape[1] * height / img.shape[0])))) * 255.0
    rng = np.random.default_rng(seed)
    return [srgb_decode((np.clip(np.rint(codes + rng.normal(0.0, sigma, codes.shape)), 0, 255) / 255.0)
                        .astype(np.float32)).astype(np.float32) for _ in range(n)]


def still_region(height: int = 256, matte: Path = STILL_MATTE, photo: Path = STILL_PHOTO) -> np.ndarray:
    """[height, w] float32 in {0, 1}: the photo's person (its reference matte > 0.5), where the
    still shot's flicker is measured: fixed, so the measure does not move with the relighter's matte."""
    from relight.files.photo import read_photo
    from relight.imaging.resample import resize_linear

    img, _ = read_photo(photo)
    ref, _ = read_photo(matte)
    width = int(round(img.shape[1] * height / img.shape[0]))
    return (resize_linear(ref[..., 0], height, width) > 0.5).astype(np.float32)


def lowpass_flicker(frames, region: np.ndarray, block: int | None = None) -> float:
    """The low-pass frame-to-frame change of a clip over `region` [H, W]: model.evaluate_clips.flicker
    (mean over frame pairs of sum |X_t - X_t-1| / sum X_t) of the frames averaged over blocks of
    `block` x `block` pixels (default: 1/32 of the frame's height, 16 px at 512), the region's blocks
    those it mostly covers. The blocks average the photo's pixel noise away (by `block`), what the
    relighter changes at its working resolution (about 1/128 of the person) stays."""
    from model.evaluate_clips import flicker

    frames = np.stack(frames)
    h, w = frames.shape[1:3]
    k = block or max(1, int(round(h / 32)))
    hb, wb = h // k, w // k

    def blocks(x):  # [..., H, W, C] -> [..., hb, wb, C]
        x = x[..., :hb * k, :wb * k, :]
        return x.reshape(*x.shape[:-3], hb, k, wb, k, x.shape[-1]).mean(axis=(-4, -2))

    area = blocks(region[..., None].astype(np.float32))[..., 0]
    return flicker(blocks(frames.astype(np.float64)), np.broadcast_to(area, (len(frames), hb, wb)))


def grainy_video(path: Path, n: int = 30, fps=24, sigma: float = 8.0, seed: int = 0) -> Path:
    """A video of the walking person (3 px a frame) with film grain of `sigma` codes, written with
    PyAV as a camera or an editor writes one: an .mp4 / .mov with its index first (faststart), so
    that a copy cut short still opens and declares its length; the grain spreads the bytes evenly
    over the frames (a cut at 60 % of the bytes falls mid-clip, not in the first keyframe)."""
    from fractions import Fraction

    import av

    from relight.files.video_out import encode_srgb8

    rng = np.random.default_rng(seed)
    frames = person_clip(n, step=3)
    options = {"movflags": "faststart"} if Path(path).suffix in (".mp4", ".mov", ".m4v") else {}
    with av.open(str(path), "w", options=options) as c:
        v = c.add_stream("libx264", rate=Fraction(fps))
        v.width, v.height, v.pix_fmt = W, H, "yuv420p"
        for i, f in enumerate(frames):
            codes = np.clip(encode_srgb8(f) + rng.normal(0.0, sigma, f.shape), 0, 255).astype(np.uint8)
            frame = av.VideoFrame.from_ndarray(codes, format="rgb24")
            frame.pts, frame.time_base = i, 1 / Fraction(fps)
            c.mux(v.encode(frame))
        c.mux(v.encode(None))
    return Path(path)


def cut_short(path: Path, fraction: float, to: Path) -> Path:
    """The first `fraction` of the file's bytes, as an interrupted copy or download leaves it."""
    data = Path(path).read_bytes()
    Path(to).write_bytes(data[:int(len(data) * fraction)])
    return Path(to)
