"""Clips in: video files through PyAV, folders of numbered frames through relight.files.photo.

    clip = open_clip("in.mp4")                 # or a folder: frame_0001.png, frame_0002.png, ...
    clip.info                                  # ClipInfo: size, frame rate, frame count, audio
    for frame in clip.frames(start=0): ...     # Frame: index, linear float32 [H, W, 3], alpha, codes

Video files (.mp4 .mov .m4v .mkv .webm .avi) are read with PyAV, whose wheels
carry FFmpeg and its codecs (docs/video.md says why PyAV). Frames are 8-bit
(10/12-bit sources read through 16 bits), sRGB-encoded like photos, decoded
with the stream's own YCbCr matrix and range (untagged: BT.709 from 720 lines
up, else BT.601; limited range); an 8-bit frame keeps its codes beside the
linear image. A folder of frames is the files whose names end in a number, in
the number's order; every frame's header is read when the clip is opened
(relight.files.photo_header, the core's one header reader: no frame decoded),
so a frame whose header is damaged, whose size is refused or differs from the
first's is refused before any frame is decoded. Every failure to read is one
ValueError naming the file. Writing: relight.files.video_out.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import NamedTuple

import numpy as np

from relight.files.photo_header import ImageDamaged, PhotoHeader, open_photo, read_header
from relight.imaging.colour import decode_srgb_codes

__all__ = ["ClipInfo", "Frame", "FrameFolder", "VideoFile", "open_clip", "VIDEO_SUFFIXES", "FRAME_SUFFIXES",
           "DEFAULT_FPS", "MAX_FPS", "frame_number", "frame_spans", "decode_srgb", "import_av", "open_container",
           "prefetch"]

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".webm", ".avi")
FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".webp", ".bmp")
DEFAULT_FPS = Fraction(24)   # a folder of frames has no rate of its own
MAX_FPS = 1000
_NUMBER = re.compile(r"(\d+)(?!.*\d)")  # the last run of digits in a name


class Frame(NamedTuple):
    """One decoded frame: linear float32 [H, W, 3], the frame's alpha [H, W] (its person mask)
    or None, and its 8-bit sRGB codes [H, W, 3] when it came from 8-bit codes (video), else None."""

    index: int
    image: np.ndarray
    alpha: np.ndarray | None
    codes: np.ndarray | None


@dataclass(frozen=True)
class ClipInfo:
    """What a clip is: `frames` is exact for folders, the container's count (or duration x rate)
    for video files, None when neither is known."""

    path: Path
    kind: str                 # "video" or "frames"
    width: int
    height: int
    fps: Fraction
    frames: int | None
    audio: bool = False
    names: tuple[str, ...] = field(default=(), repr=False)   # frame file stems (folders)
    colour: dict = field(default_factory=dict, repr=False)   # video colour tags, copied to the output


def frame_spans(indices) -> str:
    """0-based frame indices as 1-based frame numbers in ranges: '3-5, 9'."""
    out, run = [], []
    for i in sorted(indices):
        if run and i == run[-1] + 1:
            run.append(i)
            continue
        if run:
            out.append(f"{run[0] + 1}" if len(run) == 1 else f"{run[0] + 1}-{run[-1] + 1}")
        run = [i]
    if run:
        out.append(f"{run[0] + 1}" if len(run) == 1 else f"{run[0] + 1}-{run[-1] + 1}")
    return ", ".join(out)


def frame_number(name: str) -> int | None:
    """The number a frame file's stem ends in (its last run of digits), or None."""
    m = _NUMBER.search(name)
    return int(m.group(1)) if m else None


# a frame's 8- or 16-bit sRGB codes -> linear float32: the one decoder (relight.imaging.colour), the photo's too
decode_srgb = decode_srgb_codes


# ------------------------------------------------------------------ folders of frames


