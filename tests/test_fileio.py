"""Atomic writes: the target is either the old file or the complete new one."""

import hashlib
import os

import pytest

from relight.files import fileio


def test_failed_write_keeps_the_old_file_and_leaves_no_temp(tmp_path):
    target = tmp_path / "scene.json"
    target.write_text("old")
    with pytest.raises(RuntimeError, match="killed"):
        with fileio.atomic_path(target, ".json") as tmp:
            tmp.write_text("half")
            raise RuntimeError("killed mid-write")
    assert target.read_text() == "old"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["scene.json"]


def test_successful_write_replaces_and_gets_open_permissions(tmp_path):
    target = tmp_path / "out.txt"
    fileio.atomic_write_text(target, "new")
    assert target.read_text() == "new"
    umask = os.umask(0)
    os.umask(umask)
    assert target.stat().st_mode & 0o777 == 0o666 & ~umask  # not mkstemp's 0600


def test_json_with_nan_is_refused_before_anything_is_written(tmp_path):
    target = tmp_path / "x.json"
    with pytest.raises(ValueError):
        fileio.atomic_write_json(target, {"a": float("nan")}, allow_nan=False)
    assert list(tmp_path.iterdir()) == []


def test_sha256_matches_hashlib_across_chunk_boundary(tmp_path):
    data = os.urandom(fileio.HASH_CHUNK + 123)  # spans two chunks
    p = tmp_path / "blob"
    p.write_bytes(data)
    assert fileio.file_sha256(p) == hashlib.sha256(data).hexdigest()


def test_output_lock_is_one_writer_and_leaves_nothing(tmp_path):
    out = tmp_path / "frames"
    with fileio.output_lock(out, "relight video"):
        assert fileio.lock_path(out).read_text().split() == [str(os.getpid()), "relight", "video"]
        with pytest.raises(fileio.OutputBusy, match=rf"another relight video run \(process {os.getpid()}\) "
                                                    rf"is writing {out}: wait for it"):
            with fileio.output_lock(out, "relight image"):
                pass
    assert list(tmp_path.iterdir()) == []
    fileio.lock_path(out).write_text("4242 relight video\n")  # left by a run killed with -9: not held
    with fileio.output_lock(out):
        pass
    assert list(tmp_path.iterdir()) == []


def test_stale_temps_are_the_atomic_writes_temporaries_only(tmp_path):
    target = tmp_path / "o.mp4"
    with fileio.atomic_path(target, ".mp4") as tmp:
        assert fileio.stale_temps(target) == [tmp]  # the name atomic_path gives is recognised
        tmp.write_bytes(b"x")
    for name in ("o.mp4", ".o.mp4.lock", ".o.mp4x.abcdefgh.tmp.mp4", ".other.abcdefgh.tmp.mp4", "o.mp4.tmp.mp4"):
        (tmp_path / name).write_bytes(b"keep")
    assert fileio.stale_temps(target) == []
    (tmp_path / ".o.mp4.k9_left_.tmp.mp4").write_bytes(b"half")
    assert [p.name for p in fileio.stale_temps(target)] == [".o.mp4.k9_left_.tmp.mp4"]
    assert [p.name for p in fileio.stale_temps_in(tmp_path)] == [".o.mp4.k9_left_.tmp.mp4",
                                                                 ".o.mp4x.abcdefgh.tmp.mp4",
                                                                 ".other.abcdefgh.tmp.mp4"]
