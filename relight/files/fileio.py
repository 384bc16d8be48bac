"""Atomic file writes and file hashing.

A reader never sees a half-written file: data goes to a temporary file in the
same folder (so os.replace is an atomic rename) and replaces the target only
once it is complete; on any failure the temporary file is removed.
"""

from __future__ import annotations

import hashlib
import json
import os
import stat
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
    except OSError as exc:
        tmp.unlink(missing_ok=True)
        if _names_nothing(exc):  # a full disk's bare "[Errno 28] No space left on device": say which file
            raise WriteError(exc.errno, exc.strerror, str(final)) from None
        raise
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


class WriteError(OSError):
    """The operating system's error while writing a file, with the file named: str() is
    "cannot write PATH: its words"; errno, strerror (the words alone) and filename as
    OSError's, so a caller that words its own message still can."""

    def __str__(self) -> str:
        return f"cannot write {self.filename}: {self.strerror}"


def _names_nothing(exc: OSError) -> bool:
    """Whether `exc` is the operating system's bare error (its number and words, no file):
    one a writer raised with its own message, or naming a file, is left as it is."""
    return exc.filename is None and exc.errno is not None and exc.strerror == os.strerror(exc.errno) \
        and str(exc) == f"[Errno {exc.errno}] {exc.strerror}"


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


def stale_temps(final, folders=()) -> list[Path]:
    """The temporaries that writes of `final` left beside it when their process was killed
    outright (SIGKILL: no cleanup ran), then every temporary of an atomic write left inside each
    of `folders` (an output folder's frames). Remove them only while holding output_lock(final)."""
    import re

    final = Path(final)
    found: list[Path] = []
    for folder, name in ((final.parent, re.escape(final.name)), *((Path(f), ".+") for f in folders)):
        pattern = re.compile(_TEMP_NAME.format(name=name))
        try:
            found += sorted(p for p in folder.iterdir() if pattern.fullmatch(p.name) and p.is_file())
        except (FileNotFoundError, NotADirectoryError):
            pass
    return found


class OutputBusy(ValueError):
    """Another process holds the lock of the output."""


def lock_path(final) -> Path:
    """The lock file of output `final`: `.NAME.lock` beside the output's real path (the real
    folder and, when `final` is a link to a folder, the folder's real name), so that every
    name of one output (a symlink to it or to a folder above it, `..`) shares one lock."""
    final = Path(final)
    real = Path(os.path.realpath(final)) if final.is_dir() else \
        Path(os.path.realpath(final.parent)) / final.name
    return real.parent / f".{real.name}.lock"


# opened without following a link, kept from child processes; O_NONBLOCK: opening a FIFO
# planted at the path does not wait for a writer
_OPEN_FLAGS = os.O_RDWR | getattr(os, "O_NOFOLLOW", 0) | getattr(os, "O_CLOEXEC", 0) | getattr(os, "O_NONBLOCK", 0)


def _open_lock(path: Path) -> tuple[int, bool]:
    """(fd, created) of the lock file at `path`: a new file (O_EXCL: created by us, so nothing
    else is ever written), else the regular file there (left by a run killed with -9, or
    held by a live writer). A symbolic link or anything but a regular file is refused
    (ValueError naming it): it is never followed, written or removed."""
    while True:
        try:
            return os.open(path, _OPEN_FLAGS | os.O_CREAT | os.O_EXCL, 0o666), True
        except FileExistsError:
            pass
        except OSError as exc:
            raise OSError(exc.errno, f"cannot write in {path.parent} ({os.strerror(exc.errno)}): "
                                     "choose an output in a folder you can write to") from None
        try:
            fd = os.open(path, _OPEN_FLAGS)
        except FileNotFoundError:
            continue  # removed by its holder meanwhile: create it
        except OSError as exc:
            _refuse_if_not_a_lock(path)  # O_NOFOLLOW's ELOOP on a link, EISDIR on a folder
            raise OSError(exc.errno, f"cannot open the lock file {path} ({os.strerror(exc.errno)}): "
                                     "choose an output in a folder you can write to") from None
        if not stat.S_ISREG(os.fstat(fd).st_mode):  # a FIFO or a device: opened, never written
            os.close(fd)
            _refuse_if_not_a_lock(path)
            continue  # replaced meanwhile: open it again
        return fd, False


def _refuse_if_not_a_lock(path: Path) -> None:
    """ValueError naming `path` when a symbolic link or anything but a regular file is there."""
    try:
        mode = os.lstat(path).st_mode
    except FileNotFoundError:
        return
    if stat.S_ISLNK(mode):
        raise ValueError(f"{path} is a symbolic link, not the lock file of relight: remove it "
                         "(it is not followed), then run again")
    if not stat.S_ISREG(mode):
        raise ValueError(f"{path} is not a regular file, so not the lock file of relight: remove it, "
                         "then run again")


@contextmanager
def output_lock(final, what: str = "relight", clear_in=None):
    """Hold the one writer's lock of output `final` (a file or a folder) for the block;
    `what` (the command) is named to a second writer, with this process's id. `clear_in`
    (folders, possibly none): once locked, the temporaries that killed runs left beside
    `final` and inside those folders are removed (stale_temps; no live writer owns them now).

    The lock is an flock on lock_path(final) (on Windows msvcrt's lock of one byte): the
    kernel drops it when the process ends however it ends (kill -9 included), so a lock is
    never stale. A second writer gets OutputBusy at once (never waits). The lock file is
    opened without following links; the holder writes only into a file it created itself
    (one left by a killed run is locked, then unlinked and made anew), so a link or a hard
    link planted at the path never reaches another file. A symbolic link or a file that is
    not regular there is refused with one line naming it. The file is removed on release
    while still locked; a process that opened it just before re-opens the path and locks anew.
    """
    path = lock_path(final)
    while True:
        fd, created = _open_lock(path)
        try:
            _try_lock(fd)
        except BlockingIOError:
            pid, _, holder = _read_head(fd).decode("utf-8", "replace").strip().partition(" ")
            os.close(fd)
            who = f"another {holder or 'relight'} run" + (f" (process {pid})" if pid.isdigit() else "")
            raise OutputBusy(f"{who} is writing {final}: wait for it to finish, or choose another "
                             "output") from None
        try:  # still the file at `path` (not followed: a link is not it)?
            here, there = os.fstat(fd), os.lstat(path)
        except FileNotFoundError:
            here = there = None
        if there is None or (here.st_dev, here.st_ino) != (there.st_dev, there.st_ino):
            os.close(fd)  # the holder removed the file between our open and lock: lock the new one
            continue
        if created:
            break
        # a file we did not create (a killed run's, or anything planted as one): locked, so no
        # live writer owns it; its name is removed and a file of our own made in its place
        try:
            os.unlink(path)
        except FileNotFoundError:
            pass
        except PermissionError as exc:
            if os.name == "nt":  # Windows cannot remove an open file: this one is regular and locked
                os.ftruncate(fd, 0)
                break
            os.close(fd)
            raise OSError(exc.errno, f"cannot replace the lock file {path} that another run left "
                                     f"({os.strerror(exc.errno)}): remove it, then run again") from None
        os.close(fd)
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        os.write(fd, f"{os.getpid()} {what}\n".encode("utf-8"))  # who holds it, for the refusal
        for tmp in stale_temps(final, clear_in) if clear_in is not None else ():
            tmp.unlink(missing_ok=True)
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
