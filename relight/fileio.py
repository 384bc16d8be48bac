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
