"""`relight video`: relight everyone in a clip (or --person N), frame by frame, stable over time.

    relight video INPUT (--light HDR_OR_PRESET | --light-from PHOTO) [--rotate DEG] [--exposure EV]
                  [--no-normalize] --out OUTPUT [--format png|exr] [--layers] [--fps RATE]
                  [--stability 0..1] [--filter ema|flow] [--resume]
                  [--matte person|network] [--person N] [--model PATH] [--quality draft|balanced|best]
                  [--threads N] [--max-pixels N]

INPUT is a video file (.mp4 .mov .m4v .mkv .webm .avi) or a folder of numbered
frames (PNG/JPEG/TIFF/EXR; a frame's alpha channel is its person mask); OUTPUT a
video file (.mp4 .mov .m4v .mkv .webm: the input's frame rate, size and audio)
or a folder of frames (PNG, or EXR with linear values). The light and photo
options work as in `relight image`; relight.command.clip keeps the light, maps and
matte steady (--stability 0: every frame on its own), each person tracked with their
own. A frame without a person is written unchanged (and listed). Frames go to a folder atomically, one whole
file each; a video is written to a temporary file that replaces OUTPUT only
when complete. --resume continues an interrupted job, skipping the frames
already written and giving exactly the frames an uninterrupted run gives (a
video output keeps its frames in OUTPUT.frames/ until it is encoded). Ctrl-C
stops after the frame in progress is dropped. Exit 0 done, 1 the job failed
(disk full, ...), 2 bad input, 130 interrupted.
"""

from __future__ import annotations

import argparse
import errno
import signal
import sys
from dataclasses import dataclass, replace
from fractions import Fraction
from pathlib import Path

import numpy as np

from relight.command.request import LightRequest, PhotoRequest
from relight.command.video_job import JOB_FILE, STATE_FILE, Frames as _Frames  # noqa: F401 (the job's files)

EXIT_FAILED = 1
EXIT_INTERRUPTED = 130
CHECKPOINT_EVERY = 24   # frames between saved filter states (a resume re-runs at most this many)
WORK_SUFFIX = ".frames"  # OUTPUT.mp4.frames/: a resumable video job's frames


def register(subparsers) -> argparse.ArgumentParser:
    """Add the `video` sub-command to the `relight` command's subparsers."""
    from relight.command.cli_args import finite_float
    from relight.command.request import add_relight_parser
    from relight.command.clip import DEFAULT_STABILITY, FILTER_MODES

    p = add_relight_parser(subparsers, "video", help="relight everyone in a video or a folder of frames",
                           description=__doc__.split("\n\n")[0], source="input",
                           source_help="video file or folder of numbered frames")
    # the shared --threads counts frames analysed at once here (each network on one thread)
    p._option_string_actions["--threads"].help = ("frames analysed at once, each network on one onnxruntime "
                                                  "thread (default: the cores available)")
    p.add_argument("--out", required=True,
                   help="output video (.mp4 .mov .m4v .mkv .webm) or folder of frames")
    p.add_argument("--format", choices=("png", "exr"), default=None,
                   help="frames written to a folder: png (8-bit sRGB) or exr (linear); default exr for EXR "
                        "input frames, else png")
    p.add_argument("--layers", action="store_true",
                   help="EXR frames with the layers for Blender (Relit, Albedo, Shading, Residual, Alpha)")
    p.add_argument("--fps", type=_fps, default=None,
                   help="frame rate of a folder of frames (default 24; a video keeps its own)")
    p.add_argument("--stability", type=finite_float(0.0, 1.0, what="stability"), default=DEFAULT_STABILITY,
                   help=f"0: every frame on its own; 1: the longest smoothing (more lag); default {DEFAULT_STABILITY}")
    p.add_argument("--filter", choices=FILTER_MODES, default="ema",
                   help="how the maps follow motion: ema (default) or flow (OpenCV's DIS flow; needs "
                        "opencv-python-headless)")
    p.add_argument("--resume", action="store_true", help="continue an interrupted job with the same settings")
    p.set_defaults(func=run_video)
    return p


def _fps(text: str) -> Fraction:
    from relight.files.video_io import MAX_FPS

    try:
        value = Fraction(text)
    except (ValueError, ZeroDivisionError):
        raise argparse.ArgumentTypeError(f"invalid frame rate: {text!r} (e.g. 24, 29.97, 30000/1001)") from None
    if not 0 < value <= MAX_FPS:
        raise argparse.ArgumentTypeError(f"frame rate must be in (0, {MAX_FPS}], got {text}")
    return value


