"""Fuzzing `relight video` (Hypothesis; profile in fuzz_support): generated command lines on
mutated clips.

The clips: an .mp4 with its index first and an .mkv (each frame declared, 8 frames of a person
with film grain), a .webm, a folder of PNG frames and one of EXR frames; each drawn whole or
mutated (cut at any fraction of its bytes, bytes flipped, a span zeroed or removed, junk
appended; a folder's frame cut short, replaced by junk or by a frame of another size, or
removed). The options mix good and hostile values (--stability, --rotate, --exposure, --fps,
--threads, --max-pixels, --person, --format, --layers, --resume, --filter, --matte) and the
output is a video, a folder, or a bad path (another format, a missing folder, the input itself).

Property, read at the file-descriptor level (FFmpeg's own prints count): exit 0 with a whole
output, or exit 2 with one `relight video: error:` line and nothing left in the output's folder;
never a traceback, a Python warning or a partial output. Whole: the frames the command reports
are the frames in the output (decoded by PyAV for a video, read for a folder), as many as the
input declares (a folder: its files; a video: its container's count or duration x rate, within
one frame of rounding), no temporary left.
"""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import av
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from clip_support import grainy_video, person_clip, write_frames, write_video
from fuzz_support import PROFILE, accepted_share, fuzz_settings, new_case, record
from relight.cli import main
from relight.files.exr import read_exr

FRAMES = 8


@pytest.fixture(scope="module")
def clips(tmp_path_factory) -> dict[str, Path]:
    tmp = tmp_path_factory.mktemp("fuzz-video")
    frames = person_clip(4)
    return {"mp4": grainy_video(tmp / "clip.mp4", n=FRAMES), "mkv": grainy_video(tmp / "clip.mkv", n=FRAMES),
            "webm": write_video(tmp / "clip.webm", frames[:3]), "png": write_frames(tmp / "png", frames),
            "exr": write_frames(tmp / "exr", frames[:3], fmt="exr")}


NUMBER_TEXT = st.one_of(
    st.floats(-2, 2).map(lambda v: f"{v:.3g}"),
    st.integers(-3, 10**6).map(str),
    st.sampled_from(["1e308", "-inf", "nan", "0", "", "-", "0x10", "1/0", "30000/1001", "9" * 30]),
    st.text(max_size=5),
)
SANE = {"--stability": st.sampled_from(["0", "0.5", "1", "0.25"]), "--rotate": st.sampled_from(["0", "90", "-45"]),
        "--exposure": st.sampled_from(["0", "1.5", "-2"]), "--threads": st.sampled_from(["1", "2"]),
        "--filter": st.just("ema"), "--matte": st.sampled_from(["person", "network"]), "--person": st.just("1")}
HOSTILE = ["--stability", "--rotate", "--exposure", "--threads", "--max-pixels", "--person", "--fps", "--format",
           "--layers", "--resume", "--filter", "--matte", "--quality", "--mask", "--bogus"]


