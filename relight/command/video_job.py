"""The output frames of a resumable `relight video` job (relight.command.cli_video): a folder writer and
the bookkeeping beside the frames: JOB_FILE, the settings (and, once the job is complete, its frame
count and the people it relit: relight.command.clip.ClipRelighter.record), and STATE_FILE, the filters'
state at the last checkpoint (docs/video.md, "Resume, interrupts, failures")."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np

__all__ = ["Frames", "JOB_FILE", "STATE_FILE", "named"]

JOB_FILE = ".relight-video.json"
STATE_FILE = ".relight-video-state.npz"

class Frames:
    """The output frames of the job: a folder writer plus the resume bookkeeping beside them
    (JOB_FILE: the settings, and the frame count once the job is complete; STATE_FILE: the
    filter state at the last checkpoint)."""

    def __init__(self, folder: Path, names, fmt: str, fingerprint: dict, resume: bool, video: bool = False):
        import json

        from relight.files.video_out import FrameFolderWriter

        self.folder = folder
        self.writer = FrameFolderWriter(folder, fmt, names, video_codes=video)
        self.fingerprint = fingerprint
        self.created = not folder.exists()
        folder.mkdir(parents=True, exist_ok=True)
        self.done = self.writer.written()
        self.new: set[int] = set()   # the frames this run wrote
        self.checkpointed = False
        job = folder / JOB_FILE
        self.had_job = job.is_file()
        if self.done and not resume:
            raise ValueError(f"{folder} already holds {len(self.done)} frames of this clip: --resume continues "
                             "that job, or choose another output")
        self.start, self.state, self.complete, self.people = 0, None, None, None
        if resume and job.is_file():
            before = json.loads(job.read_text(encoding="utf-8"))
            self.complete = before.pop("complete_frames", None)
            self.people = before.pop("people", None)
            changed = sorted(k for k in set(before) | set(fingerprint) if before.get(k) != fingerprint.get(k))
            if changed:
                raise ValueError(f"--resume: the frames in {folder} were made with other settings "
                                 f"({', '.join(changed)} differ): rerun them with those, or use another output")
            state_path = folder / STATE_FILE
            if state_path.is_file():
                with np.load(state_path) as saved:
                    state = {k: saved[k] for k in saved.files}
                self.start = int(state.pop("next_frame"))
                self.state = state
        from relight.files.fileio import atomic_write_json

        try:
            atomic_write_json(job, fingerprint)
        except OSError as exc:
            self.discard()
            raise named(exc, job) from None

    def write(self, index: int, *frame) -> None:
        """Write frame `index` (FrameFolderWriter.write's arguments); a failure names the frame's file."""
        try:
            self.writer.write(index, *frame)
        except OSError as exc:
            raise named(exc, self.writer.path(index)) from None
        self.new.add(index)

    def checkpoint(self, next_frame: int, state: dict) -> None:
        """Save the filter state after frame next_frame - 1 (every frame before it is written)."""
        from relight.files.fileio import atomic_path

        try:
            # through memory: numpy's zip file, failing on a full disk, prints a traceback when collected
            buffer = io.BytesIO()
            np.savez_compressed(buffer, next_frame=np.int64(next_frame), **state)
            with atomic_path(self.folder / STATE_FILE, ".npz") as tmp:
                tmp.write_bytes(buffer.getbuffer())
        except OSError as exc:
            raise named(exc, self.folder / STATE_FILE) from None
        self.checkpointed = True

    def discard(self, own_frames: bool = False) -> None:
        """Remove what this run made that describes nothing: with `own_frames` (a refused input)
        the frames it wrote, then, if no frame is left, its settings and the folder if it made it."""
        if own_frames:
            for index in sorted(self.new):
                self.writer.path(index).unlink(missing_ok=True)
            self.new.clear()
            if self.checkpointed:  # it may count frames just removed: a resume replays from the start
                (self.folder / STATE_FILE).unlink(missing_ok=True)
        if self.writer.written():
            return
        if not self.had_job:
            (self.folder / JOB_FILE).unlink(missing_ok=True)
            (self.folder / STATE_FILE).unlink(missing_ok=True)
        if self.created:
            try:
                self.folder.rmdir()
            except OSError:
                pass  # something else is in it now: not ours to remove

    def finish(self, frames: int, people: dict | None = None) -> None:
        """The job is complete: its settings stay (a later --resume finds nothing to do) with `people`
        (what ClipRelighter.record says, when given), the state goes."""
        from relight.files.fileio import atomic_write_json

        people = self.people if people is None else people
        done = {"complete_frames": frames} if people is None else {"complete_frames": frames, "people": people}
        atomic_write_json(self.folder / JOB_FILE, {**self.fingerprint, **done})
        (self.folder / STATE_FILE).unlink(missing_ok=True)


def named(exc: OSError, path) -> OSError:
    """The error of a write, naming the file it was writing (not a temporary beside it)."""
    return OSError(exc.errno, exc.strerror or str(exc), str(path)) if exc.errno else exc
