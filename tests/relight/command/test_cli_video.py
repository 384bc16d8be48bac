"""`relight video`: files and folders in and out, resume, interrupts and every bad-input path."""

from __future__ import annotations

import contextlib
import errno
from fractions import Fraction

import av
import numpy as np
import pytest
from PIL import Image

from clip_support import background, person_clip, write_frames, write_video
from relight.command import cli_video
from relight.files import video_io, video_out
from relight.cli import main
from relight.files.photo import read_photo


@pytest.fixture(scope="module")
def clip_frames():
    return person_clip(12)


def _run(capsys, *argv):
    code = main(["video", *map(str, argv), "--quality", "draft", "--threads", "1"])
    out, err = capsys.readouterr()
    return code, out, err


def _folder(path, suffix=".png"):
    return {p.name: read_photo(p)[0] for p in sorted(path.iterdir()) if p.suffix == suffix}


def _leftovers(path):
    """Temporary files that a write left behind (there must be none)."""
    return [p.name for p in path.rglob("*") if ".tmp" in p.name]


def test_video_to_video_keeps_count_rate_size_and_audio(tmp_path, capsys, clip_frames):
    src = write_video(tmp_path / "in.mp4", clip_frames, Fraction(30000, 1001), audio="aac")
    code, out, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "out.mp4")
    assert code == 0, err
    assert "relit 12 frames" in out
    clip = video_io.open_clip(tmp_path / "out.mp4")
    assert (clip.info.width, clip.info.height, clip.info.fps) == (160, 90, Fraction(30000, 1001))
    assert len(list(clip.frames())) == 12
    with av.open(str(tmp_path / "out.mp4")) as c:
        assert [s.codec_context.name for s in c.streams.audio] == ["aac"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.mp4", "out.mp4"]


def test_folder_to_folder_and_exr_keeps_linear_values(tmp_path, capsys, clip_frames):
    frames = [f.copy() for f in clip_frames[:4]]
    for f in frames:
        f[:3, :3] = 4.0  # a light source in the background: linear values above 1
    src = write_frames(tmp_path / "in", frames, fmt="exr")
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "out", "--stability", "0")
    assert code == 0, err
    got = _folder(tmp_path / "out", ".exr")
    assert sorted(got) == [f"f_{i:04d}.exr" for i in range(1, 5)]
    # stability 0: each frame exactly as `relight image` relights it
    code = main(["image", str(src / "f_0003.exr"), "--light", "studio", "--quality", "draft",
                 "--threads", "1", "--out", str(tmp_path / "still.exr")])
    assert code == 0, capsys.readouterr().err
    np.testing.assert_array_equal(got["f_0003.exr"], read_photo(tmp_path / "still.exr")[0])
    # linear values above 1 survive in EXR frames (the background is kept bit for bit)
    assert np.all(got["f_0001.exr"][:3, :3] == 4.0)


def test_layers_and_a_frame_without_a_person(tmp_path, capsys, clip_frames):
    frames = clip_frames[:3] + [background()] + clip_frames[3:5]
    src = write_frames(tmp_path / "in", frames)
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "out", "--layers")
    assert code == 0, err
    assert "no person in frames 4: written unchanged" in err
    from relight.files.exr import read_exr

    empty = read_exr(tmp_path / "out" / "f_0004.exr")
    assert np.all(empty["Relight.Alpha.A"] == 0)
    np.testing.assert_array_equal(np.stack([empty[f"Relight.Relit.{c}"] for c in "RGB"], -1),
                                  read_photo(src / "f_0004.png")[0])
    assert read_exr(tmp_path / "out" / "f_0005.exr")["Relight.Alpha.A"].max() > 0.5


def _interrupt_after(monkeypatch, cls, method, calls):
    """Make cls.method raise KeyboardInterrupt on its `calls`-th call (as Ctrl-C would)."""
    original = getattr(cls, method)
    count = {"n": 0}

    def wrapped(self, *a, **kw):
        count["n"] += 1
        if count["n"] == calls:
            raise KeyboardInterrupt
        return original(self, *a, **kw)

    monkeypatch.setattr(cls, method, wrapped)