class FrameFolder:
    """The numbered frames of a folder, their headers read when it is opened (`headers`), their
    pixels with relight.files.photo (alpha, when a frame has one, is returned as its mask)."""

    def __init__(self, path, fps: Fraction | None = None, max_pixels: int | None = None, files=None):
        self.path = Path(path)
        self.max_pixels = max_pixels
        if files is None:
            files = [p for p in self.path.iterdir() if p.is_file() and p.suffix.lower() in FRAME_SUFFIXES
                     and not p.name.startswith(".")]
        if not files:
            raise ValueError(f"{self.path}: no frames ({', '.join(FRAME_SUFFIXES)}) in the folder")
        numbered = {}
        for p in files:
            n = frame_number(p.stem)
            if n is None:
                raise ValueError(f"{self.path}: frame {p.name} has no number in its name (frames are "
                                 "ordered by the number their names end in: frame_0001.png, ...)")
            if n in numbered:
                raise ValueError(f"{self.path}: two frames are numbered {n}: {numbered[n].name} and {p.name}")
            numbered[n] = p
        self.files = [numbered[n] for n in sorted(numbered)]
        self.headers = self._headers()
        width, height = self.headers[0].upright_size
        self.info = ClipInfo(self.path, "frames", width, height, fps or DEFAULT_FPS, len(self.files),
                             names=tuple(p.stem for p in self.files))

    @classmethod
    def from_files(cls, files, fps: Fraction | None = None, max_pixels: int | None = None) -> "FrameFolder":
        """The clip of these frame files (one folder's image sequence; ordered by their numbers)."""
        files = [Path(f) for f in files]
        return cls(files[0].parent if files else Path("."), fps, max_pixels, files)

    def _headers(self) -> tuple[PhotoHeader, ...]:
        """Every frame's header (relight.files.photo_header.read_header: nothing decoded), its size
        weighed as read_photo will weigh it: a frame whose header, EXIF or PNG chunks are damaged,
        or whose size is refused (an ImageFileError naming it), or that is not the first's size
        (upright), is refused before any frame is decoded."""
        headers: list[PhotoHeader] = []
        for p in self.files:
            header = read_header(p, self.max_pixels)
            if headers and header.upright_size != headers[0].upright_size:
                (w, h), (w0, h0) = header.upright_size, headers[0].upright_size
                raise ValueError(f"{p}: frame is {w}x{h}, but {headers[0].path.name} is {w0}x{h0}: every frame "
                                 "of a clip must have one size")
            headers.append(header)
        return tuple(headers)

    def frames(self, start: int = 0):
        """Frames (linear float32 [H, W, 3], alpha [H, W] or None; codes None) from `start` on."""
        from relight.files.photo import read_photo

        for index in range(start, len(self.files)):
            image, alpha = read_photo(self.files[index], self.max_pixels)
            if image.shape[:2] != (self.info.height, self.info.width):  # a file changed since its header was read
                raise ValueError(f"{self.files[index]}: frame is {image.shape[1]}x{image.shape[0]}, the clip is "
                                 f"{self.info.width}x{self.info.height}")
            yield Frame(index, image, alpha, None)

    def codes(self):
        """Each frame's 8-bit sRGB codes [H, W, 3] uint8, upright: the PNG frames a resumable video
        job wrote (relight.files.video_out.FrameFolderWriter's video_codes), the codes the video
        encodes. Decoded from the header reader's open (open_photo)."""
        from relight.files.photo import upright

        for path in self.files:
            with open_photo(path, self.max_pixels) as (header, im):
                if im is None:
                    raise ValueError(f"{path}: an EXR frame holds no 8-bit codes")
                try:
                    codes = np.asarray(im if im.mode == "RGB" else im.convert("RGB"))
                except Exception as exc:  # Pillow's many types: the pixels after a whole header are broken
                    if isinstance(exc, MemoryError):
                        raise
                    raise ImageDamaged(path, f"{path}: corrupt or truncated image ({type(exc).__name__}: "
                                             f"{exc})") from None
            yield np.ascontiguousarray(upright(codes, header.orientation))


# ------------------------------------------------------------------ video files


def import_av():
    try:
        import av
    except ImportError:
        raise ValueError("reading and writing video files needs PyAV: pip install 'fullbody-relight[video]' "
                         "(or give a folder of frames)") from None
    return av


def open_container(path: Path):
    av = import_av()
    try:
        return av.open(str(path), mode="r")
    except (av.error.FFmpegError, UnicodeDecodeError, OSError) as exc:
        if isinstance(exc, OSError) and not isinstance(exc, av.error.FFmpegError):
            raise
        raise ValueError(f"{path}: not a readable video ({exc})") from None


