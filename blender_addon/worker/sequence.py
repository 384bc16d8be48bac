"""Relight a movie or an image sequence frame by frame: what Relight Sequence
(blender_addon/blender/bl_sequence.py) runs on a worker thread. Plain Python, no bpy.

The frames are read from the files themselves, because Blender's Python gives
the pixels of a movie's first frame only: an image sequence through
relight.files.photo, a movie through PyAV when Blender's Python has it (the add-on
does not bundle it: FFmpeg is 35 MB a platform). relight.command.clip.ClipRelighter
relights them steadily over time (docs/video.md) into a new image sequence,
`<image name>_relit/frame_000001.png` ... (EXR, linear, when the input is EXR)
in a folder beside the .blend; each frame is written whole (atomically), so
Esc, which stops after the frame in progress, keeps every frame done.
"""

from __future__ import annotations

import re
from pathlib import Path

from . import engine, jobs

OUTPUT_SUFFIX = "_relit"
_NUMBER = re.compile(r"^(.*?)(\d+)(\D*)$")  # the last run of digits in a file stem


class SequenceProgress(jobs.Progress):
    """jobs.Progress plus the frames written so far (plain attributes, each replaced whole)."""

    def __init__(self):
        super().__init__()
        self.written, self.total, self.nobody = 0, 0, []


def sequence_files(first) -> list[Path]:
    """The files of the image sequence `first` belongs to: same folder, extension and name around
    the number its stem ends in, in the number's order (Blender's own sequence naming)."""
    first = Path(first)
    m = _NUMBER.match(first.stem)
    if m is None:
        return [first] if first.is_file() else []
    head, tail = m.group(1), m.group(3)
    found = []
    for p in first.parent.iterdir():
        n = _NUMBER.match(p.stem)
        if p.suffix.lower() == first.suffix.lower() and n and n.group(1) == head and n.group(3) == tail:
            found.append((int(n.group(2)), p))
    return [p for _, p in sorted(found)]


def output_folder(blend_path: str, image_name: str) -> Path:
    """Where the relit frames go: a folder beside the saved .blend."""
    if not blend_path:
        raise ValueError("Save the .blend file first: the relit frames go into a folder beside it.")
    safe = re.sub(r"[^\w.-]+", "_", Path(image_name).stem).strip("._") or "sequence"
    return Path(blend_path).parent / f"{safe}{OUTPUT_SUFFIX}"


def frames_in(folder) -> list[Path]:
    """The relit frames a run left in `folder` (frame_000001.png / .exr ...), in order."""
    folder = Path(folder)
    if not folder.is_dir():
        return []
    return sorted(p for p in folder.iterdir() if _FRAME.fullmatch(p.name))


_FRAME = re.compile(r"frame_\d{6,}\.(png|exr)")


def open_frames(path: str, source: str, max_pixels: int | None = None):
    """(relight.files.video_io clip, output format) of a SEQUENCE's files or a MOVIE."""
    from relight.files.video_io import FrameFolder, VideoFile

    p = Path(path)
    if source == "SEQUENCE":
        files = sequence_files(p)
        if not files:
            raise ValueError(f"No frames of the image sequence '{p.name}' were found on disk.")
        clip = FrameFolder.from_files(files, max_pixels=max_pixels)
        return clip, "exr" if files[0].suffix.lower() == ".exr" else "png"
    if source == "MOVIE":
        try:
            import av  # noqa: F401
        except ImportError:
            raise ValueError("Relighting a movie needs PyAV in Blender's Python (pip install av), or render the "
                             "movie to an image sequence first.") from None
        if not p.is_file():
            raise ValueError(f"The movie file '{path}' does not exist.")
        return VideoFile(p, max_pixels), "png"
    raise ValueError("Relight Sequence works on a movie or an image sequence.")


def relight_sequence(plan: dict, progress: SequenceProgress, token: engine.CancelToken) -> dict:
    """The worker's whole job; returns {"folder", "first", "written", "total", "nobody"}.
    On Esc (token) it stops between frames and raises engine.Cancelled; the frames
    written stay (progress.written says how many)."""
    from relight.command.clip import ClipRelighter
    from relight.lighting.light import SHLight
    from relight.files.video_out import FrameFolderWriter

    from ..logic import light_sources

    progress.enter("Opening the frames", 0.0)
    clip, fmt = open_frames(plan["path"], plan["source"])
    total = clip.info.frames or 0
    progress.total = total
    relighter = plan.get("relighter") or engine.open_relighter(plan["model_path"])
    cache = light_sources.light_cache()
    coeffs = SHLight.resolve(plan["light"], relighter.sh_order, cache=cache).at(plan["rotation"], cache)
    runner = ClipRelighter(relighter, coeffs, plan["exposure"], stability=plan["stability"],
                           working_size=plan["long_side"], person=plan.get("person"),
                           matte_method=plan.get("matte_method", "ensemble"), augment=plan.get("augment", ()))
    folder = Path(plan["folder"])
    folder.mkdir(parents=True, exist_ok=True)
    for old in plan.get("replace", ()):  # an earlier run's frames, replaced as the artist asked
        Path(old).unlink(missing_ok=True)  # (all of them: a longer run's last frames would stay behind)
    writer = FrameFolderWriter(folder, fmt)
    for frame in clip.frames():
        token.check()
        progress.enter(f"Frame {frame.index + 1}" + (f" of {total}" if total else ""),
                       frame.index / max(total, frame.index + 1))
        result = runner.relight(frame.image, frame.alpha)
        if not result.person:
            progress.nobody = progress.nobody + [frame.index]
        writer.write(frame.index, result.image, None, frame.codes, result.changed)
        progress.written = frame.index + 1
    if progress.written == 0:
        raise ValueError("The sequence has no frames.")
    return {"folder": folder, "first": writer.path(0), "written": progress.written, "total": progress.written,
            "nobody": list(progress.nobody)}


def nobody_note(nobody: list[int]) -> str:
    """' (no person in frames 4-6: kept as they were)' or ''."""
    if not nobody:
        return ""
    from relight.files.video_io import frame_spans

    return f" (no person in frames {frame_spans(nobody)}: kept as they were)"