def test_resume_after_an_interrupt_writes_only_the_missing_frames_identically(tmp_path, capsys, monkeypatch,
                                                                                clip_frames):
    src = write_frames(tmp_path / "in", clip_frames)
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "whole")
    assert code == 0, err
    whole = _folder(tmp_path / "whole")

    with monkeypatch.context() as m:
        _interrupt_after(m, video_out.FrameFolderWriter, "write", 8)
        code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "part")
    assert code == cli_video.EXIT_INTERRUPTED
    assert "interrupted" in err and "--resume" in err
    assert sorted(_folder(tmp_path / "part")) == [f"f_{i:04d}.png" for i in range(1, 8)]
    assert _leftovers(tmp_path / "part") == []

    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "part")
    assert code == 2 and "--resume" in err  # without --resume a half-done folder is refused
    written = []
    original = video_out.FrameFolderWriter.write
    monkeypatch.setattr(video_out.FrameFolderWriter, "write",
                        lambda self, i, *a: written.append(i) or original(self, i, *a))
    code, out, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "part", "--resume")
    assert code == 0, err
    assert written == list(range(7, 12)) and "relit 5 frames" in out and "(7 were there already)" in out
    part = _folder(tmp_path / "part")
    assert sorted(part) == sorted(whole)
    for name in whole:
        np.testing.assert_array_equal(part[name], whole[name])


def test_resume_without_a_saved_state_recomputes_from_the_start(tmp_path, capsys, monkeypatch, clip_frames):
    """A job killed outright (no checkpoint yet): the resume replays the filter from frame 1."""
    src = write_frames(tmp_path / "in", clip_frames[:8])
    code, _, err = _run(capsys, src, "--light", "city", "--out", tmp_path / "whole", "--stability", "1")
    assert code == 0, err
    with monkeypatch.context() as m:
        _interrupt_after(m, video_out.FrameFolderWriter, "write", 5)
        _run(capsys, src, "--light", "city", "--out", tmp_path / "part", "--stability", "1")
    (tmp_path / "part" / cli_video.STATE_FILE).unlink()
    code, _, err = _run(capsys, src, "--light", "city", "--out", tmp_path / "part", "--stability", "1", "--resume")
    assert code == 0, err
    whole, part = _folder(tmp_path / "whole"), _folder(tmp_path / "part")
    for name in whole:
        np.testing.assert_array_equal(part[name], whole[name])
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "part", "--stability", "1", "--resume")
    assert code == 2 and "light differ" in err


def test_a_resumable_video_job_keeps_its_frames_until_the_video_is_complete(tmp_path, capsys, monkeypatch,
                                                                           clip_frames):
    src = write_video(tmp_path / "in.mp4", clip_frames[:8])
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "whole.mp4")
    assert code == 0, err
    with monkeypatch.context() as m:
        _interrupt_after(m, video_out.FrameFolderWriter, "write", 6)
        code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "out.mp4", "--resume")
    assert code == cli_video.EXIT_INTERRUPTED
    assert not (tmp_path / "out.mp4").exists()
    assert len(list((tmp_path / "out.mp4.frames").glob("*.png"))) == 5
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "out.mp4", "--resume")
    assert code == 0, err
    assert not (tmp_path / "out.mp4.frames").exists()
    got = [f for _, f, _, _ in video_io.open_clip(tmp_path / "out.mp4").frames()]
    want = [f for _, f, _, _ in video_io.open_clip(tmp_path / "whole.mp4").frames()]
    assert len(got) == len(want) == 8
    for a, b in zip(got, want):
        np.testing.assert_array_equal(a, b)


def test_an_interrupted_video_leaves_no_file(tmp_path, capsys, monkeypatch, clip_frames):
    src = write_video(tmp_path / "in.mp4", clip_frames[:6])
    _interrupt_after(monkeypatch, video_out.VideoWriter, "write", 4)
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "out.mp4")
    assert code == cli_video.EXIT_INTERRUPTED and "no video written" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.mp4"]


