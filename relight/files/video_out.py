"""Clips out: video files through PyAV, folders of frames through relight.files.photo.

    out = VideoWriter("out.mp4", clip.info, audio_from=clip.info.path)
    out.write(relit); out.close()              # the file appears, complete, only at close()
    FrameFolderWriter("frames/", "png").write(index, relit)   # one whole file per frame

Output video (.mp4 .mov .m4v .mkv .webm) is H.264 (VP9 for .webm), 4:2:0 when
width and height are even, else 4:4:4 so the size is kept; the frame rate and
colour tags of the clip are kept (only those it has: output_colour) and the source's audio is copied (re-encoded
when the container cannot hold its codec). Frames are encoded to 8-bit sRGB by
encode_srgb8; where a frame is its decoded input, its input codes are kept
(frame_codes).
"""

from __future__ import annotations

import os
import re
from fractions import Fraction
from pathlib import Path

import numpy as np

from relight.files.fileio import temp_path_beside
from relight.files.png_encoder import encode_srgb8
from relight.files.video_io import ClipInfo, import_av, open_container

__all__ = ["VideoWriter", "FrameFolderWriter", "encode_srgb8", "frame_codes", "output_colour", "OUTPUT_VIDEO_SUFFIXES"]

OUTPUT_VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".mkv", ".webm")
H264_CRF = "18"              # visually lossless for most footage; the relit frames are 8-bit anyway
H264_PRESET = "veryfast"     # docs/BENCHMARKS.md: encoding is a small share of a frame's time at this preset
VP9_OPTIONS = {"crf": "30", "b:v": "0", "deadline": "good", "cpu-used": "5", "row-mt": "1"}
# audio codecs each container holds as they are (copied); others are re-encoded to its default
AUDIO_COPY = {".mp4": {"aac", "mp3", "alac", "ac3", "eac3", "opus", "flac"}, ".m4v": {"aac", "mp3", "ac3", "alac"},
              ".mov": {"aac", "mp3", "alac", "ac3", "pcm_s16le", "pcm_s24le", "pcm_f32le"},
              ".webm": {"opus", "vorbis"}, ".mkv": None}  # None: anything
AUDIO_REENCODE = {".webm": "libopus"}  # the rest: aac


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
        from relight.files.photo import write_image, write_layers_exr

        if layers is not None:
            return write_layers_exr(self.path(index), linear, layers)
        if self.video_codes:
            from PIL import Image

            from relight.files.fileio import atomic_path

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
        av = import_av()
        self.path = Path(path)
        suffix = self.path.suffix.lower()
        if suffix not in OUTPUT_VIDEO_SUFFIXES:
            raise ValueError(f"video output must end in {', '.join(OUTPUT_VIDEO_SUFFIXES)}, got {self.path.name}")
        self.info = info
        self.count = 0
        try:  # no check first: `relight video` has refused a missing folder at its arguments
            self.tmp = temp_path_beside(self.path, suffix)
        except FileNotFoundError:
            if self.path.parent.is_dir():
                raise
            raise ValueError(f"output folder does not exist: {self.path.parent}") from None
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
            self._colour = output_colour(info)
            for key, value in self._colour.items():
                setattr(stream.codec_context, key, value)
            self._space, self._range = _conversion(self._colour, info.height)
            self.stream = stream
            if audio_from is not None:
                self._audio = _AudioCopy(Path(audio_from), self.container, suffix, self.path)
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
        av = import_av()
        if codes.shape != (self.info.height, self.info.width, 3) or codes.dtype != np.uint8:
            raise ValueError(f"frame is {codes.shape} {codes.dtype}, the video is "
                             f"{self.info.height}x{self.info.width}x3 uint8")
        frame = av.VideoFrame.from_ndarray(codes, format="rgb24")
        frame = frame.reformat(format=self.stream.pix_fmt, dst_colorspace=self._space, dst_color_range=self._range)
        frame.pts = self.count
        frame.time_base = 1 / Fraction(self.info.fps)
        self._mux(self.stream.encode(frame))
        self.count += 1
        if self._audio is not None:
            self._audio.copy_until(self.count / self.info.fps)

    def _mux(self, packets) -> None:
        try:
            self.container.mux(packets)
        except import_av().error.FFmpegError as exc:
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
            except import_av().error.FFmpegError as exc:
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
                except Exception:  # tearing down after an error: the first error is the one to report
                    pass
        self._audio = None
        self.container = None
        self.tmp.unlink(missing_ok=True)


# FFmpeg's codes for "not said" (AVColorSpace, AVColorPrimaries, AVColorTransferCharacteristic:
# 2; AVColorRange: 0); colorspace 0 is RGB, which a YCbCr stream cannot be
_UNSPECIFIED = {"colorspace": (0, 2), "color_primaries": (0, 2), "color_trc": (0, 2), "color_range": (0,)}
# the matrices swscale converts with, by AVColorSpace code: BT.709, FCC, BT.601 (470BG, SMPTE 170M),
# SMPTE 240M, BT.2020 (non-constant luminance)
_MATRICES = {1: "itu709", 4: "fcc", 5: "itu601", 6: "smpte170m", 7: "smpte240m", 9: "bt2020"}
# a folder of frames holds sRGB images: BT.709 primaries (sRGB's), the sRGB curve, a BT.709 matrix, limited range
SRGB_TAGS = {"colorspace": 1, "color_primaries": 1, "color_trc": 13, "color_range": 1}


def output_colour(info: ClipInfo) -> dict:
    """The colour tags of the output stream. A video's are its source's, tag by tag, and only
    those it has: an untagged source gives an untagged output (a player makes the same guess
    for both; video_io decodes an untagged stream by that guess, and the output is encoded by
    it), never a claim the source did not make. A matrix swscale cannot encode with (BT.2020
    constant luminance, ...) is left untagged. Frames from a folder are sRGB images, and are tagged as such."""
    if info.kind != "video":
        return dict(SRGB_TAGS)
    tags = {k: int(v) for k, v in info.colour.items() if k in _UNSPECIFIED and int(v) not in _UNSPECIFIED[k]}
    if tags.get("colorspace") not in (None, *_MATRICES):
        del tags["colorspace"]
    return tags


def _conversion(tags: dict, height: int) -> tuple[str, str]:
    """(matrix, range) that RGB frames are converted to YCbCr with: the tagged ones, else the
    guess video_io reads an untagged stream with (BT.709 from 720 lines up, else BT.601; limited)."""
    space = _MATRICES.get(tags.get("colorspace"), "itu709" if height >= 720 else "itu601")
    return space, "JPEG" if tags.get("color_range") == 2 else "MPEG"


def _raise_write_error(path: Path, exc) -> None:
    import errno as errno_module

    code = getattr(exc, "errno", None)
    if "No space left" in str(exc):
        code = errno_module.ENOSPC
    code = code if code and code in errno_module.errorcode else errno_module.EIO
    # the output's name, not the temporary's: the temporary is gone once the writer is aborted
    raise OSError(code, os.strerror(code), str(path)) from None


class _AudioCopy:
    """The source's first audio stream into the output, packet by packet as the video
    advances (kept interleaved): copied when the container holds its codec, else
    re-encoded to the container's usual codec."""

    def __init__(self, source: Path, container, suffix: str, output: Path):
        self.output = output
        self.input = open_container(source)
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
        av = import_av()
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
                _raise_write_error(self.output, exc)
        if not self.copy:
            self.container.mux(self.out_stream.encode(None))
        self.input.close()
        self.input = None

    def close(self) -> None:
        if self.input is not None:
            self.input.close()
            self.input = None
