"""relight.files.video_io: video files and frame folders in and out, and how bad input fails."""

from __future__ import annotations

import errno
import struct
import zlib
from fractions import Fraction

import av
import numpy as np
import pytest
from PIL import Image

from clip_support import write_video
from relight.imaging.colour import srgb_decode, srgb_encode
from relight.files.video_io import ClipInfo, FrameFolder, decode_srgb, frame_number, open_clip
from relight.files.video_out import FrameFolderWriter, VideoWriter, encode_srgb8


def _frames(n, h=36, w=48, seed=0):
    """Smooth frames (video codecs keep smooth content within a few code values)."""
    y, x = np.mgrid[0:h, 0:w] / max(h, w)
    out = []
    for i in range(n):
        t = i / max(1, n - 1)
        rgb = np.stack([0.2 + 0.6 * x, 0.3 + 0.4 * y * (1 - t), 0.1 + 0.5 * t + 0 * x], axis=-1)
        out.append(srgb_decode(rgb).astype(np.float32))
    return out


def _audio_seconds(path) -> float:
    with av.open(str(path)) as c:
        s = c.streams.audio[0]
        return sum(float(p.duration * s.time_base) for p in c.demux(s) if p.duration)


def test_srgb_tables_round_trip_every_code():
    codes = np.arange(256, dtype=np.uint8)
    np.testing.assert_array_equal(encode_srgb8(decode_srgb(codes)), codes)
    np.testing.assert_allclose(decode_srgb(codes), srgb_decode(codes / 255.0), rtol=1e-6, atol=1e-7)


@pytest.mark.parametrize("suffix, fps", [(".mp4", Fraction(25)), (".webm", Fraction(30000, 1001)),
                                         (".mov", Fraction(24)), (".mkv", Fraction(12))])
def test_video_round_trip_keeps_count_rate_size_and_values(tmp_path, suffix, fps):
    frames = _frames(12)
    path = write_video(tmp_path / f"clip{suffix}", frames, fps)
    clip = open_clip(path)
    assert (clip.info.width, clip.info.height, clip.info.fps) == (48, 36, fps)
    got = [f for _, f, _, _ in clip.frames()]
    assert len(got) == 12
    # lossy 8-bit 4:2:0 (H.264 at CRF 18, VP9 at CRF 30): no exact bound exists; these encoders
    # keep smooth content above 35 dB PSNR in sRGB, a mean error under 2 code values
    err = srgb_encode(np.stack(got)) - srgb_encode(np.stack(frames))
    assert np.abs(err).mean() < 2 / 255
    assert -10 * np.log10(np.mean(err.astype(np.float64) ** 2)) > 35
    assert [f.index for f in clip.frames(start=9)] == [9, 10, 11]
    # an 8-bit stream keeps its codes, which the linear image decodes exactly
    first = next(clip.frames())
    np.testing.assert_array_equal(decode_srgb(first.codes), first.image)


def test_odd_sizes_are_kept(tmp_path):
    frames = _frames(3, h=35, w=47)
    clip = open_clip(write_video(tmp_path / "odd.mp4", frames, 25))
    assert (clip.info.width, clip.info.height) == (47, 35)
    assert len(list(clip.frames())) == 3


@pytest.mark.parametrize("source, out", [("aac", ".mp4"), ("aac", ".webm"), ("libopus", ".mkv")])
def test_audio_is_copied_or_reencoded(tmp_path, source, out):
    frames = _frames(12)
    src = write_video(tmp_path / ("src.mkv" if source == "libopus" else "src.mp4"), frames, 25, audio=source)
    clip = open_clip(src)
    assert clip.info.audio
    writer = VideoWriter(tmp_path / f"out{out}", clip.info, audio_from=src)
    for _, f, _, _ in clip.frames():
        writer.write(f)
    writer.close()
    with av.open(str(tmp_path / f"out{out}")) as c:
        assert len(c.streams.audio) == 1
        assert c.streams.audio[0].codec_context.name in ({"opus"} if out == ".webm" else {"aac", "opus"})
    # the whole track: 12 frames at 25 fps are 0.48 s (codec frames round it up by < 25 ms)
    assert 0.48 - 0.03 <= _audio_seconds(tmp_path / f"out{out}") <= 0.48 + 0.05