def _disk_full(*_a, **_k):
    raise OSError(errno.ENOSPC, "No space left on device")


def _frames_fail_from(monkeypatch, failing: int):
    """The frames' PNG writes (relight's encoder; Pillow's for a resumable video's frames) fail from
    the `failing`-th on, half-way through, as on a full disk."""
    from relight.files import png_encoder

    calls = {"n": 0}

    def failing_from(original, opened):
        def save(target, *a, **k):
            calls["n"] += 1
            if calls["n"] >= failing:
                with opened(target) as f:
                    f.write(b"\x89PNG partial")
                _disk_full()
            return original(target, *a, **k)
        return save

    keep_open = contextlib.nullcontext
    monkeypatch.setattr(png_encoder, "write_png_file", failing_from(png_encoder.write_png_file, keep_open))
    pillow = Image.Image.save
    monkeypatch.setattr(Image.Image, "save", lambda im, fp, *a, **k: failing_from(
        lambda target, *b, **c: pillow(im, target, *b, **c), lambda t: open(t, "wb"))(fp, *a, **k))


def test_a_full_disk_fails_the_job_with_one_message_and_whole_frames_only(tmp_path, capsys, monkeypatch,
                                                                           clip_frames):
    src = write_frames(tmp_path / "in", clip_frames[:6])
    out = tmp_path / "out"
    with monkeypatch.context() as m:
        _frames_fail_from(m, 4)
        code, _, err = _run(capsys, src, "--light", "studio", "--out", out)
    assert code == cli_video.EXIT_FAILED
    assert err == (f"relight video: error: output disk full: {out / 'f_0004.png'}; 3 whole frames are in {out}: "
                   "free space and rerun with --resume\n")
    assert sorted(_folder(out)) == ["f_0001.png", "f_0002.png", "f_0003.png"]
    assert _leftovers(out) == []


def test_a_full_disk_before_any_frame_leaves_no_folder_and_says_so(tmp_path, capsys, monkeypatch, clip_frames):
    """Issue 48: the line said the frames written were whole when none was, and the folder kept a
    settings file describing no frame."""
    src = write_frames(tmp_path / "in", clip_frames[:3])
    _frames_fail_from(monkeypatch, 1)
    for out, extra, said in ((tmp_path / "out", [], "no frame was written"),
                             (tmp_path / "o.mp4", ["--resume"], "no video or frame written")):
        code, _, err = _run(capsys, src, "--light", "studio", "--out", out, *extra)
        frame = (out if not extra else tmp_path / "o.mp4.frames") / ("f_0001.png" if not extra else
                                                                      "frame_000001.png")
        assert code == cli_video.EXIT_FAILED
        assert err == f"relight video: error: output disk full: {frame}; {said}: free space and rerun\n"
        assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_a_full_disk_while_encoding_names_the_video_and_leaves_none(tmp_path, capsys, monkeypatch, clip_frames):
    """Issue 48: the line was nested ("cannot write ([Errno 28] ...)") and said "make the output writable"."""
    src = write_video(tmp_path / "in.mp4", clip_frames[:4])
    out = tmp_path / "o.mp4"
    real_open = av.open

    class FullDisk:  # an output container whose muxing fails as FFmpeg's does on a full disk
        def __init__(self, container):
            self._container = container

        def mux(self, *_):
            raise av.error.FFmpegError(errno.ENOSPC, "No space left on device")

        def __getattr__(self, name):
            return getattr(self._container, name)

    monkeypatch.setattr(av, "open", lambda f, mode="r", **k: FullDisk(real_open(f, mode, **k)) if mode == "w"
                        else real_open(f, mode, **k))
    code, _, err = _run(capsys, src, "--light", "studio", "--out", out)
    assert code == cli_video.EXIT_FAILED
    assert err == f"relight video: error: output disk full: {out}; no video written: free space and rerun\n"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in.mp4"]