class VideoFile:
    """A video file's first video stream, decoded frame by frame (PyAV, threaded decoding)."""

    def __init__(self, path, max_pixels: int | None = None):
        from relight.files.image_limits import check_declared_size

        self.path = Path(path)
        container = open_container(self.path)
        try:
            if container.format.name in ("image2", "gif") or container.format.name.endswith("_pipe"):
                raise ValueError(f"{self.path}: an image, not a video (relight image relights a photo; "
                                 "relight video takes a video file or a folder of frames)")
            if not container.streams.video:
                raise ValueError(f"{self.path}: no video stream in the file")
            stream = container.streams.video[0]
            ctx = stream.codec_context
            if ctx is None:  # a codec FFmpeg has no decoder for (or a damaged codec id)
                raise ValueError(f"{self.path}: the video stream's codec cannot be decoded")
            width, height = ctx.width, ctx.height
            check_declared_size(width, height, self.path, max_pixels=max_pixels,
                                bytes_per_pixel=64)  # a frame in flight through decode, relight, encode
            fps = stream.average_rate or stream.guessed_rate or stream.base_rate
            if not fps or not 0 < fps <= MAX_FPS:
                raise ValueError(f"{self.path}: the video stream has no usable frame rate ({fps})")
            self._slack = _slack(container, fps)
            self._held_s, hidden, shown = _check_whole(self.path, container, stream, fps, self._slack)
            count = (stream.frames - hidden if stream.frames else shown) or None  # the frames shown
            colour = {"colorspace": int(ctx.colorspace), "color_primaries": int(ctx.color_primaries),
                      "color_trc": int(ctx.color_trc), "color_range": int(ctx.color_range)}
            self.info = ClipInfo(self.path, "video", width, height, Fraction(fps), count,
                                 audio=bool(container.streams.audio), colour=colour)
        finally:
            container.close()

    def frames(self, start: int = 0):
        """Frames from `start` on (earlier frames are decoded and dropped: exact whatever the
        codec's keyframes); 8-bit streams keep their sRGB codes beside the linear image."""
        av = import_av()
        container = open_container(self.path)
        try:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            index, first, last = 0, None, None  # the decoded frames' timestamps (the stream's time base)
            try:
                for frame in container.decode(stream):
                    if frame.pts is not None:
                        first = frame.pts if first is None else min(first, frame.pts)
                        last = frame.pts if last is None else max(last, frame.pts)
                    if index >= start:
                        codes = self._codes(frame)
                        image = decode_srgb(codes)
                        yield Frame(index, image, None, codes if codes.dtype == np.uint8 else None)
                    index += 1
            except av.error.FFmpegError as exc:
                raise ValueError(f"{self.path}: cannot decode frame {index + 1} ({exc})") from None
            if index == 0:
                raise ValueError(f"{self.path}: the video stream holds no frames")
            fps = float(self.info.fps)
            decoded_s = index / fps if first is None else float((last - first) * stream.time_base) + 1 / fps
            if decoded_s < self._held_s - self._slack:  # packets the decoder dropped without an error
                raise ValueError(f"{self.path}: the video is damaged: {index} frames ({decoded_s:.2f} s) could "
                                 f"be decoded of the {self._held_s:.2f} s it holds (copy it again whole)")
        finally:
            container.close()

    def _codes(self, frame) -> np.ndarray:
        """The frame's sRGB codes [H, W, 3]: uint8, or uint16 for deeper streams."""
        if (frame.width, frame.height) != (self.info.width, self.info.height):
            raise ValueError(f"{self.path}: the frame size changes mid-stream ({frame.width}x{frame.height}, "
                             f"was {self.info.width}x{self.info.height})")
        deep = frame.format.name.endswith(("10le", "10be", "12le", "12be", "16le", "16be"))
        space = int(frame.colorspace)
        kwargs = {}
        if frame.format.name.startswith("yuv") or frame.format.name.startswith("nv"):
            if space in (2, 0):  # unspecified (or RGB-coded): the usual guess by height
                kwargs["src_colorspace"] = "itu709" if frame.height >= 720 else "itu601"
            kwargs["src_color_range"] = "JPEG" if int(frame.color_range) == 2 or frame.format.name.startswith(
                "yuvj") else "MPEG"
        return frame.to_ndarray(format="rgb48le" if deep else "rgb24", **kwargs)


def _slack(container, fps) -> float:
    """Seconds a whole file's timestamps may fall short of its declared length: a frame (the last
    one's duration may be unknown, a count derived from duration x rate rounds) plus one tick of
    the coarsest time base (Matroska's milliseconds) and of the container's microseconds."""
    ticks = [float(s.time_base) for s in container.streams if s.time_base]
    return 1 / float(fps) + max(ticks, default=0.0) + 1e-6


def _tag(stream, name: str):
    """A Matroska statistics tag (NUMBER_OF_FRAMES, DURATION; FFmpeg may add a language suffix)."""
    return next((v for k, v in stream.metadata.items() if k.split("-")[0].upper() == name), None)