@dataclass(frozen=True)
class VideoRequest:
    """`relight video`'s parsed options, checked once at the command's edge (from_args), and the light
    and photo options as values."""

    input: str
    out: str
    format: str | None
    layers: bool
    fps: Fraction | None
    stability: float
    filter: str
    resume: bool
    light: LightRequest
    photo: PhotoRequest

    @classmethod
    def from_args(cls, args: argparse.Namespace) -> "VideoRequest":
        if args.mask is not None:
            raise ValueError("--mask applies to one photo; give the frames an alpha channel, or let the person "
                             "matte find the person in each frame")
        if args.refine:
            raise ValueError("--refine applies to photos (relight image, relight light): a clip's light is the "
                             "shot's, held steady over its frames (--stability)")
        from relight.command.request import relight_options

        return cls(args.input, args.out, args.format, args.layers, args.fps, args.stability, args.filter,
                   args.resume, *relight_options(args))


def _plan(request: VideoRequest, info, exr_frames: bool = False):
    """(kind "video" | "frames", output path, frames folder or None, frame format); `exr_frames`: the
    input is frames of which one is an EXR (its header's format)."""
    from relight.command.cli_output import check_folder_name, check_not_an_input
    from relight.files.fileio import same_file
    from relight.files.video_out import OUTPUT_VIDEO_SUFFIXES

    out = Path(request.out)
    source = Path(request.input)
    if source.is_dir() and out.exists() and same_file(out, source):
        raise ValueError("--out must differ from the input folder")
    check_not_an_input(out, {"input": source, "--light map": request.light.map_file,
                             "--light-from photo": request.light.light_from, "--mask": request.photo.mask})
    if out.suffix.lower() in OUTPUT_VIDEO_SUFFIXES:
        if request.layers or request.format is not None:
            raise ValueError("--layers and --format apply to a folder of frames, not to a video output")
        if not out.parent.is_dir():
            raise ValueError(f"output folder does not exist: {out.parent}")
        if out.is_dir():
            raise ValueError(f"--out {out} is a folder")
        work = out.with_name(out.name + WORK_SUFFIX) if request.resume else None
        return "video", out, work, "png"
    if out.exists() and not out.is_dir():
        raise ValueError(f"--out {out} exists and is not a folder (a video output ends in "
                         f"{', '.join(OUTPUT_VIDEO_SUFFIXES)})")
    check_folder_name(out, f"videos {' '.join(OUTPUT_VIDEO_SUFFIXES)}, or a folder of PNG or EXR frames")
    if not out.parent.is_dir():
        raise ValueError(f"output folder does not exist: {out.parent}")
    fmt = request.format or ("exr" if request.layers or exr_frames else "png")
    if request.layers and fmt != "exr":
        raise ValueError("--layers writes multi-layer EXR frames: leave --format out or give --format exr")
    return "frames", out, out, fmt


def _exr_frames(clip) -> bool:
    """Whether a folder of frames holds an EXR frame, as its headers (read when it was opened) say."""
    return any(header.format == "EXR" for header in getattr(clip, "headers", ()))


def _fingerprint(request: VideoRequest, info, relighter) -> dict:
    """What decides the frames: a resumed job must have the same."""
    light, photo = request.light, request.photo
    return {"input": str(Path(request.input).resolve()), "frames": info.frames, "size": [info.width, info.height],
            "light": light.light, "light_from": light.light_from and str(Path(light.light_from).resolve()),
            "rotate": light.rotate, "exposure": light.exposure, "normalize": light.normalize,
            "model": relighter.sha256, "working_size": relighter.working_size, "matte": photo.matte,
            "person": photo.person, "stability": request.stability, "filter": request.filter,
            "format": request.format, "layers": request.layers}


def _write_failure(exc: OSError, out: Path, frames, kind: str) -> str:
    """The one line of a write that failed mid-job (a full disk, ...): the file, the cause, what is left."""
    cause, todo = {errno.ENOSPC: ("output disk full", "free space"), errno.EDQUOT: ("disk quota exceeded", "free space"),
                   errno.EFBIG: ("file too large for the file system or the process's file-size limit (ulimit -f)",
                                 "choose an output on another disk")}.get(
        exc.errno, (exc.strerror or "cannot write", "make the output writable"))
    line = f"{cause}: {exc.filename or out}" if exc.errno else str(exc)  # else a library's line, naming the file
    if frames is not None:
        frames.discard()  # no frame written: no settings left that describe none
        left = len(frames.writer.written())
        kept = f"{left} whole frames are in {frames.folder}" if left else "no frame was written"
        if kind == "video":
            kept = f"no video written; {kept}" if left else "no video or frame written"
        return f"{line}; {kept}: {todo} and rerun" + (" with --resume" if left else "")
    return f"{line}; {'no video' if kind == 'video' else 'nothing'} written: {todo} and rerun"


