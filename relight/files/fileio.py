"""Atomic file writes and file hashing.

A reader never sees a half-written file: data goes to a temporary file in the
same folder (so os.replace is an atomic rename) and replaces the target only
once it is complete; on any failure the temporary file is removed.
"""

from __future__ import annotations

import hashlib
import json
import os
import tempfile
from contextlib import contextmanager
from pathlib import Path

HASH_CHUNK = 1 << 20


def file_sha256(path) -> str:
    """Hex SHA-256 of a file, read in 1 MiB chunks."""
    digest = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(HASH_CHUNK):
            digest.update(chunk)
    return digest.hexdigest()


def temp_path_beside(final: Path, suffix: str = "") -> Path:
    """A fresh temporary path next to `final`, with the permissions open() would give."""
    fd, tmp = tempfile.mkstemp(prefix=f".{final.name}.", suffix=f".tmp{suffix}", dir=final.parent)
    os.close(fd)
    umask = os.umask(0)  # mkstemp makes 0600; read the umask without changing it
    os.umask(umask)
    os.chmod(tmp, 0o666 & ~umask)
    return Path(tmp)


@contextmanager
def atomic_path(final, suffix: str = ""):
    """Yield a temporary path; on success it replaces `final`, on error it is removed.

    `suffix` keeps an extension on the temporary file for writers that pick
    the format from it (Pillow, OpenEXR).
    """
    final = Path(final)
    tmp = temp_path_beside(final, suffix)
    try:
        yield tmp
        os.replace(tmp, final)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def atomic_write_text(path, text: str) -> Path:
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return Path(path)


def atomic_write_json(path, data, **dumps_kwargs) -> Path:
    """json.dumps(data) written atomically; dumps errors leave nothing behind."""
    return atomic_write_text(path, json.dumps(data, **dumps_kwargs) + "\n")


def same_file(a, b) -> bool:
    """Whether paths `a` and `b` name one file: the same real path (symlinks and `..`
    resolved) or, when both exist, the same inode (a hard link)."""
    a, b = Path(a), Path(b)
    if os.path.realpath(a) == os.path.realpath(b):
        return True
    try:
        return os.path.samefile(a, b)
    except OSError:
        return False


# a temporary file of atomic_path / temp_path_beside: ".NAME." + mkstemp's 8 characters + ".tmp" + suffix
_TEMP_NAME = r"\.{name}\.[A-Za-z0-9_]{{8}}\.tmp(\.[A-Za-z0-9]+)?"


def stale_temps(final) -> list[Path]:
    """The temporaries that writes of `final` left beside it when their process was killed
    outright (SIGKILL: no cleanup ran). Remove them only while holding output_lock(final)."""
    import re

    final = Path(final)
    pattern = re.compile(_TEMP_NAME.format(name=re.escape(final.name)))
    try:
        return sorted(p for p in final.parent.iterdir() if pattern.fullmatch(p.name) and p.is_file())
    except FileNotFoundError:
        return []


def stale_temps_in(folder) -> list[Path]:
    """Every temporary of an atomic write left inside `folder` (see stale_temps)."""
    import re

    pattern = re.compile(_TEMP_NAME.format(name=".+"))
    try:
        return sorted(p for p in Path(folder).iterdir() if pattern.fullmatch(p.name) and p.is_file())
    except (FileNotFoundError, NotADirectoryError):
        return []


class OutputBusy(ValueError):
    """Another process holds the lock of the output."""


def lock_path(final) -> Path:
    final = Path(final)
    return final.parent / f".{final.name}.lock"


@contextmanager
def output_lock(final, what: str = "relight"):
    """Hold the one writer's lock of output `final` (a file or a folder) for the block;
    `what` (the command) is named to a second writer, with this process's id.

    The lock is an flock on `.NAME.lock` beside `final` (on Windows msvcrt's lock of one
    byte): the kernel drops it when the process ends however it ends (kill -9 included), so
    a lock is never stale. A second
    writer gets OutputBusy at once (never waits). The file is removed on release while
    still locked; a process that opened it just before re-opens the path and locks anew.
    """
    path = lock_path(final)
    while True:
        try:
            fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
        except OSError as exc:
            raise OSError(exc.errno, f"cannot write in {path.parent} ({os.strerror(exc.errno)}): "
                                     "choose an output in a folder you can write to") from None
        try:
            _try_lock(fd)
        except BlockingIOError:
            pid, _, holder = _read_head(fd).decode("utf-8", "replace").strip().partition(" ")
            os.close(fd)
            who = f"another {holder or 'relight'} run" + (f" (process {pid})" if pid.isdigit() else "")
            raise OutputBusy(f"{who} is writing {final}: wait for it to finish, or choose another "
                             "output") from None
        try:
            same = os.fstat(fd).st_ino == os.stat(path).st_ino
        except FileNotFoundError:
            same = False
        if same:
            break
        os.close(fd)  # the holder removed the file between our open and lock: lock the new one
    try:
        os.ftruncate(fd, 0)
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, f"{os.getpid()} {what}\n".encode("utf-8"))  # who holds it, for the refusal
        yield path
    finally:
        try:
            os.unlink(path)
        except OSError:
            pass
        os.close(fd)


def _read_head(fd: int) -> bytes:
    os.lseek(fd, 0, os.SEEK_SET)
    return os.read(fd, 200)


try:
    import fcntl

    def _try_lock(fd: int) -> None:
        """Lock the file exclusively or raise BlockingIOError (another holds it)."""
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
except ImportError:  # Windows: a byte far past the text locked instead (its locks are mandatory)
    import msvcrt

    def _try_lock(fd: int) -> None:
        """Lock the file exclusively or raise BlockingIOError (another holds it)."""
        os.lseek(fd, 1 << 20, os.SEEK_SET)
        try:
            msvcrt.locking(fd, msvcrt.LK_NBLCK, 1)
        except OSError:
            raise BlockingIOError from None