def test_an_aborted_video_leaves_nothing(tmp_path):
    out = tmp_path / "out.mp4"
    writer = VideoWriter(out, ClipInfo(out, "frames", 48, 36, Fraction(24), 2))
    writer.write(_frames(1)[0])
    writer.abort()
    assert list(tmp_path.iterdir()) == []
    writer = VideoWriter(out, ClipInfo(out, "frames", 48, 36, Fraction(24), 2))
    with pytest.raises(ValueError, match="no frames"):
        writer.close()
    assert list(tmp_path.iterdir()) == []


def test_a_full_disk_while_encoding_is_one_oserror_and_no_file(tmp_path):
    out = tmp_path / "out.mp4"
    writer = VideoWriter(out, ClipInfo(out, "frames", 48, 36, Fraction(24), 2))
    writer.write(_frames(1)[0])

    def full(*_):
        raise av.error.FFmpegError(errno.ENOSPC, "No space left on device")

    writer.container = _Failing(writer.container, full)
    with pytest.raises(OSError) as info:
        writer.close()
    assert info.value.errno == errno.ENOSPC
    assert list(tmp_path.iterdir()) == []


class _Failing:
    """A container whose mux fails like a full disk."""

    def __init__(self, container, fail):
        self._container, self.mux = container, fail

    def close(self):
        self._container.close()


def _png(path, h=20, w=30, value=100, alpha=False):
    a = np.full((h, w, 4 if alpha else 3), value, np.uint8)
    Image.fromarray(a).save(path)


def test_frame_folder_is_ordered_by_number_and_keeps_alpha(tmp_path):
    for n in (10, 9, 100, 1):
        _png(tmp_path / f"shot_{n}.png", value=n, alpha=n == 9)
    clip = open_clip(tmp_path, fps=Fraction(30))
    assert clip.info.names == ("shot_1", "shot_9", "shot_10", "shot_100")
    assert (clip.info.frames, clip.info.fps, clip.info.kind) == (4, Fraction(30), "frames")
    got = list(clip.frames())
    assert [round(float(srgb_encode(f.image[0, 0, 0]) * 255)) for f in got] == [1, 9, 10, 100]
    assert [f.alpha is not None for f in got] == [False, True, False, False]


@pytest.mark.parametrize("make, message", [
    (lambda d: None, "no frames"),
    (lambda d: (_png(d / "a.png"), _png(d / "b_2.png")), "has no number"),
    (lambda d: (_png(d / "a_2.png"), _png(d / "b_02.png")), "two frames are numbered 2"),
    (lambda d: (_png(d / "f_1.png"), _png(d / "f_2.png", h=21)), "every frame of a clip must have one size"),
    (lambda d: (d / "f_1.png").write_bytes(b"not an image"), "not a readable image"),
])
def test_bad_frame_folders_fail_before_any_frame_is_decoded(tmp_path, make, message):
    make(tmp_path)
    with pytest.raises(ValueError, match=message):
        FrameFolder(tmp_path)


@pytest.mark.parametrize("content, message", [
    (b"this is not a video at all" * 40, "not a readable video"),
    (b"", "file is empty"),
])
def test_a_file_that_is_not_a_video_is_one_valueerror(tmp_path, content, message):
    path = tmp_path / "x.mp4"
    path.write_bytes(content)
    with pytest.raises(ValueError, match=message):
        open_clip(path)


def test_an_image_or_audio_file_is_not_a_video_and_a_missing_input_is_named(tmp_path):
    _png(tmp_path / "photo.png")
    with pytest.raises(ValueError, match="an image, not a video"):
        open_clip(tmp_path / "photo.png")
    c = av.open(str(tmp_path / "sound.m4a"), "w")
    a = c.add_stream("aac", rate=48000)
    tone = np.zeros((2, 4800), np.float32)
    af = av.AudioFrame.from_ndarray(tone, format="fltp", layout="stereo")
    af.sample_rate, af.pts, af.time_base = 48000, 0, Fraction(1, 48000)
    c.mux(a.encode(af))
    c.mux(a.encode(None))
    c.close()
    with pytest.raises(ValueError, match="no video stream"):
        open_clip(tmp_path / "sound.m4a")
    with pytest.raises(ValueError, match="no such file"):
        open_clip(tmp_path / "missing.mp4")