def test_a_file_size_limit_is_one_line_naming_the_file_and_leaves_nothing(tmp_path, clip_frames):
    """The issue's own full disk: a subprocess under RLIMIT_FSIZE (its writes past the limit fail
    with EFBIG, as on a FAT32 disk past 4 GiB), for a video and for a folder of frames."""
    import resource
    import signal
    import subprocess
    import sys

    from clip_support import REPO

    src = write_video(tmp_path / "in.mp4", clip_frames[:3])
    limit = 2000  # bytes a file may grow to: the settings file (~600) fits, no frame (~25 KB) or video (~5 KB) does

    def small_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)
        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))

    for out, name in ((tmp_path / "o.mp4", tmp_path / "o.mp4"), (tmp_path / "f", tmp_path / "f" / "frame_000001.png")):
        res = subprocess.run([sys.executable, "-m", "relight.cli", "video", str(src), "--light", "studio", "--out",
                              str(out), "--quality", "draft", "--threads", "1"], cwd=REPO, capture_output=True,
                             text=True, preexec_fn=small_disk, timeout=300)
        assert res.returncode == cli_video.EXIT_FAILED and res.stdout == "", res.stderr
        assert res.stderr.startswith(f"relight video: error: file too large for the file system or the process's "
                                     f"file-size limit (ulimit -f): {name}; no ")
        assert res.stderr.count("\n") == 1 and "choose an output on another disk and rerun\n" in res.stderr
        assert sorted(p.name for p in tmp_path.iterdir()) == ["in.mp4"]


@pytest.mark.parametrize("suffix", [".mp4", ".mkv"])
def test_a_video_cut_short_is_refused_and_leaves_nothing(tmp_path, capsys, suffix):
    """Issue 48: a clip cut at 60 % of its bytes (30 frames declared) was relit as a shorter clip, exit 0."""
    from clip_support import cut_short, grainy_video

    (tmp_path / "in").mkdir()
    cut = cut_short(grainy_video(tmp_path / f"whole{suffix}"), 0.6, tmp_path / "in" / f"cut{suffix}")
    (tmp_path / f"whole{suffix}").unlink()
    for out, extra in ((tmp_path / "t.mp4", []), (tmp_path / "frames", []), (tmp_path / "r.mp4", ["--resume"])):
        code, text, err = _run(capsys, cut, "--light", "sunset", "--out", out, *extra)
        assert code == 2 and text == "" and err.count("\n") == 1, err
        assert err.startswith(f"relight video: error: {cut}: the video is cut short: it declares 30 frames (1.25 s) "
                              "but holds "), err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


@pytest.mark.parametrize("setup, extra, message", [
    (lambda d: (d / "x.mp4").write_bytes(b"garbage" * 100), [], "not a readable video"),
    (lambda d: (d / "x").mkdir(), [], "no frames"),
    (lambda d: (write_frames(d / "x", person_clip(2)), Image.new("RGB", (40, 30)).save(d / "x" / "f_0003.png")),
     [], "every frame of a clip must have one size"),
    (lambda d: write_frames(d / "x", person_clip(2)), ["--mask", "m.png"], "--mask applies to one photo"),
    (lambda d: write_video(d / "x.mp4", person_clip(2)), ["--fps", "30"], "--fps applies to a folder"),
    (lambda d: write_frames(d / "x", person_clip(2)), ["--out-same"], "must differ from the input folder"),
    (lambda d: write_video(d / "x.mp4", person_clip(2)), ["--layers"], "apply to a folder of frames"),
    (lambda d: write_frames(d / "x", person_clip(2)), ["--format", "png", "--layers"], "--layers writes"),
])
def test_bad_input_is_one_line_exit_2_and_nothing_written(tmp_path, capsys, setup, extra, message):
    (tmp_path / "in").mkdir()
    setup(tmp_path / "in")
    source = next((tmp_path / "in").iterdir())
    out = source if extra == ["--out-same"] else tmp_path / ("out.mp4" if "--layers" in extra and
                                                             len(extra) == 1 else "out")
    extra = [] if extra == ["--out-same"] else extra
    code, _, err = _run(capsys, source, "--light", "studio", "--out", out, *extra)
    assert code == 2
    assert err.count("\n") == 1 and message in err, err
    assert not (tmp_path / "out").exists() and not (tmp_path / "out.mp4").exists()