def _mutated(draw, data: bytes) -> bytes:
    how = draw(st.sampled_from(["cut", "flip", "zero", "splice", "append"]))
    n = len(data)
    if how == "cut":
        return data[:int(n * draw(st.floats(0.0, 0.995)))]
    at = draw(st.integers(0, n - 1))
    if how == "flip":
        out = bytearray(data)
        for i in draw(st.lists(st.integers(0, n - 1), min_size=1, max_size=8)) + [at]:
            out[i] ^= draw(st.integers(1, 255))
        return bytes(out)
    span = draw(st.integers(1, max(1, n // 8)))
    if how == "zero":
        return data[:at] + bytes(min(span, n - at)) + data[at + span:]
    if how == "splice":
        return data[:at] + data[at + span:]
    return data + draw(st.binary(min_size=1, max_size=64))


def _input(draw, clips, folder: Path, sane: bool) -> Path:
    """The clip of this case in `folder`: one of the base clips, whole or mutated."""
    import shutil

    kind = draw(st.sampled_from(sorted(clips)))
    src = clips[kind]
    if src.is_dir():
        dst = folder / kind
        shutil.copytree(src, dst)
        if not sane:
            files = sorted(dst.iterdir())
            victim = files[draw(st.integers(0, len(files) - 1))]
            how = draw(st.sampled_from(["cut", "junk", "size", "remove", "whole"]))
            if how == "cut":
                data = victim.read_bytes()
                victim.write_bytes(data[:int(len(data) * draw(st.floats(0.0, 0.99)))])
            elif how == "junk":
                victim.write_bytes(draw(st.binary(max_size=64)))
            elif how == "size":
                victim.unlink()
                Image.new("RGB", (40, 30), (90, 80, 70)).save(victim.with_suffix(".png"))
            elif how == "remove":
                victim.unlink()
        return dst
    data = src.read_bytes()
    dst = folder / src.name
    dst.write_bytes(data if sane or draw(st.integers(0, 4)) == 0 else _mutated(draw, data))
    return dst


@st.composite
def video_argv(draw, clips, folder: Path) -> list[str]:
    sane = draw(st.booleans())  # half the cases: a whole clip and good options (else most runs end early)
    argv = ["video", str(_input(draw, clips, folder, sane))]
    argv += ["--light", draw(st.sampled_from(["studio", "sunset"] if sane else ["studio", "no-such-preset", ""]))]
    out = draw(st.sampled_from(["o.mp4", "o.webm", "f"] if sane else
                               ["o.mp4", "o.mkv", "o.mov", "f", "o.gif", "nowhere/o.mp4", "outdir", "=input"]))
    argv += ["--out", argv[1] if out == "=input" else str(folder / "out" / out), "--quality", "draft"]
    if sane:
        for option in draw(st.lists(st.sampled_from(sorted(SANE)), max_size=3, unique=True)):
            argv += [option, draw(SANE[option])]
        return argv + (["--threads", "1"] if "--threads" not in argv else [])
    for option in draw(st.lists(st.sampled_from(HOSTILE), max_size=3)):
        argv.append(option)
        if option == "--format":
            argv.append(draw(st.sampled_from(["png", "exr", "jpg"])))
        elif option == "--filter":
            argv.append(draw(st.sampled_from(["ema", "flow", "x"])))
        elif option == "--matte":
            argv.append(draw(st.sampled_from(["person", "network", "x"])))
        elif option == "--quality":
            argv.append(draw(st.sampled_from(["draft", "huge"])))
        elif option == "--mask":
            argv.append(str(folder / "mask.png"))
        elif option not in ("--layers", "--resume", "--bogus"):
            argv.append(draw(NUMBER_TEXT))
    return argv


def _declared(path: Path) -> int | None:
    """The frames a clip declares, read here with PyAV (a folder: its frame files)."""
    if path.is_dir():
        return len([p for p in path.iterdir() if not p.name.startswith(".")])
    try:
        with av.open(str(path)) as c:
            s = c.streams.video[0]
            rate = s.average_rate or s.guessed_rate
            seconds = (float(s.duration * s.time_base) if s.duration else
                       c.duration / 1e6 if c.duration else None)
            return s.frames or (round(seconds * float(rate)) if seconds and rate else None)
    except (av.error.FFmpegError, IndexError, ValueError, OverflowError):
        return None


def _output_frames(out: Path) -> int:
    """The frames in an output: a video's, decoded by PyAV; a folder's, each read whole."""
    if out.is_dir():
        frames = [p for p in out.iterdir() if not p.name.startswith(".")]
        for p in frames:
            if p.suffix == ".exr":
                assert all(np.all(np.isfinite(a)) for a in read_exr(p).values()), p
            else:
                with Image.open(p) as im:
                    im.load()
        return len(frames)
    with av.open(str(out)) as c:
        return sum(1 for _ in c.decode(video=0))


def _check(argv: list[str], folder: Path, capfd) -> int:
    source = Path(argv[1])
    kept = source.read_bytes() if source.is_file() else None
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            code = main(argv)
    except BaseException as exc:  # main() must turn everything into an exit status
        record("cli.video", type(exc).__name__)
        raise
    stdout, err = capfd.readouterr()
    if caught:
        record("cli.video", "warning")
    assert not caught, [f"{w.category.__name__}: {w.message}" for w in caught]
    record("cli.video", f"exit {code}")
    assert code in (0, 2), (code, err)
    assert "Traceback" not in err and "Warning:" not in err, err
    lines = err.splitlines()
    # nothing from FFmpeg, Pillow, ... (argparse's usage errors are `relight: error: ...`)
    assert all(line.startswith(("relight video: ", "relight: error: ")) for line in lines), err
    left = sorted(str(p.relative_to(folder / "out")) for p in (folder / "out").rglob("*") if p.name != "outdir")
    out = Path(argv[argv.index("--out") + 1])
    if code == 2:
        assert [line for line in lines if ": error: " in line] == [lines[-1]], err
        assert left == [], (err, left)  # nothing partial, no lock, no settings file
        if kept is not None:
            assert source.read_bytes() == kept  # an output that is the input leaves it as it was
        return code
    assert not any(": error: " in line for line in lines), err
    assert not any(".tmp" in name or name.endswith(".lock") for name in left), left
    relit = int(stdout.split("relit ")[1].split(" frames")[0])
    assert _output_frames(out) == relit, (stdout, left)
    declared = _declared(source)
    assert declared is None or relit >= declared - (0 if source.is_dir() else 1), (declared, stdout)
    return code


def test_fuzz_video_arguments_and_clips(clips, capfd):
    # "sane" cases (half) are a whole clip with good options: valid by construction, so the floor is
    # half that share, a quarter of the calls (fuzz_support.accepted_share)
    @given(st.data())
    @fuzz_settings(1.0 if PROFILE == "ci" else 0.2)  # a run relights a clip: 0.2-1 s a case
    def case(data):
        folder = Path(tempfile.mkdtemp(dir=clips["mp4"].parent))
        (folder / "out" / "outdir").mkdir(parents=True)
        Image.new("L", (8, 8), 255).save(folder / "mask.png")
        argv = data.draw(video_argv(clips, folder))
        new_case("test_fuzz_video_arguments_and_clips")
        _check(argv, folder, capfd)

    with accepted_share("cli.video", 0.25, accepted=("exit 0",)):
        case()