def test_frame_folder_writer_names_and_what_is_written(tmp_path):
    w = FrameFolderWriter(tmp_path, "png")
    assert w.path(0).name == "frame_000001.png" and w.written() == set()
    w.write(4, _frames(1)[0])
    (tmp_path / ".frame_000002.png.tmp").write_bytes(b"x")  # a temporary is not a frame
    assert w.written() == {4}
    named = FrameFolderWriter(tmp_path, "exr", names=["a_1", "a_2"])
    named.write(1, _frames(1)[0])
    assert named.written() == {1} and (tmp_path / "a_2.exr").is_file()
    assert frame_number("take3_0042") == 42 and frame_number("plain") is None


# ------------------------------------------------------------------ issue 48: what is declared against what is read


@pytest.mark.parametrize("suffix", [".mp4", ".mkv", ".mov"])
def test_a_video_cut_short_is_refused_and_the_whole_one_read_whole(tmp_path, suffix):
    from clip_support import cut_short, grainy_video

    whole = grainy_video(tmp_path / f"whole{suffix}")
    clip = open_clip(whole)
    assert clip.info.frames == 30 and len(list(clip.frames())) == 30
    for fraction in (0.6, 0.9):
        cut = cut_short(whole, fraction, tmp_path / f"cut{suffix}")
        with pytest.raises(ValueError) as refused:
            list(open_clip(cut).frames())
        assert str(refused.value).startswith(f"{cut}: the video is cut short: it declares 30 frames (1.25 s) but "
                                             "holds "), refused.value


class _Unseekable:
    """A file object without seek: the muxer cannot go back to write the length (a live recording)."""

    def __init__(self, path):
        self.file = open(path, "wb")

    def write(self, data):
        return self.file.write(data)


def test_a_video_that_declares_no_length_is_read_whole(tmp_path):
    """A live recording's Matroska says neither its frame count nor its duration: nothing to check
    against, so it is read as it is (no refusal of a whole file), its frames counted in its packets."""
    sink = _Unseekable(tmp_path / "live.mkv")
    with av.open(sink, "w", format="matroska") as c:
        v = c.add_stream("libx264", rate=25)
        v.width, v.height, v.pix_fmt = 48, 36, "yuv420p"
        for i, f in enumerate(_frames(10)):
            frame = av.VideoFrame.from_ndarray(encode_srgb8(f), format="rgb24")
            frame.pts, frame.time_base = i, Fraction(1, 25)
            c.mux(v.encode(frame))
        c.mux(v.encode(None))
    sink.file.close()
    clip = open_clip(tmp_path / "live.mkv")
    assert clip.info.frames == 10 and len(list(clip.frames())) == 10  # the frames counted in its packets


def test_frames_the_decoder_drops_without_an_error_are_refused(tmp_path, monkeypatch):
    """Every packet is there but fewer frames come out of the decoder (a damaged stream the decoder
    skips silently): the decoded frames' span is checked against the packets' once decoding ends."""
    from relight.files import video_io

    clip = open_clip(write_video(tmp_path / "c.mkv", _frames(12), 12))
    real = video_io.open_container

    class Dropping:
        def __init__(self, path):
            self.container = real(path)
            self.streams = self.container.streams

        def decode(self, stream):
            return (f for i, f in enumerate(self.container.decode(stream)) if i < 6)

        def close(self):
            self.container.close()

    monkeypatch.setattr(video_io, "open_container", Dropping)
    with pytest.raises(ValueError, match=r"c\.mkv: the video is damaged: 6 frames \(0\.50 s\) could be decoded of "
                                         r"the 1\.00 s it holds"):
        list(clip.frames())