def test_folder_input_fps_sets_the_video_rate(tmp_path, capsys, clip_frames):
    src = write_frames(tmp_path / "in", clip_frames[:3])
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "o.webm", "--fps", "12.5")
    assert code == 0, err
    clip = video_io.open_clip(tmp_path / "o.webm")
    assert clip.info.fps == Fraction(25, 2) and len(list(clip.frames())) == 3


# ------------------------------------------------------------------ issue 40: outputs, locks, leftovers


def test_an_output_that_is_the_input_is_refused_and_the_input_kept(tmp_path, capsys, clip_frames):
    src = write_video(tmp_path / "a.mp4", clip_frames[:3])
    (tmp_path / "link.mp4").symlink_to(src)
    kept = src.read_bytes()
    for source, out in ((src, src), (tmp_path / "link.mp4", src), (src, tmp_path / "link.mp4")):
        code, _, err = _run(capsys, source, "--light", "studio", "--out", out)
        assert code == 2 and err.count("\n") == 1 and "writing would replace it" in err, err
        assert src.read_bytes() == kept
        assert sorted(p.name for p in tmp_path.iterdir()) == ["a.mp4", "link.mp4"]


def test_a_second_writer_of_one_output_is_refused(tmp_path, capsys, clip_frames):
    from fuzz_support import writer_holding

    src = write_frames(tmp_path / "in", clip_frames[:3])
    for out, extra in ((tmp_path / "out", []), (tmp_path / "out.mp4", ["--resume"])):
        with writer_holding(out) as other:
            code, _, err = _run(capsys, src, "--light", "studio", "--out", out, *extra)
            assert code == 2 and err.count("\n") == 1, err
            assert f"another relight run (process {other.pid}) is writing {out}" in err and "wait for it" in err
            assert "free space" not in err
            assert not out.exists() and not (tmp_path / "out.mp4.frames").exists()
        code, _, err = _run(capsys, src, "--light", "studio", "--out", out, *extra)  # the writer is gone
        assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in", "out", "out.mp4"]  # no lock file left


def test_what_a_killed_run_left_is_cleared_by_the_next(tmp_path, capsys, clip_frames):
    import os
    import signal
    import subprocess
    import sys
    import time

    from clip_support import REPO

    src = write_video(tmp_path / "in.mp4", person_clip(60))
    out = tmp_path / "out.mp4"
    run = subprocess.Popen([sys.executable, "-m", "relight.cli", "video", str(src), "--light", "studio", "--out",
                            str(out), "--quality", "draft", "--threads", "1"], cwd=REPO,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        deadline = time.monotonic() + 120
        while not list(tmp_path.glob(".out.mp4.*.tmp.mp4")) and run.poll() is None and time.monotonic() < deadline:
            time.sleep(0.02)
        os.kill(run.pid, signal.SIGKILL)  # kill -9 while the video is being written
    finally:
        run.wait(timeout=60)
    assert run.returncode == -signal.SIGKILL
    left = sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".out.mp4"))
    assert any(name.endswith(".tmp.mp4") for name in left), left
    folder = tmp_path / "frames"
    folder.mkdir()
    (folder / ".frame_000002.png.k9_left_.tmp.png").write_bytes(b"half")  # a frame killed mid-write
    for target in (out, folder):
        code, _, err = _run(capsys, src if target == out else write_video(tmp_path / "short.mp4", clip_frames[:2]),
                            "--light", "studio", "--out", target)
        assert code == 0, err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["frames", "in.mp4", "out.mp4", "short.mp4"]
    assert sorted(p.name for p in folder.iterdir()) == [".relight-video.json", "frame_000001.png",
                                                        "frame_000002.png"]


