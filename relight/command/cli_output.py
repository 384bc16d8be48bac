"""What `relight image` and `relight video` do around their outputs: refuse an output that is
one of the inputs or names an unwritable format, hold the one writer's lock of an output and
clear what a killed run left there, and report progress (a bar on a terminal, a plain line
now and then in a log file)."""

from __future__ import annotations

import sys
from contextlib import contextmanager
from pathlib import Path

__all__ = ["PROGRESS_EVERY", "Progress", "check_folder_name", "check_not_an_input", "claim_output"]

PROGRESS_EVERY = 10.0  # seconds between progress lines when stderr is not a terminal
# extensions of files (images, videos, archives, documents) that a folder of frames is not named with
FILE_SUFFIXES = {".png", ".jpg", ".jpeg", ".exr", ".tif", ".tiff", ".webp", ".bmp", ".gif", ".hdr", ".avi",
                 ".mpg", ".mpeg", ".mp4", ".mov", ".m4v", ".mkv", ".webm", ".wmv", ".flv", ".ts", ".mts",
                 ".ogv", ".3gp", ".apng", ".heic", ".avif", ".zip", ".json", ".txt", ".npz", ".y4m"}


def check_not_an_input(out, inputs: dict) -> None:
    """ValueError when output `out` is one of `inputs` ({what: path or None}): the same
    file by its real path (a symlink, `..`) or inode (a hard link). Writing would replace it."""
    from relight.files.fileio import same_file

    for what, path in inputs.items():
        if path is not None and Path(path).exists() and same_file(out, path):
            raise ValueError(f"--out {out} is the {what} ({path}): writing would replace it; choose "
                             "another output")


def check_folder_name(out: Path, writes: str) -> None:
    """ValueError when `out`, about to become a folder of `writes`, is not a folder yet and
    ends in a file's extension (`o.gif`): the user meant a file of a format not written."""
    if out.is_dir() or out.suffix.lower() not in FILE_SUFFIXES:
        return
    raise ValueError(f"--out {out.name}: {out.suffix} is not a format this command writes ({writes}); give "
                     "one of those, or a folder name without an extension")


@contextmanager
def claim_output(out: Path, command: str, folders=(), inputs: dict | None = None):
    """Hold the lock of output `out` (relight.files.fileio.output_lock) and remove the temporaries
    that a killed run (kill -9) left beside it or, for a folder, inside it (and inside
    `folders`, the job's other folders): with the lock held no live writer can own them.
    `inputs` ({what: path or None}): refused first when `out` is one of them (check_not_an_input)."""
    from relight.files.fileio import output_lock

    if inputs is not None:
        check_not_an_input(out, inputs)
    with output_lock(out, command, clear_in=(out, *folders)):
        yield


class _Lines:
    """tqdm's file where stderr is not a terminal: each refresh of the bar one plain line
    (tqdm writes a carriage return + the bar; a log file wants lines)."""

    def __init__(self, stream):
        self.stream = stream

    def write(self, text: str) -> None:
        text = text.strip()
        if text:
            print(text, file=self.stream, flush=True)

    def flush(self) -> None:
        pass


class Progress:
    """A progress report on stderr through tqdm: its bar on a terminal; elsewhere (a log
    file, a pipe) one plain line every PROGRESS_EVERY seconds (tqdm's mininterval), none
    at the start or the end: `relight video: 120 of 240 frames (50%), 61 s`."""

    def __init__(self, total: int | None, *, command: str, unit: str, initial: int = 0):
        from tqdm import tqdm

        self.command, self.unit = command, unit
        self.extra: dict = {}
        self.terminal = sys.stderr is not None and sys.stderr.isatty()
        if self.terminal:
            self.bar = tqdm(total=total, initial=initial, desc="relight", unit=unit, file=sys.stderr,
                            dynamic_ncols=True)
            return
        done = (f"{{n}} of {{total}} {unit}s ({{percentage:.0f}}%)" if total else f"{{n}} {unit}s")
        # delay: no line at the start; miniters=1: the interval alone decides; leave=False: no
        # line at the end. A closed stderr (None) gets nothing
        self.bar = tqdm(total=total or None, initial=initial, file=_Lines(sys.stderr), mininterval=PROGRESS_EVERY,
                        miniters=1, delay=1e-9, leave=False, disable=sys.stderr is None,
                        bar_format=f"{command}: {done}, {{elapsed_s:.0f}} s{{postfix}}")

    def update(self, n: int = 1) -> None:
        self.bar.update(n)

    def set_postfix(self, **values) -> None:
        if self.terminal:
            self.bar.set_postfix(refresh=False, **values)
            return
        self.extra.update(values)
        self.bar.set_postfix_str(", ".join(f"{k.replace('_', ' ')} {v}" for k, v in self.extra.items()),
                                 refresh=False)

    def write(self, message: str) -> None:
        if self.terminal:
            self.bar.write(message, file=sys.stderr)
        elif sys.stderr is not None:
            print(message, file=sys.stderr, flush=True)

    def close(self) -> None:
        self.bar.close()
