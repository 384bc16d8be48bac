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
    # and inside folders: every atomic write's temporary (the one beside `target` listed once more)
    assert [p.name for p in fileio.stale_temps(target, [tmp_path])] == [".o.mp4.k9_left_.tmp.mp4",
                                                                        ".o.mp4.k9_left_.tmp.mp4",
                                                                        ".o.mp4x.abcdefgh.tmp.mp4",
                                                                        ".other.abcdefgh.tmp.mp4"]


def test_every_name_of_one_output_shares_its_lock(tmp_path):
    # issue 48: `--out outA` and `--out alias` (alias -> outA) each took a lock of its own
    real = tmp_path / "outA"
    real.mkdir()
    (tmp_path / "alias").symlink_to(real, target_is_directory=True)
    (tmp_path / "up").symlink_to(tmp_path, target_is_directory=True)
    names = {real: [tmp_path / "alias", tmp_path / "up" / "outA", real / ".." / "outA"],
             tmp_path / "o.png": [tmp_path / "up" / "o.png", real / ".." / "o.png"]}
    for output, aliases in names.items():
        for alias in aliases:
            assert fileio.lock_path(alias) == fileio.lock_path(output) == tmp_path / f".{output.name}.lock"
            with fileio.output_lock(output, "relight image"):
                with pytest.raises(fileio.OutputBusy, match=f"is writing {alias}"):
                    with fileio.output_lock(alias, "relight video"):
                        pass
    assert sorted(p.name for p in tmp_path.iterdir()) == ["alias", "outA", "up"]  # no lock file left


def test_the_lock_never_writes_through_a_link_planted_at_its_path(tmp_path):
    # issue 48: a symlink planted as .o.png.lock was followed and the file it names truncated
    out = tmp_path / "o.png"
    planted = fileio.lock_path(out)
    victim = tmp_path / "victim.txt"
    victim.write_text("the user's data\n")
    for target in (victim, tmp_path / "nowhere"):  # a file, and a dangling link (O_CREAT would make it)
        planted.symlink_to(target)
        with pytest.raises(ValueError, match=f"^{planted} is a symbolic link, not the lock file"):
            with fileio.output_lock(out):
                pass
        assert os.path.islink(planted) and not (tmp_path / "nowhere").exists()  # not followed, not removed
        planted.unlink()
    assert victim.read_text() == "the user's data\n"
    # a hard link (or a run killed with -9 leaving its file): locked, then its name replaced by
    # a file of our own; the other name keeps its bytes
    os.link(victim, planted)
    with fileio.output_lock(out, "relight image"):
        assert planted.read_text() == f"{os.getpid()} relight image\n"
        assert victim.read_text() == "the user's data\n" and victim.stat().st_nlink == 1
    assert victim.read_text() == "the user's data\n" and not planted.exists()
    planted.mkdir()  # not a regular file
    with pytest.raises(ValueError, match=f"^{planted} is not a regular file"):
        with fileio.output_lock(out):
            pass
    planted.rmdir()
    os.mkfifo(planted)  # opening it for the lock must not wait for a writer
    with pytest.raises(ValueError, match=f"^{planted} is not a regular file"):
        with fileio.output_lock(out):
            pass
    assert planted.exists()


def test_a_full_disk_names_the_file_it_was_writing(tmp_path):
    # issue 48: a full disk while writing a photo was "[Errno 27] File too large", naming no file
    import errno

    target = tmp_path / "out.png"
    target.write_bytes(b"previous result")
    for code in (errno.EFBIG, errno.ENOSPC):
        with pytest.raises(OSError) as info:
            with fileio.atomic_path(target, ".png") as tmp:
                with open(tmp, "wb") as f:
                    f.write(b"half")
                    raise OSError(code, os.strerror(code))  # as write() raises it: no file named
        assert str(info.value) == f"cannot write {target}: {os.strerror(code)}"
        assert (info.value.errno, info.value.strerror, info.value.filename) == (code, os.strerror(code), str(target))
        assert target.read_bytes() == b"previous result" and sorted(p.name for p in tmp_path.iterdir()) == ["out.png"]
    # a writer's own words, or an error that names its file, pass unchanged
    for raised in (OSError(errno.ENOSPC, "output disk full while writing o.mp4"),
                   OSError(errno.EACCES, os.strerror(errno.EACCES), str(tmp_path / "x"))):
        with pytest.raises(OSError) as info:
            with fileio.atomic_path(target):
                raise raised
        assert info.value is raised