def test_a_stream_of_an_unknown_codec_is_one_valueerror(tmp_path):
    """Found by tests/relight/command/test_fuzz_video.py: a Matroska whose codec id is damaged has a video stream
    without a decoder (an AttributeError, a traceback, before)."""
    data = write_video(tmp_path / "c.mkv", _frames(3), 12).read_bytes()
    assert data.count(b"V_MPEG4/ISO/AVC") == 1
    (tmp_path / "x.mkv").write_bytes(data.replace(b"V_MPEG4/ISO/AVC", b"V_MPEG4/ISO/AVX"))
    with pytest.raises(ValueError, match=r"x\.mkv: the video stream's codec cannot be decoded"):
        open_clip(tmp_path / "x.mkv")


def test_an_mp4_trimmed_by_its_edit_list_is_read_whole(tmp_path):
    """An mp4 whose edit list starts 5 frames in (a cut made without re-encoding: the frames before
    it are stored, decoded for the next ones, never shown): its container counts 30 frames and lasts
    25. Not a file cut short: the 25 frames shown are read, and counted."""
    from fractions import Fraction

    frames = _frames(30)
    with av.open(str(tmp_path / "trimmed.mp4"), "w") as c:
        v = c.add_stream("libx264", rate=24)
        v.width, v.height, v.pix_fmt = 48, 36, "yuv420p"
        for i, f in enumerate([*frames, None]):
            if f is not None:
                f = av.VideoFrame.from_ndarray(encode_srgb8(f), format="rgb24")
                f.pts, f.time_base = i, Fraction(1, 24)
            for packet in v.encode(f):  # 5 frames before the start: the muxer writes the edit list
                packet.pts, packet.dts = packet.pts - 5, packet.dts - 5
                c.mux(packet)
    with av.open(str(tmp_path / "trimmed.mp4")) as c:
        assert c.streams.video[0].frames == 30
        assert sum(p.is_discard for p in c.demux(video=0) if p.size) == 5
    clip = open_clip(tmp_path / "trimmed.mp4")
    assert clip.info.frames == 25 and len(list(clip.frames())) == 25


@pytest.mark.parametrize("suffix", [".mkv", ".mp4"])
def test_a_video_starting_late_is_read_whole(tmp_path, suffix):
    """A stream whose first frame is at 0.5 s: Matroska declares its length as the end time from 0
    (DURATION 1.00 s for 0.50 s of frames), an mp4 as a length. Neither is a file cut short."""
    from fractions import Fraction

    with av.open(str(tmp_path / f"late{suffix}"), "w") as c:
        v = c.add_stream("libx264", rate=24)
        v.width, v.height, v.pix_fmt = 48, 36, "yuv420p"
        for i, f in enumerate([*_frames(12), None]):
            if f is not None:
                f = av.VideoFrame.from_ndarray(encode_srgb8(f), format="rgb24")
                f.pts, f.time_base = i + 12, Fraction(1, 24)
            c.mux(v.encode(f))
    clip = open_clip(tmp_path / f"late{suffix}")
    assert clip.info.frames == 12 and len(list(clip.frames())) == 12


# ------------------------------------------------------------------ issue 49: a frame folder's headers, read once


def _count_pillow(monkeypatch) -> tuple[list, list]:
    """(Image.open calls, decoders Pillow made: one per decoded frame, these frames have one tile)."""
    opens, decoders = [], []
    real_open, real_decoder = Image.open, Image._getdecoder
    monkeypatch.setattr(Image, "open", lambda *a, **k: opens.append(a[0]) or real_open(*a, **k))
    monkeypatch.setattr(Image, "_getdecoder", lambda *a, **k: decoders.append(a[0]) or real_decoder(*a, **k))
    return opens, decoders