def _refused_inputs(d):
    """Inputs that `relight video` refuses (exit 2), each found only once the job has begun."""
    from fuzz_support import png_bytes

    frames = person_clip(4)
    data = write_video(d / "in.mkv", frames).read_bytes()
    (d / "trunc.mkv").write_bytes(data[:len(data) // 3])
    (d / "ones").mkdir()
    for i in range(2):
        Image.new("RGB", (1, 1), (90, 80, 70)).save(d / "ones" / f"f_{i + 1:04d}.png")
    write_frames(d / "one", frames[:2])
    (d / "bomb").mkdir()  # 100 MP declared: past Pillow's warning size and the default --max-pixels
    (d / "bomb" / "f_0001.png").write_bytes(png_bytes(8, 8, declared=(10000, 10000)))
    return {"truncated mkv": ([d / "trunc.mkv"], "the video is cut short"),
            "1x1 frames": ([d / "ones"], "too small"),
            "oversized frame": ([d / "one", "--max-pixels", "1000"], "over the limit"),
            "person 2 of 1": ([d / "one", "--person", "2"], "shows 1 person"),
            "bomb header": ([d / "bomb"], "10000x10000")}


def test_refused_inputs_leave_nothing_and_only_the_project_speaks(tmp_path, capsys):
    import warnings

    (tmp_path / "in").mkdir()
    for name, (argv, message) in _refused_inputs(tmp_path / "in").items():
        for out in (tmp_path / "out", tmp_path / "out.mp4"):
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                code, _, err = _run(capsys, *argv, "--light", "studio", "--out", out,
                                    *(["--resume"] if out.suffix else []))
            assert code == 2 and err.count("\n") == 1 and message in err, (name, err)
            assert [str(w.message) for w in caught] == [], name  # no DecompressionBombWarning before ours
            assert sorted(p.name for p in tmp_path.iterdir()) == ["in"], (name, out)


def test_an_output_named_as_a_file_of_another_format_is_refused(tmp_path, capsys, clip_frames):
    src = write_frames(tmp_path / "in", clip_frames[:2])
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "o.gif")
    assert code == 2 and ".gif is not a format" in err and ".mp4" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]


def test_a_read_only_output_is_exit_2_for_a_video_and_a_folder(tmp_path, capsys, monkeypatch, clip_frames):
    import errno
    import os

    src = write_frames(tmp_path / "in", clip_frames[:2])
    ro = tmp_path / "ro"
    ro.mkdir()

    def read_only(call):  # a read-only mount under ro/ (the tests run as root: chmod would not stop them)
        def guarded(path, *a, **k):
            if str(path).startswith(str(ro)) and (call is os.mkdir or a and a[0] & (os.O_WRONLY | os.O_RDWR)):
                raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(path))
            return call(path, *a, **k)
        return guarded

    monkeypatch.setattr(os, "open", read_only(os.open))
    monkeypatch.setattr(os, "mkdir", read_only(os.mkdir))
    for out in (ro / "o.mp4", ro / "frames"):
        code, _, err = _run(capsys, src, "--light", "studio", "--out", out)
        assert code == 2 and err.count("\n") == 1, err
        assert "Read-only file system" in err and "choose an output in a folder you can write to" in err
    assert list(ro.iterdir()) == []


def test_progress_is_reported_when_stderr_is_not_a_terminal(tmp_path, capsys, monkeypatch, clip_frames):
    from relight.command import cli_output

    src = write_frames(tmp_path / "in", clip_frames[:4])
    monkeypatch.setattr(cli_output, "PROGRESS_EVERY", 0.0)  # a line at every frame
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "out")
    assert code == 0, err
    assert [line.split(",")[0] for line in err.strip().splitlines()] == [
        f"relight video: {i} of 4 frames ({25 * i}%)" for i in (1, 2, 3, 4)]