def _empty_layers(frame: np.ndarray) -> dict:
    zeros = np.zeros_like(frame)
    return {"albedo": zeros, "shading": zeros, "residual": zeros, "alpha": np.zeros(frame.shape[:2], np.float32)}


def _terminate_as_interrupt(signum, frame):
    raise KeyboardInterrupt


def _on_sigterm(handler):
    """Set SIGTERM's handler (main thread only: elsewhere Python cannot); returns the previous one."""
    import threading

    if handler is None or threading.current_thread() is not threading.main_thread():
        return None
    return signal.signal(signal.SIGTERM, handler)


def run_video(args) -> int:
    """Entry point of `relight video` (argparse namespace from register()): its request built once, here."""
    from relight.command.cli_output import claim_output
    from relight.files.video_io import open_clip

    request = VideoRequest.from_args(args)
    clip = open_clip(request.input, request.fps, request.photo.max_pixels)
    info = clip.info
    kind, out, folder, fmt = _plan(request, info, _exr_frames(clip))
    with claim_output(out, "relight video", folders=[folder] if folder is not None else []):
        return _run(request, clip, info, kind, out, folder, fmt)


def _run(request: VideoRequest, clip, info, kind: str, out: Path, folder: Path | None, fmt: str) -> int:
    """run_video once it holds the output's lock."""
    from relight.command.request import relighter_and_light
    from relight.command.clip import ClipRelighter
    from relight.models.session import cores_available
    from relight.files.video_io import frame_spans
    from relight.files.video_out import VideoWriter

    photo = request.photo
    # frames are analysed `workers` at once, each network on one thread: on few cores this beats
    # onnxruntime's intra-op threads on these small inputs (docs/BENCHMARKS.md)
    workers = photo.threads or cores_available()
    relighter, light = relighter_and_light(request.light, replace(photo, threads=1))
    preset = photo.preset
    runner = ClipRelighter(relighter, light, matte=photo.matte, person=photo.person,
                           stability=request.stability, mode=request.filter, threads=1,
                           matte_method=preset.matte_method, augment=preset.augment)
    if request.filter == "flow":
        from relight.command.clip_maps import dis_flow

        dis_flow(np.zeros((8, 8), np.float32), np.zeros((8, 8), np.float32))  # OpenCV missing: fail now
    names = info.names if info.kind == "frames" and kind == "frames" else None  # None: frame_000001, ...
    frames = video = None
    previous = _on_sigterm(_terminate_as_interrupt)
    try:
        if folder is not None:
            frames = _Frames(folder, names, fmt, _fingerprint(request, info, relighter), request.resume,
                             video=kind == "video")
            if frames.complete is not None and len(frames.done) >= frames.complete and kind == "frames":
                frames.finish(frames.complete)
                print(f"all {frames.complete} frames are already in {out}")
                return 0
            if frames.state is not None:
                runner.load_state(frames.state)
        if kind == "video" and folder is None:
            video = VideoWriter(out, info, audio_from=info.path if info.kind == "video" else None)
        done, written, nobody, clamped = _loop(clip, runner, frames, video, request, info, workers)
        if video is not None:
            video.close()
            video = None
        elif kind == "video":
            _encode_folder(frames, info, out, photo.max_pixels)
        else:
            frames.finish(frames.start + done, runner.record())
    except KeyboardInterrupt:
        if video is not None:
            video.abort()
        where = f"whole frames are in {folder}; rerun with --resume to continue" if folder is not None else \
            f"no video written (with --resume an interrupted video job keeps its frames in {out}{WORK_SUFFIX})"
        print(f"relight video: interrupted: {where}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except OSError as exc:
        if video is not None:
            video.abort()
        print(f"relight video: error: {_write_failure(exc, out, frames, kind)}", file=sys.stderr)
        return EXIT_FAILED
    except BaseException as exc:
        if video is not None:
            video.abort()
        if frames is not None and isinstance(exc, (ValueError, MemoryError)):
            frames.discard(own_frames=True)  # refused input (found mid-job: a damaged clip): leave nothing
        raise
    finally:
        _on_sigterm(previous)
    if nobody:
        print(f"relight video: no person in frames {frame_spans(nobody)}: written unchanged", file=sys.stderr)
    if clamped > 0.01:
        print(f"relight video: warning: negative light (SH ringing) clamped to 0 on up to {clamped:.1%} of the "
              "person", file=sys.stderr)
    people = runner.record()
    if people["found"] > 1 or people["frames_with_people_left"]:  # (one person: the lines as they were)
        print(_people_line(people))
    kept = len(frames.done) if frames is not None else 0
    print(f"relit {written} frames into {out}" + (f" ({kept} were there already)" if kept else ""))
    return 0


def _people_line(record: dict) -> str:
    """What the record (ClipRelighter.record) says of the people, in one line."""
    line = (f"people: up to {record['found']} found in a frame, up to {record['relit']} relit under the shot's "
            f"one light, {len(record['tracks'])} tracked")
    left = record["frames_with_people_left"]
    return line + (f"; someone too small to relight left as they were in {left} frames" if left else "")


def _loop(clip, runner, frames, video, request: VideoRequest, info, workers: int):
    """Relight every frame from the resume point: `workers` frames analysed at once (matte and
    network, ClipRelighter.analyse), finished and written in order; (frames processed, frames
    written, frames without a person, largest clamped share)."""
    from collections import deque
    from concurrent.futures import ThreadPoolExecutor

    from relight.command.cli_output import Progress
    from relight.files.video_io import frame_spans, prefetch

    start = frames.start if frames is not None else 0
    bar = Progress(info.frames, command="relight video", unit="frame", initial=start)
    nobody, clamped, count, written, last = [], 0.0, 0, 0, start - 1
    committed = None  # (next frame, the filter state once every frame before it is written)

    def emit(frame, analysis):
        nonlocal clamped, count, written, last, committed
        index = frame.index
        skip = frames is not None and index in frames.done
        result = runner.finish(analysis, layers=request.layers and not skip)
        if not result.person:
            nobody.append(index)
            bar.set_postfix(no_person=len(nobody))
        clamped = max(clamped, result.clamped)
        if frames is not None:
            if not skip:
                layers = (result.layers or _empty_layers(result.image)) if request.layers else None
                frames.write(index, result.image, layers, frame.codes, result.changed)
                written += 1
            # a snapshot (the filters replace their arrays, never change them in place): an
            # interrupt during the next frame's finish() or write() must not save that frame's state
            committed = (index + 1, runner.state())
            if (index + 1) % CHECKPOINT_EVERY == 0:
                frames.checkpoint(*committed)
        else:
            video.write(result.image, frame.codes, result.changed)
            written += 1
        count, last = count + 1, index
        bar.update(1)

    pool = ThreadPoolExecutor(max_workers=workers, thread_name_prefix="relight-analyse")
    pending: deque = deque()
    try:
        for frame in prefetch(clip.frames(start)):
            pending.append((frame, pool.submit(runner.analyse, frame.image, frame.alpha)))
            if len(pending) > workers:
                frame, future = pending.popleft()
                emit(frame, future.result())
        while pending:
            frame, future = pending.popleft()
            emit(frame, future.result())
    except KeyboardInterrupt:
        if frames is not None and committed is not None:
            try:
                frames.checkpoint(*committed)
            except OSError:
                pass  # a full disk: the last checkpoint stands, the resume re-runs a few more frames
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)
        bar.close()
    if frames is not None:  # every frame of the clip must now be there (a resume may have started late)
        total = len(frames.writer.names) if frames.writer.names is not None else last + 1
        missing = [i for i in range(total) if not frames.writer.done(i)]
        if missing:
            raise ValueError(f"{request.input}: frames {frame_spans(missing)} are missing from {frames.folder} (the clip "
                             f"ended after {last + 1} frames)")
    return count, written, nobody, clamped


def _encode_folder(frames, info, out: Path, max_pixels: int | None) -> None:
    """The resumable video job's frames (OUTPUT.frames/) into OUTPUT; the folder goes once it is.
    Their headers are read as the input's were, under the job's --max-pixels (a frame the input's
    limit allowed is allowed here)."""
    import shutil

    from relight.files.video_io import FrameFolder
    from relight.files.video_out import VideoWriter

    video = VideoWriter(out, info, audio_from=info.path if info.kind == "video" else None)
    try:
        for codes in FrameFolder(frames.folder, info.fps, max_pixels).codes():
            video.write_codes(codes)  # the codes the direct path would have encoded
    except BaseException:
        video.abort()
        raise
    video.close()
    shutil.rmtree(frames.folder)