def test_a_png_frame_sequence_is_opened_from_its_headers_without_decoding_a_frame(tmp_path, monkeypatch):
    """Each frame's size and EXIF turn come from relight.files.photo_header: one open per frame,
    no frame decoded (Pillow's getexif decoded every PNG frame before), the clip upright."""
    exif = Image.Exif()
    exif[0x0112] = 6  # turned a quarter: the frames stand 20 wide, 30 high
    tiff = exif.tobytes()[6:]  # without the "Exif\0\0" of a JPEG's APP1
    late = struct.pack(">I", len(tiff)) + b"eXIf" + tiff + struct.pack(">I", zlib.crc32(b"eXIf" + tiff))
    for i in range(5):  # the eXIf chunk after the pixels, where Pillow finds it only by decoding them
        Image.fromarray(np.full((20, 30, 3), 40 * i, np.uint8)).save(tmp_path / f"f_{i + 1}.png")
        data = (tmp_path / f"f_{i + 1}.png").read_bytes()
        (tmp_path / f"f_{i + 1}.png").write_bytes(data[:-12] + late + data[-12:])
    opens, decoders = _count_pillow(monkeypatch)
    clip = open_clip(tmp_path)
    assert (clip.info.width, clip.info.height, clip.info.frames) == (20, 30, 5)
    assert len(opens) == 5 and decoders == []
    assert [h.orientation for h in clip.headers] == [6] * 5 and {h.format for h in clip.headers} == {"PNG"}
    got = list(clip.frames())
    assert len(decoders) == 5 and all(f.image.shape == (30, 20, 3) for f in got)
    codes = list(clip.codes())  # the 8-bit codes, upright, from the header reader's open
    assert [c.shape for c in codes] == [(30, 20, 3)] * 5 and [int(c[0, 0, 0]) for c in codes] == [0, 40, 80, 120, 160]


def _cut_png(path):
    _png(path)
    data = path.read_bytes()
    path.write_bytes(data[:len(data) // 2])  # the IDAT chunk now declares bytes past the end


def _broken_exif_png(path):
    exif = Image.Exif()
    exif[0x0112] = 6
    Image.fromarray(np.full((20, 30, 3), 9, np.uint8)).save(path, exif=exif)
    data = path.read_bytes()
    at = data.index(b"eXIf")
    length = struct.unpack(">I", data[at - 4:at])[0]
    body = b"XX" + data[at + 6:at + 4 + length]  # the TIFF header's byte order: neither II nor MM
    chunk = b"eXIf" + body + struct.pack(">I", zlib.crc32(b"eXIf" + body))  # a whole chunk, its CRC right
    path.write_bytes(data[:at] + chunk + data[at + 8 + length:])


def _cut_exr(path):
    from relight.files.photo import write_exr_image

    write_exr_image(path, np.full((20, 30, 3), 0.5, np.float32))
    path.write_bytes(path.read_bytes()[:40])


@pytest.mark.parametrize("damage, suffix, said", [(_cut_png, ".png", "past the end"),
                                                  (_broken_exif_png, ".png", "corrupt EXIF"),
                                                  (_cut_exr, ".exr", "")])
def test_a_frame_damaged_in_its_header_is_refused_when_the_clip_is_opened(tmp_path, monkeypatch, damage, suffix,
                                                                          said):
    """Refused by the header reader, before any frame is decoded (a cut PNG or a broken EXIF was
    refused only when the frame was decoded, mid-job, before): one line naming the frame."""
    from relight.files.photo_header import ImageDamaged

    for i in (1, 2, 4):
        _png(tmp_path / f"f_{i}.png")
    damage(tmp_path / f"f_3{suffix}")
    _, decoders = _count_pillow(monkeypatch)
    with pytest.raises(ImageDamaged) as refused:
        open_clip(tmp_path)
    line = str(refused.value)
    assert f"{tmp_path / f'f_3{suffix}'}: " in line and said in line and "\n" not in line
    assert decoders == []


def test_a_frame_past_pillows_own_limit_is_refused_with_its_pixel_count(tmp_path):
    """The header reader's line for a size Pillow refuses before we weigh it: the count declared
    (the video path said only 'over 178,956,970 pixels' before)."""
    from fuzz_support import png_bytes
    from relight.files.image_limits import ImageSizeError

    (tmp_path / "f_1.png").write_bytes(png_bytes(8, 8, declared=(15000, 15000)))
    with pytest.raises(ImageSizeError) as refused:
        open_clip(tmp_path)
    assert str(refused.value) == (f"{tmp_path / 'f_1.png'}: image is too large (225,000,000 pixels; at most "
                                  "150,000,000 can be relit): scale it down")
