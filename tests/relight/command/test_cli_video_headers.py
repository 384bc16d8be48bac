"""`relight video` reads a folder of frames through the core's one header reader (issue 49,
relight.files.photo_header): a frame whose header is damaged is refused when the job starts,
before any frame is decoded or anything written; one whose pixels are damaged behind a whole
header is found when it is decoded (tests/relight/command/test_cli_video.py,
test_a_frame_found_damaged_mid_job_removes_the_frames_already_written)."""

from __future__ import annotations

import pytest
from PIL import Image

from clip_support import person_clip, write_frames
from relight.cli import main
from relight.files import image_limits, video_io, video_out


def _run(capsys, *argv):
    code = main(["video", *map(str, argv), "--quality", "draft", "--threads", "1"])
    out, err = capsys.readouterr()
    return code, out, err


def _count(monkeypatch, cls, method) -> list:
    """A list that grows by one at each call of cls.method."""
    calls, real = [], getattr(cls, method)
    monkeypatch.setattr(cls, method, lambda self, *a, **k: calls.append(1) or real(self, *a, **k))
    return calls


def test_a_frame_damaged_in_its_header_is_refused_before_anything_is_decoded_or_written(tmp_path, capsys,
                                                                                        monkeypatch):
    """The 6th of 8 PNG frames cut short (its IDAT chunk declares bytes past the end): one line naming
    it, exit 2, no frame decoded, no frame file or video begun. Before, frames 1 - 5 were relit and
    written, then removed when the 6th failed to decode."""
    src = write_frames(tmp_path / "in", person_clip(8))
    data = (src / "f_0006.png").read_bytes()
    (src / "f_0006.png").write_bytes(data[:len(data) // 2])
    idat = int.from_bytes(data[data.index(b"IDAT") - 4:data.index(b"IDAT")], "big")
    frames_written = _count(monkeypatch, video_out.FrameFolderWriter, "write")
    videos_begun = _count(monkeypatch, video_out.VideoWriter, "__init__")
    decoders, real_decoder = [], Image._getdecoder
    monkeypatch.setattr(Image, "_getdecoder", lambda *a, **k: decoders.append(a[0]) or real_decoder(*a, **k))
    for out, extra in ((tmp_path / "out", []), (tmp_path / "o.mp4", ["--resume"]), (tmp_path / "v.mp4", [])):
        code, text, err = _run(capsys, src, "--light", "studio", "--out", out, *extra)
        assert code == 2 and text == "", err
        assert err == (f"relight video: error: {src / 'f_0006.png'}: truncated or corrupt PNG (chunk b'IDAT' "
                       f"declares {idat:,} bytes, past the end of the {len(data) // 2:,}-byte file)\n")
        assert frames_written == [] and videos_begun == [] and decoders == []
        assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_a_resumable_video_job_is_encoded_under_its_own_pixel_limit(tmp_path, capsys, monkeypatch):
    """A video job's frames (OUTPUT.frames/) are read back under the job's --max-pixels, as its input
    was: before, under the default limit, so a clip that --max-pixels allowed above it was relit whole
    and then refused when encoded (here the default is lowered below the clip's 160 x 90 pixels)."""
    src = write_frames(tmp_path / "in", person_clip(3))
    monkeypatch.setattr(image_limits, "DEFAULT_MAX_PIXELS", 10_000)
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "o.mp4", "--resume")
    assert code == 2 and "over the limit" in err  # the default refuses the input itself...
    code, text, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "o.mp4", "--resume",
                           "--max-pixels", "20000")
    assert code == 0, err  # ...which --max-pixels allows, for the input and the job's frames alike
    assert "relit 3 frames" in text and not (tmp_path / "o.mp4.frames").exists()
    assert video_io.open_clip(tmp_path / "o.mp4", max_pixels=20_000).info.frames == 3


@pytest.mark.parametrize("fmt, expected", [("exr", ".exr"), ("png", ".png")])
def test_the_frames_format_follows_the_input_frames_headers(tmp_path, capsys, fmt, expected):
    """Without --format, EXR input frames give EXR output frames: as their headers say."""
    src = write_frames(tmp_path / "in", person_clip(2), fmt=fmt)
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "out")
    assert code == 0, err
    assert sorted(p.suffix for p in (tmp_path / "out").iterdir() if not p.name.startswith(".")) == [expected] * 2
