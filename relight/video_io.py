"""Clips in and out: video files through PyAV, folders of numbered frames through relight.photo.

    clip = open_clip("in.mp4")                 # or a folder: frame_0001.png, frame_0002.png, ...
    clip.info                                  # ClipInfo: size, frame rate, frame count, audio
    for frame in clip.frames(start=0): ...   # Frame: index, linear float32 [H, W, 3], alpha, codes
    out = VideoWriter("out.mp4", clip.info, audio_from=clip.path)
    out.write(relit); out.close()              # the file appears, complete, only at close()

Video files (.mp4 .mov .m4v .mkv .webm .avi in; .mp4 .mov .m4v .mkv .webm out) are
read and written with PyAV, whose wheels carry FFmpeg and its codecs
(docs/video.md says why PyAV). Frames are 8-bit (10/12-bit sources read
through 16 bits), sRGB-encoded like photos, decoded with the stream's own
YCbCr matrix and range (untagged: BT.709 from 720 lines up, else BT.601;
limited range). Output video is H.264 (VP9 for .webm), 4:2:0 when width and
height are even, else 4:4:4 so the size is kept; frame rate and colour tags
are kept and the audio of the source is copied (re-encoded when the output
container cannot hold its codec). A folder of frames is the files whose names
end in a number, in the number's order; every frame must have the size of the
first (checked before anything is decoded). Every failure to read is one
ValueError naming the file.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass, field
from fractions import Fraction
from pathlib import Path
from typing import NamedTuple

import numpy as np

from relight.fileio import temp_path_beside

__all__ = ["ClipInfo", "Frame", "FrameFolder", "VideoFile", "VideoWriter", "FrameFolderWriter", "open_clip",
           "VIDEO_SUFFIXES", "OUTPUT_VIDEO_SUFFIXES", "FRAME_SUFFIXES", "DEFAULT_FPS", "frame_number",
           "frame_spans", "frame_codes", "encode_srgb8", "decode_srgb"]

VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".webm", ".avi")
OUTPUT_VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".webm")
FRAME_SUFFIXES = (".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".webp", ".bmp")
DEFAULT_FPS = Fraction(24)   # a folder of frames has no rate of its own
MAX_FPS = 1000
H264_CRF = "18"              # visually lossless for most footage; the relit frames are 8-bit anyway
H264_PRESET = "veryfast"     # docs/BENCHMARKS.md: encoding is a small share of a frame's time at this preset
VP9_OPTIONS = {"crf": "30", "b:v": "0", "deadline": "good", "cpu-used": "5", "row-mt": "1"}
# audio codecs each container holds as they are (copied); others are re-encoded to its default
AUDIO_COPY = {".mp4": {"aac", "mp3", "alac", "ac3", "eac3", "opus", "flac"}, ".m4v": {"aac", "mp3", "ac3", "alac"},
              ".mov": {"aac", "mp3", "alac", "ac3", "pcm_s16le", "pcm_s24le", "pcm_f32le"},
              ".webm": {"opus", "vorbis"}, ".mkv": None}  # None: anything
AUDIO_REENCODE = {".webm": "libopus"}  # the rest: aac
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


def _srgb_table(levels: int) -> np.ndarray:
    from relight.colour import srgb_decode

    return srgb_decode(np.arange(levels, dtype=np.float64) / (levels - 1)).astype(np.float32)


_TABLES: dict[int, np.ndarray] = {}


def decode_srgb(codes: np.ndarray) -> np.ndarray:
    """8- or 16-bit sRGB code values -> linear float32 (an exact table per code value)."""
    levels = 256 if codes.dtype == np.uint8 else 65536
    if levels not in _TABLES:
        _TABLES[levels] = _srgb_table(levels)
    return _TABLES[levels][codes]


_ENCODE_BINS = 4096  # bins of sqrt(linear): each holds at most one rounding threshold (the closest two
                     # thresholds, near code 255, are 0.0039 apart in sqrt(linear))
_ENCODE: tuple[np.ndarray, np.ndarray] | None = None


def _encode_tables() -> tuple[np.ndarray, np.ndarray]:
    """(code at each sqrt bin's lower edge, the linear value where code k + 1 begins, k = 0..255)."""
    global _ENCODE
    if _ENCODE is None:
        from relight.colour import srgb_decode

        # rint(255 srgb_encode(x)) steps from k to k + 1 where srgb_encode(x) = (k + 0.5) / 255
        steps = srgb_decode((np.arange(255, dtype=np.float64) + 0.5) / 255.0)
        edges = (np.arange(_ENCODE_BINS + 1, dtype=np.float64) / _ENCODE_BINS) ** 2
        codes = np.searchsorted(steps, edges, side="right").astype(np.uint8)
        _ENCODE = codes, np.append(steps, np.inf).astype(np.float32)
    return _ENCODE


def encode_srgb8(linear: np.ndarray) -> np.ndarray:
    """Linear RGB -> 8-bit sRGB codes, clipped to [0, 1] and rounded: a table lookup in
    sqrt(linear) and one comparison with the next code's threshold, 3x faster than
    evaluating the curve on a 1080p frame. It gives rint(255 srgb_encode(x)) except within
    float32 rounding of a threshold (one code off, 1e-5 of random values); decoded codes
    (decode_srgb) come back exactly."""
    a = np.asarray(linear, np.float32)
    out = np.empty(a.shape, np.uint8)
    codes, steps = _encode_tables()
    rows = max(1, (1 << 18) // max(1, a[0].size)) if a.ndim > 1 else a.shape[0]
    for r0 in range(0, a.shape[0], rows):  # strips: temporaries stay in cache
        x = a[r0:r0 + rows]
        if not np.all(np.isfinite(x)):
            raise ValueError("frame to write contains NaN or Inf")
        x = np.clip(x, 0.0, 1.0)
        code = codes[(np.sqrt(x) * np.float32(_ENCODE_BINS)).astype(np.intp)]
        code += x >= steps[code]
        out[r0:r0 + rows] = code
    return out


def frame_codes(linear: np.ndarray, codes: np.ndarray | None = None, changed=None) -> np.ndarray:
    """encode_srgb8(linear), computed only inside `changed` = (y0, y1, x0, x1) when `codes`, the
    codes the frame was decoded from, are given (outside that box `linear` is the decoded
    frame, which encodes back to its codes exactly); changed None with codes: nothing changed."""
    if codes is None:
        return encode_srgb8(linear)
    out = codes.copy()
    if changed is not None:
        y0, y1, x0, x1 = changed
        out[y0:y1, x0:x1] = encode_srgb8(linear[y0:y1, x0:x1])
    return out


# ------------------------------------------------------------------ folders of frames


class FrameFolder:
    """The numbered frames of a folder, read with relight.photo (alpha, when a frame has
    one, is returned as its mask)."""

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
        width, height = self._sizes()
        self.info = ClipInfo(self.path, "frames", width, height, fps or DEFAULT_FPS, len(self.files),
                             names=tuple(p.stem for p in self.files))

    @classmethod
    def from_files(cls, files, fps: Fraction | None = None, max_pixels: int | None = None) -> "FrameFolder":
        """The clip of these frame files (one folder's image sequence; ordered by their numbers)."""
        files = [Path(f) for f in files]
        return cls(files[0].parent if files else Path("."), fps, max_pixels, files)

    def _sizes(self) -> tuple[int, int]:
        """The size every frame declares, read from headers only; ValueError at the first that differs."""
        first = None
        for p in self.files:
            size = _declared_size(p)
            if first is None:
                first = (p, size)
            elif size != first[1]:
                raise ValueError(f"{p}: frame is {size[0]}x{size[1]}, but {first[0].name} is "
                                 f"{first[1][0]}x{first[1][1]}: every frame of a clip must have one size")
        return first[1]

    def frames(self, start: int = 0):
        """Frames (linear float32 [H, W, 3], alpha [H, W] or None; codes None) from `start` on."""
        from relight.photo import read_photo

        for index in range(start, len(self.files)):
            image, alpha = read_photo(self.files[index], self.max_pixels)
            if image.shape[:2] != (self.info.height, self.info.width):  # a header that lied
                raise ValueError(f"{self.files[index]}: frame is {image.shape[1]}x{image.shape[0]}, the clip is "
                                 f"{self.info.width}x{self.info.height}")
            yield Frame(index, image, alpha, None)


def _declared_size(path: Path) -> tuple[int, int]:
    from relight.photo import EXR_MAGIC

    with open(path, "rb") as f:
        magic = f.read(4)
    if magic == EXR_MAGIC:
        from relight.exr import exr_size

        return tuple(exr_size(path))
    from PIL import Image

    try:
        with Image.open(path) as im:
            size = im.size
            orientation = im.getexif().get(0x0112, 1)  # EXIF rotations that swap the sides
            return (size[1], size[0]) if orientation in (5, 6, 7, 8) else size
    except Exception as exc:  # Pillow's many exception types: one ValueError naming the file
        if isinstance(exc, MemoryError):
            raise
        raise ValueError(f"{path}: not a readable image ({type(exc).__name__}: {exc})") from None


# ------------------------------------------------------------------ video files


def _av():
    try:
        import av
    except ImportError:
        raise ValueError("reading and writing video files needs PyAV: pip install 'fullbody-relight[video]' "
                         "(or give a folder of frames)") from None
    return av


def _open_input(path: Path):
    av = _av()
    try:
        return av.open(str(path), mode="r")
    except (av.error.FFmpegError, UnicodeDecodeError, OSError) as exc:
        if isinstance(exc, OSError) and not isinstance(exc, av.error.FFmpegError):
            raise
        raise ValueError(f"{path}: not a readable video ({exc})") from None


class VideoFile:
    """A video file's first video stream, decoded frame by frame (PyAV, threaded decoding)."""

    def __init__(self, path, max_pixels: int | None = None):
        from relight.photo import check_declared_size

        self.path = Path(path)
        container = _open_input(self.path)
        try:
            if container.format.name in ("image2", "gif") or container.format.name.endswith("_pipe"):
                raise ValueError(f"{self.path}: an image, not a video (relight image relights a photo; "
                                 "relight video takes a video file or a folder of frames)")
            if not container.streams.video:
                raise ValueError(f"{self.path}: no video stream in the file")
            stream = container.streams.video[0]
            ctx = stream.codec_context
            width, height = ctx.width, ctx.height
            check_declared_size(width, height, self.path, max_pixels=max_pixels,
                                bytes_per_pixel=64)  # a frame in flight through decode, relight, encode
            fps = stream.average_rate or stream.guessed_rate or stream.base_rate
            if not fps or not 0 < fps <= MAX_FPS:
                raise ValueError(f"{self.path}: the video stream has no usable frame rate ({fps})")
            count = stream.frames or None
            if count is None and stream.duration is not None and stream.time_base is not None:
                count = max(1, round(float(stream.duration * stream.time_base * fps)))
            elif count is None and container.duration:
                count = max(1, round(container.duration / 1_000_000 * float(fps)))
            colour = {"colorspace": int(ctx.colorspace), "color_primaries": int(ctx.color_primaries),
                      "color_trc": int(ctx.color_trc), "color_range": int(ctx.color_range)}
            self.info = ClipInfo(self.path, "video", width, height, Fraction(fps), count,
                                 audio=bool(container.streams.audio), colour=colour)
        finally:
            container.close()

    def frames(self, start: int = 0):
        """Frames from `start` on (earlier frames are decoded and dropped: exact whatever the
        codec's keyframes); 8-bit streams keep their sRGB codes beside the linear image."""
        av = _av()
        container = _open_input(self.path)
        try:
            stream = container.streams.video[0]
            stream.thread_type = "AUTO"
            index = 0
            try:
                for frame in container.decode(stream):
                    if index >= start:
                        codes = self._codes(frame)
                        image = decode_srgb(codes)
                        yield Frame(index, image, None, codes if codes.dtype == np.uint8 else None)
                    index += 1
            except av.error.FFmpegError as exc:
                raise ValueError(f"{self.path}: cannot decode frame {index + 1} ({exc})") from None
            if index == 0:
                raise ValueError(f"{self.path}: the video stream holds no frames")
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


# ------------------------------------------------------------------ writing


class FrameFolderWriter:
    """Frames into a folder, one file each, written atomically (a frame is there whole or not
    at all): PNG (8-bit sRGB) or EXR (linear float, optionally the layers for Blender).
    `names`: the file stem of each frame; None: frame_000001, frame_000002, ..."""

    def __init__(self, folder, fmt: str, names=None, video_codes: bool = False):
        if fmt not in ("png", "exr"):
            raise ValueError(f"frame format must be png or exr, got {fmt!r}")
        self.folder, self.fmt = Path(folder), fmt
        self.names = None if names is None else list(names)
        # PNGs holding exactly the codes VideoWriter.write would encode (a resumable video's frames)
        self.video_codes = video_codes and fmt == "png"

    def name(self, index: int) -> str:
        return f"frame_{index + 1:06d}" if self.names is None else self.names[index]

    def path(self, index: int) -> Path:
        return self.folder / f"{self.name(index)}.{self.fmt}"

    def done(self, index: int) -> bool:
        return self.path(index).is_file()

    def written(self) -> set[int]:
        """Indices of the frames already in the folder."""
        if self.names is not None:
            return {i for i in range(len(self.names)) if self.done(i)}
        if not self.folder.is_dir():
            return set()
        pattern = re.compile(rf"frame_(\d{{6,}})\.{self.fmt}")
        return {int(m.group(1)) - 1 for p in self.folder.iterdir() if (m := pattern.fullmatch(p.name))}

    def write(self, index: int, linear: np.ndarray, layers: dict | None = None, codes=None, changed=None) -> Path:
        """Write frame `index` (`codes`, `changed`: as frame_codes, for video_codes PNGs)."""
        from relight.photo import write_image, write_layers_exr

        if layers is not None:
            return write_layers_exr(self.path(index), linear, layers)
        if self.video_codes:
            from PIL import Image

            from relight.fileio import atomic_path

            with atomic_path(self.path(index), ".png") as tmp:
                Image.fromarray(frame_codes(linear, codes, changed), "RGB").save(tmp, format="PNG",
                                                                                  compress_level=1)
            return self.path(index)
        return write_image(self.path(index), linear)


class VideoWriter:
    """Frames into a video file. Everything goes to a temporary file beside the output,
    which replaces OUTPUT only when close() has finished it; abort() (or any error in
    close) removes it, so a video under OUTPUT's name is always complete."""

    def __init__(self, path, info: ClipInfo, audio_from=None):
        av = _av()
        self.path = Path(path)
        suffix = self.path.suffix.lower()
        if suffix not in OUTPUT_VIDEO_SUFFIXES:
            raise ValueError(f"video output must end in {', '.join(OUTPUT_VIDEO_SUFFIXES)}, got {self.path.name}")
        if not self.path.parent.is_dir():
            raise ValueError(f"output folder does not exist: {self.path.parent}")
        self.info = info
        self.count = 0
        self.tmp = temp_path_beside(self.path, suffix)
        self._audio = None
        try:
            self.container = av.open(str(self.tmp), mode="w")
            even = info.width % 2 == 0 and info.height % 2 == 0
            if suffix == ".webm":
                stream = self.container.add_stream("libvpx-vp9", rate=info.fps)
                stream.pix_fmt = "yuv420p" if even else "yuv444p"
                stream.options = dict(VP9_OPTIONS)
            else:
                stream = self.container.add_stream("libx264", rate=info.fps)
                stream.pix_fmt = "yuv420p" if even else "yuv444p"  # 4:2:0 needs even sides
                stream.options = {"crf": H264_CRF, "preset": H264_PRESET}
            stream.width, stream.height = info.width, info.height
            stream.thread_type = "AUTO"
            colour = {"colorspace": 1, "color_primaries": 1, "color_trc": 13, "color_range": 1}  # 709, sRGB curve
            colour.update({k: v for k, v in info.colour.items() if v not in (0, 2)})  # the source's, where tagged
            self._colour = colour
            for key, value in colour.items():
                setattr(stream.codec_context, key, value)
            self.stream = stream
            if audio_from is not None:
                self._audio = _AudioCopy(Path(audio_from), self.container, suffix)
        except BaseException as exc:
            self._discard()
            if isinstance(exc, av.error.FFmpegError):
                raise ValueError(f"{self.path}: cannot start the video ({exc})") from None
            raise

    def write(self, linear: np.ndarray, codes: np.ndarray | None = None, changed=None) -> None:
        """Append one frame (linear RGB [H, W, 3], encoded to 8-bit sRGB by frame_codes)."""
        self.write_codes(frame_codes(linear, codes, changed))

    def write_codes(self, codes: np.ndarray) -> None:
        """Append one frame of 8-bit sRGB codes [H, W, 3]."""
        av = _av()
        if codes.shape != (self.info.height, self.info.width, 3) or codes.dtype != np.uint8:
            raise ValueError(f"frame is {codes.shape} {codes.dtype}, the video is "
                             f"{self.info.height}x{self.info.width}x3 uint8")
        frame = av.VideoFrame.from_ndarray(codes, format="rgb24")
        space = "itu709" if self._colour["colorspace"] == 1 else "itu601"
        frame = frame.reformat(format=self.stream.pix_fmt, dst_colorspace=space,
                               dst_color_range="JPEG" if self._colour["color_range"] == 2 else "MPEG")
        frame.pts = self.count
        frame.time_base = 1 / Fraction(self.info.fps)
        self._mux(self.stream.encode(frame))
        self.count += 1
        if self._audio is not None:
            self._audio.copy_until(self.count / self.info.fps)

    def _mux(self, packets) -> None:
        try:
            self.container.mux(packets)
        except _av().error.FFmpegError as exc:
            _raise_write_error(self.path, exc)

    def close(self) -> Path:
        """Flush the encoder, copy the rest of the audio, and move the finished file to OUTPUT."""
        try:
            if self.count == 0:
                raise ValueError(f"{self.path}: no frames to write")
            self._mux(self.stream.encode(None))
            if self._audio is not None:
                self._audio.copy_until(None)
                self._audio.close()
                self._audio = None
            try:
                self.container.close()
            except _av().error.FFmpegError as exc:
                _raise_write_error(self.path, exc)
            self.container = None
            os.replace(self.tmp, self.path)
            return self.path
        except BaseException:
            self._discard()
            raise

    def abort(self) -> None:
        """Drop the unfinished video (its temporary file)."""
        self._discard()

    def _discard(self) -> None:
        for closing in (self._audio, getattr(self, "container", None)):
            if closing is not None:
                try:
                    closing.close()
                except Exception:  # noqa: BLE001 - tearing down after an error: the first error is the one to report
                    pass
        self._audio = None
        self.container = None
        self.tmp.unlink(missing_ok=True)


def _raise_write_error(path: Path, exc) -> None:
    import errno as errno_module

    code = getattr(exc, "errno", None)
    if code in (errno_module.ENOSPC, errno_module.EDQUOT) or "No space left" in str(exc):
        raise OSError(errno_module.ENOSPC, f"output disk full while writing {path.name}") from None
    raise OSError(code or errno_module.EIO, f"cannot write {path.name} ({exc})") from None


class _AudioCopy:
    """The source's first audio stream into the output, packet by packet as the video
    advances (kept interleaved): copied when the container holds its codec, else
    re-encoded to the container's usual codec."""

    def __init__(self, source: Path, container, suffix: str):
        self.input = _open_input(source)
        if not self.input.streams.audio:
            self.input.close()
            self.input = None
            return
        self.in_stream = self.input.streams.audio[0]
        name = self.in_stream.codec_context.name
        allowed = AUDIO_COPY.get(suffix)
        self.copy = allowed is None or name in allowed
        if self.copy:
            self.out_stream = container.add_stream_from_template(self.in_stream)
        else:
            self.out_stream = container.add_stream(AUDIO_REENCODE.get(suffix, "aac"),
                                                   rate=self.in_stream.codec_context.sample_rate or 48000)
            self._resampler = None
        self.container = container
        self._packets = self.input.demux(self.in_stream)
        self._pending = None

    def copy_until(self, seconds) -> None:
        """Mux the audio up to `seconds` of presentation time (None: all of it)."""
        if self.input is None:
            return
        av = _av()
        tb = self.in_stream.time_base
        while True:
            packet = self._pending or next(self._packets, None)
            self._pending = None
            if packet is None:
                break
            if packet.dts is None:  # the demuxer's empty flush packet
                continue
            if seconds is not None and packet.pts is not None and float(packet.pts * tb) > float(seconds):
                self._pending = packet
                return
            try:
                if self.copy:
                    packet.stream = self.out_stream
                    self.container.mux(packet)
                else:
                    for frame in packet.decode():
                        frame.pts = None
                        self.container.mux(self.out_stream.encode(frame))
            except av.error.FFmpegError as exc:
                _raise_write_error(Path(self.container.name), exc)
        if not self.copy:
            self.container.mux(self.out_stream.encode(None))
        self.input.close()
        self.input = None

    def close(self) -> None:
        if self.input is not None:
            self.input.close()
            self.input = None
