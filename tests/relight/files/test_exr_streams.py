"""EXR reads and writes leave the process's streams alone (issue 48).

Inside Blender a library shares file descriptors 1 and 2, sys.stdout and
sys.stderr with everything else: a write on the add-on's worker thread must not
swallow what others print meanwhile, nor hold a process-wide lock that stalls
the main thread's own EXR reads and writes.
"""

from __future__ import annotations

import os
import sys
import threading
from contextlib import contextmanager

import numpy as np
import OpenEXR
import pytest

from relight.files import exr, exr_zip

GUARD_S = 60  # a deadlock guard, never a measured time


class _PausingFile:
    """The library's File, paused inside write() until `resume` is set."""

    def __init__(self, real, inside: threading.Event, resume: threading.Event, order: list):
        self.real, self.inside, self.resume, self.order = real, inside, resume, order

    def __enter__(self):
        self.real.__enter__()
        return self

    def __exit__(self, *exc):
        return self.real.__exit__(*exc)

    def write(self, path):
        self.inside.set()
        self.order.append(("writer resumed by the main thread", self.resume.wait(GUARD_S)))
        self.real.write(path)


class _PausingLibrary:
    """The OpenEXR module, except that writes made on `thread` pause inside the library."""

    def __init__(self, thread_name: str, inside, resume, order):
        self.thread_name, self.inside, self.resume, self.order = thread_name, inside, resume, order

    def __getattr__(self, name):
        return getattr(OpenEXR, name)

    def File(self, *args, **kwargs):  # the library's name
        real = OpenEXR.File(*args, **kwargs)
        if threading.current_thread().name == self.thread_name and args and isinstance(args[0], dict):
            return _PausingFile(real, self.inside, self.resume, self.order)
        return real


def _planes(h=64, w=48, seed=0):
    rng = np.random.default_rng(seed)
    return {c: rng.random((h, w)).astype(np.float32) for c in "RGBA"}


@contextmanager
def paused_writer(folder, monkeypatch, writer: str):
    """write_exr started on a worker thread; entered once it is inside its writer (the OpenEXR
    library's, or relight.files.exr_zip's packing on its threads), left after resuming it and
    checking what it wrote. Started from the test's body: pytest's capfd swaps the streams in
    only when the body starts, as a console would be there first."""
    inside, resume, order = threading.Event(), threading.Event(), []
    if writer == "library":
        monkeypatch.setattr(exr_zip, "available", lambda: False)
        monkeypatch.setattr(exr, "_openexr", lambda: _PausingLibrary("exr-writer", inside, resume, order))
    else:
        pack, first = exr_zip._pack, []

        def pausing_pack(*args):
            if not first:  # the worker's first task: the main thread's own write comes later
                first.append(True)
                inside.set()
                order.append(("writer resumed by the main thread", resume.wait(GUARD_S)))
            return pack(*args)

        monkeypatch.setattr(exr_zip, "_pack", pausing_pack)
    failures = []

    def write():
        try:
            exr.write_exr(folder / "layers.exr", _planes())
        except BaseException as exc:  # reported by the test, not lost on the thread
            failures.append(exc)

    worker = threading.Thread(target=write, name="exr-writer")
    worker.start()
    try:
        assert inside.wait(GUARD_S)
        yield resume, order
    finally:
        resume.set()
        worker.join()
    assert not failures, failures
    np.testing.assert_array_equal(exr.read_exr(folder / "layers.exr")["G"], _planes()["G"])


WRITERS = ["library", "exr_zip"]  # exr_zip: ISA-L is a core dependency (pyproject.toml)


@pytest.mark.parametrize("writer", WRITERS)
def test_lines_printed_during_a_write_all_arrive(tmp_path, monkeypatch, capfd, writer):
    with paused_writer(tmp_path, monkeypatch, writer) as (resume, _):
        print("one, through sys.stdout", flush=True)
        os.write(1, b"two, on fd 1\n")
        print("three, through sys.stderr", file=sys.stderr, flush=True)
        os.write(2, b"four, on fd 2\n")
        other = threading.Thread(target=print, args=("five, from another thread",), kwargs={"flush": True})
        other.start()
        other.join()
    out, err = capfd.readouterr()
    assert out.splitlines() == ["one, through sys.stdout", "two, on fd 1", "five, from another thread"], out
    assert err.splitlines() == ["three, through sys.stderr", "four, on fd 2"], err


@pytest.mark.parametrize("writer", WRITERS)
def test_the_main_thread_reads_and_writes_while_a_write_is_under_way(tmp_path, monkeypatch, writer):
    """No process-wide lock: the main thread's EXR calls finish while the worker is still
    inside its write (before the fix they waited for it, 6-7 s at 24 MP in Blender)."""
    planes = _planes(8, 16, seed=1)
    with paused_writer(tmp_path, monkeypatch, writer) as (resume, order):
        exr.write_exr(tmp_path / "world.exr", planes)  # e.g. Photo Light -> World
        assert exr.exr_size(tmp_path / "world.exr") == (16, 8)
        np.testing.assert_array_equal(exr.read_exr(tmp_path / "world.exr")["B"], planes["B"])
        order.append("main thread done")
        resume.set()
    # our calls returned while the worker was still inside the library, and it was resumed by us
    # (not by its guard running out, which is what a lock held across its write would give)
    assert order == ["main thread done", ("writer resumed by the main thread", True)], order


@pytest.mark.parametrize("writer", WRITERS)
def test_a_banded_write_lets_others_print(tmp_path, capfd, monkeypatch, writer):
    if writer == "library":
        monkeypatch.setattr(exr_zip, "available", lambda: False)
    names = ["A.R", "A.G"]

    def bands():
        for k in range(3):
            print(f"band {k}", flush=True)  # printed while the file is open and half written
            os.write(2, f"fd 2 at band {k}\n".encode())
            yield np.full((5, 7, 2), float(k), np.float32)

    exr.write_exr_bands(tmp_path / "b.exr", names, 15, 7, bands())
    out, err = capfd.readouterr()
    assert out.splitlines() == ["band 0", "band 1", "band 2"]
    assert err.splitlines() == ["fd 2 at band 0", "fd 2 at band 1", "fd 2 at band 2"]


def _truncated(tmp_path):
    rng = np.random.default_rng(1)
    good = tmp_path / "good.exr"
    exr.write_exr(good, {c: rng.random((32, 64)).astype(np.float32) for c in "RGB"})
    data = good.read_bytes()
    bad = tmp_path / "bad.exr"
    bad.write_bytes(data[: len(data) // 2])  # the library would print a C-level message on this one
    return bad


@pytest.mark.parametrize("call", [exr.read_exr, exr.exr_size])
def test_a_damaged_exr_is_one_line_naming_it_and_nothing_printed(tmp_path, capfd, call):
    bad = _truncated(tmp_path) if call is exr.read_exr else tmp_path / "bad.exr"
    if call is exr.exr_size:
        bad.write_bytes(b"v/1\x01\x02\x00\x00\x00channels\x00chlist\x00\xff\x00\x00\x00")  # header cut short
    capfd.readouterr()
    with pytest.raises(ValueError) as caught:
        call(bad)
    message = str(caught.value)
    assert len(message.splitlines()) == 1 and str(bad) in message, message
    assert "truncated" in message
    assert capfd.readouterr() == ("", "")  # neither the library nor its binding printed anything