def _tagged_video(path, frames, **tags):
    """A video written with PyAV directly, carrying exactly `tags` (none: an untagged stream)."""
    from relight.files.video_out import encode_srgb8

    h, w = frames[0].shape[:2]
    with av.open(str(path), "w") as c:
        v = c.add_stream("libx264", rate=24)
        v.width, v.height, v.pix_fmt = w, h, "yuv420p"
        for key, value in tags.items():
            setattr(v.codec_context, key, value)
        for i, f in enumerate(frames):
            frame = av.VideoFrame.from_ndarray(encode_srgb8(f), format="rgb24")
            frame = frame.reformat(format="yuv420p", dst_colorspace="itu601",
                                   dst_color_range="JPEG" if tags.get("color_range") == 2 else "MPEG")
            frame.pts = i
            c.mux(v.encode(frame))
        c.mux(v.encode(None))
    return path


def _tags(path) -> dict:
    with av.open(str(path)) as c:
        ctx = c.streams.video[0].codec_context
        return {k: int(getattr(ctx, k)) for k in ("colorspace", "color_primaries", "color_trc", "color_range")}


def test_output_colour_tags_are_the_inputs_and_only_those(tmp_path, capsys, clip_frames):
    untagged = _tagged_video(tmp_path / "plain.mp4", clip_frames[:3])
    assert _tags(untagged) == {"colorspace": 2, "color_primaries": 2, "color_trc": 2, "color_range": 0}
    pal = {"colorspace": 5, "color_primaries": 5, "color_trc": 6, "color_range": 2}  # BT.601 625, full range
    tagged = _tagged_video(tmp_path / "pal.mp4", clip_frames[:3], **pal)
    for src, want in ((untagged, _tags(untagged)), (tagged, pal)):
        code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / f"relit_{src.name}")
        assert code == 0, err
        assert _tags(tmp_path / f"relit_{src.name}") == want
        # the background comes back as it went in, within one more lossy generation (1-1.5 codes;
        # a range mix-up, limited against full, would be 5-10)
        got = next(video_io.open_clip(tmp_path / f"relit_{src.name}").frames()).codes
        was = next(video_io.open_clip(src).frames()).codes
        assert np.abs(got[:, :20].astype(int) - was[:, :20]).mean() < 3
    frames = write_frames(tmp_path / "frames", clip_frames[:2])  # sRGB images: tagged as sRGB
    code, _, err = _run(capsys, frames, "--light", "studio", "--out", tmp_path / "from_frames.mp4")
    assert code == 0, err
    assert _tags(tmp_path / "from_frames.mp4") == {"colorspace": 1, "color_primaries": 1, "color_trc": 13,
                                                    "color_range": 1}


def test_a_frame_found_damaged_mid_job_removes_the_frames_already_written(tmp_path, capsys, clip_frames):
    """A refusal found once frames were written (the 6th of 8 frames has a span of its pixel data zeroed:
    its header and chunks read, its pixels do not) leaves nothing: the frames this run wrote go with its
    settings and folder. (A frame whose header is damaged is refused before: test_cli_video_headers.py.)"""
    src = write_frames(tmp_path / "in", clip_frames[:8])
    data = (src / "f_0006.png").read_bytes()
    middle = data.index(b"IDAT") + len(data) // 3
    (src / "f_0006.png").write_bytes(data[:middle] + bytes(64) + data[middle + 64:])
    for out, extra in ((tmp_path / "out", []), (tmp_path / "o.mp4", ["--resume"]), (tmp_path / "v.mp4", [])):
        code, _, err = _run(capsys, src, "--light", "studio", "--out", out, *extra)
        assert code == 2 and err.count("\n") == 1 and "f_0006.png: corrupt or truncated image" in err, err
        assert sorted(p.name for p in tmp_path.iterdir()) == ["in"], err


def test_a_full_disk_at_the_settings_file_leaves_no_folder(tmp_path, capsys, monkeypatch, clip_frames):
    from relight.files import fileio

    src = write_frames(tmp_path / "in", clip_frames[:2])
    monkeypatch.setattr(fileio, "atomic_write_text", _disk_full)
    code, _, err = _run(capsys, src, "--light", "studio", "--out", tmp_path / "out")
    assert code == cli_video.EXIT_FAILED
    assert err == (f"relight video: error: output disk full: {tmp_path / 'out' / cli_video.JOB_FILE}; nothing "
                   "written: free space and rerun\n")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["in"]