def _declared(container, stream) -> tuple[int | None, float | None, float | None]:
    """What the container says of the video: (frames, the stream's seconds, the file's seconds), each
    None where it says nothing (a live recording's Matroska declares no length at all)."""
    frames = stream.frames or None
    if frames is None and (text := _tag(stream, "NUMBER_OF_FRAMES")) and str(text).strip().isdigit():
        frames = int(text) or None
    seconds = float(stream.duration * stream.time_base) if stream.duration and stream.time_base else None
    if seconds is None and (text := _tag(stream, "DURATION")):
        try:
            h, m, s = str(text).split(":")
            seconds = int(h) * 3600 + int(m) * 60 + float(s)
        except ValueError:
            seconds = None  # a tag we cannot read declares nothing
    whole = container.duration / 1_000_000 if container.duration and container.duration > 0 else None
    return frames, seconds, whole


def _check_whole(path: Path, container, stream, fps, slack: float) -> tuple[float, int, int]:
    """Refuse a video whose packets fall short of what its container declares (a file cut short:
    its header promises frames its body no longer has); returns the seconds of video it shows, the
    frames it hides (those before an edit list's start: decoded, never shown) and those it shows.
    Reads the packets only (no decoding): the frame count against the declared count, and the
    span of the timestamps against the declared durations, within `slack`."""
    av = import_av()
    frame_s = 1 / float(fps)
    packets, hidden, v0, v1, a0, a1 = 0, 0, None, None, None, None
    try:
        for packet in container.demux():
            t = packet.pts if packet.pts is not None else packet.dts
            if packet.size == 0 or t is None:  # the demuxer's flush packet
                continue
            video = packet.stream_index == stream.index
            packets += video  # with the frames before an edit list's start: the container counts them
            if packet.is_discard:  # ... but never shows them, nor counts them in its durations
                hidden += video
                continue
            tb = float(packet.time_base)
            start = t * tb
            end = start + (packet.duration * tb if packet.duration else frame_s if video else 0.0)
            if video:
                v0, v1 = min(v0 if v0 is not None else start, start), max(v1 if v1 is not None else end, end)
            a0, a1 = min(a0 if a0 is not None else start, start), max(a1 if a1 is not None else end, end)
    except av.error.FFmpegError:
        pass  # the body is damaged from here on: what was read is what it holds
    held_s = (v1 - v0) if v0 is not None else 0.0
    # a declared length may be an end time from 0 (Matroska's, a stream starting late): the span or the end
    reach, reach_all = max(held_s, v1 or 0.0), max(a1 - a0, a1) if a0 is not None else 0.0
    frames, seconds, whole = _declared(container, stream)
    short = ((frames is not None and packets < frames) or (seconds is not None and reach < seconds - slack)
             or (seconds is None and whole is not None and reach_all < whole - slack))
    if short:
        length = seconds if seconds is not None else whole
        said = frames if frames is not None else max(1, round(length * float(fps)))
        raise ValueError(f"{path}: the video is cut short: it declares {said} frames"
                         + (f" ({length:.2f} s)" if length is not None else "")
                         + f" but holds {packets} ({held_s:.2f} s): a truncated or damaged copy (copy it again whole)")
    return held_s, hidden, packets - hidden


def open_clip(path, fps: Fraction | None = None, max_pixels: int | None = None):
    """A FrameFolder for a folder, a VideoFile for a file; ValueError when it is neither."""
    path = Path(path)
    if not path.exists():
        raise ValueError(f"{path}: no such file or folder")
    if path.is_dir():
        return FrameFolder(path, fps, max_pixels)
    if path.stat().st_size == 0:
        raise ValueError(f"{path}: file is empty")
    clip = VideoFile(path, max_pixels)
    if fps is not None:
        raise ValueError("--fps applies to a folder of frames; a video file keeps its own frame rate")
    return clip


def prefetch(frames, depth: int = 2):
    """The frames of an iterator, decoded one or two ahead on a thread (decoding overlaps relighting)."""
    import queue
    import threading

    q: queue.Queue = queue.Queue(maxsize=depth)
    stop = threading.Event()
    end = object()

    def produce():
        try:
            for item in frames:
                while not stop.is_set():
                    try:
                        q.put(item, timeout=0.1)
                        break
                    except queue.Full:
                        continue
                if stop.is_set():
                    return
            q.put(end)
        except BaseException as exc:  # handed to the consumer, raised there
            q.put(exc)

    thread = threading.Thread(target=produce, daemon=True, name="relight-decode")
    thread.start()
    try:
        while True:
            item = q.get()
            if item is end:
                return
            if isinstance(item, BaseException):
                raise item
            yield item
    finally:
        stop.set()
        thread.join(timeout=5)
