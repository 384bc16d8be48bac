"""Relight Photo add-on: Save Layers runs on a worker thread, with progress and Esc (issue 40).

It ran on the main thread: 10-14 s with Blender frozen for a 24 MP photo. Now, after the file
browser, the main thread checks the target and gathers the light; relighting, the layers and the
EXR are made on a worker into a temporary file beside the target, which takes the chosen name when
it is whole; Esc leaves nothing. The maps are made straight into the planes the EXR writer takes,
so it copies none (benchmarks/bench_addon_memory.py --flows save_layers measures the peak at 24 MP).
The modal path is driven with the timer and Esc events Blender would send, as the Relight tests do.
"""

from __future__ import annotations

import threading
import time
import types

import numpy as np
import pytest

import bpy

from blender_addon.blender import bl_images, bl_ops, bl_session
from blender_addon.worker import engine, jobs, state
from relight.files.exr import read_exr
from addon_support import addon_in_empty_scene, pixels


@pytest.fixture
def relit(model, tmp_path):
    with addon_in_empty_scene(tmp_path, model, rotation=0.4, exposure=0.5, strength=0.8):
        name = bpy.data.images.load(str(tmp_path / "person.png")).name
        assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
        yield name, tmp_path
        state.RUNNING.pop(bl_ops.RELIGHT_PHOTO_OT_save_layers.SLOT, None)


class _WindowManager:
    """What the operator asks of the window manager while it polls (headless Blender has no window)."""

    def __init__(self):
        self.progress, self.handlers = [], []
        self.relight_photo_status = bpy.context.window_manager.relight_photo_status

    def progress_begin(self, low, high):
        self.progress.append("begin")

    def progress_update(self, value):
        self.progress.append(value)

    def progress_end(self):
        self.progress.append("end")

    def event_timer_add(self, seconds, window=None):
        return object()

    def event_timer_remove(self, timer):
        pass

    def modal_handler_add(self, op):
        self.handlers.append(op)


def _ui_operator(name, target):
    """The Save Layers operator as the file browser's confirm runs it with a UI, and its context."""
    cls = bl_ops.RELIGHT_PHOTO_OT_save_layers
    op = types.SimpleNamespace(filepath=str(target), image_name=name, synchronous=False, _job=None, _timer=None,
                               _plan=None, _started=0.0, reports=[], SLOT=cls.SLOT)
    op.report = lambda kind, text: op.reports.append((set(kind), text))
    for method in ("_session", "_start", "_finish", "_failed", "execute", "_cleanup", "modal", "runs_here",
                   "start_polling", "stop_polling"):
        setattr(op, method, getattr(cls, method).__get__(op))
    context = types.SimpleNamespace(scene=bpy.context.scene, window_manager=_WindowManager(), workspace=None,
                                    space_data=None, window=object())
    return op, context


def _exr(path) -> dict:
    return {name: np.asarray(plane) for name, plane in read_exr(path).items()}


def test_save_layers_runs_on_a_worker_polled_by_the_timer_and_writes_what_it_wrote_here(relit, monkeypatch):
    name, folder = relit
    here = folder / "here.exr"
    assert bpy.ops.relight_photo.save_layers(filepath=str(here), image_name=name) == {"FINISHED"}
    monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)
    import relight.files.exr

    threads, gate = [], threading.Event()
    write = relight.files.exr.write_exr

    def write_on_the_worker(*args, **kw):
        threads.append(threading.current_thread())
        gate.wait(30)  # held until the main thread has seen the writing stage
        return write(*args, **kw)

    monkeypatch.setattr(relight.files.exr, "write_exr", write_on_the_worker)
    target = folder / "ui.exr"
    op, context = _ui_operator(name, target)
    started = time.perf_counter()
    assert op.execute(context) == {"RUNNING_MODAL"}
    assert time.perf_counter() - started < 0.5 and context.window_manager.handlers == [op]
    op_job = op._job
    status, stages, result = context.window_manager.relight_photo_status, set(), {"PASS_THROUGH"}
    deadline = time.monotonic() + 60
    while result == {"PASS_THROUGH"} and time.monotonic() < deadline:
        time.sleep(0.01)
        result = op.modal(context, types.SimpleNamespace(type="TIMER"))
        stages.add(status.stage)
        if status.stage == "Writing the EXR file":
            assert status.running and 0.5 <= status.progress < 1.0 and not target.exists()
            gate.set()
    assert result == {"FINISHED"}, op.reports
    assert threads and all(t is not threading.main_thread() for t in threads)
    assert gate.is_set() and "Writing the EXR file" in stages  # seen by the main thread, while it ran
    assert [stage for stage, _ in op_job.progress.history] == [
        "Relighting at full size", "Making the alpha layer", "Making the albedo layer", "Making the shading layer",
        "Making the residual layer", "Writing the EXR file"]
    assert context.window_manager.progress[-1] == "end" and not status.running
    assert op.reports[-1][1].startswith(f"Saved the layers of '{name}' to {target} in ")
    assert sorted(p.name for p in folder.iterdir() if p.suffix == ".exr") == ["here.exr", "ui.exr"]  # no temporary
    want, got = _exr(here), _exr(target)
    assert sorted(got) == sorted(want)
    for channel in want:
        np.testing.assert_array_equal(got[channel], want[channel])
    relit_exr = np.dstack([got[f"Relight.Relit.{c}"] for c in "RGB"])
    np.testing.assert_allclose(relit_exr, pixels(f"{name}.relit")[..., :3], atol=1e-6)  # under the dials


@pytest.mark.parametrize("when", ["while writing", "written, not yet handed over"])
def test_esc_leaves_no_file_and_no_temporary(relit, monkeypatch, when):
    name, folder = relit
    monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)
    gate, save = threading.Event(), engine.save_layers
    monkeypatch.setattr(engine, "save_layers", lambda *a: gate.wait(30) and save(*a))
    target = folder / "cancelled.exr"
    op, context = _ui_operator(name, target)
    assert op.execute(context) == {"RUNNING_MODAL"}
    if when != "while writing":
        gate.set()
        op._job.wait(30)  # done, and the timer has not looked yet
        assert op._job.poll() is jobs.JobState.DONE
    job = op._job
    assert op.modal(context, types.SimpleNamespace(type="ESC")) == {"CANCELLED"}
    gate.set()
    job.wait(30)
    assert op.reports[-1] == ({"WARNING"}, "Saving the layers cancelled: nothing was written.")
    assert list(folder.glob("*.exr")) == [] and list(folder.glob(".*")) == []
    assert bl_ops.RELIGHT_PHOTO_OT_save_layers.SLOT not in state.RUNNING


def test_the_exr_writer_gets_planes_it_need_not_copy(relit, monkeypatch):
    """The peak at 24 MP came from copies: the relit photo made contiguous (288 MB), each map's
    channels copied out of it (288 MB a map), a black residual made as a full map."""
    import relight.files.exr

    name, folder = relit
    seen, write = {}, relight.files.exr.write_exr
    monkeypatch.setattr(relight.files.exr, "write_exr", lambda path, channels, **kw: seen.update(channels) or
                        write(path, channels, **kw))
    assert bpy.ops.relight_photo.save_layers(filepath=str(folder / "l.exr"), image_name=name) == {"FINISHED"}

    def base(a):
        while a.base is not None:
            a = a.base
        return id(a)

    relit_rgb = [seen[f"Relight.Relit.{c}"] for c in "RGB"]
    assert all(c.flags.c_contiguous for c in seen.values())
    assert len({base(c) for c in relit_rgb}) == 1  # three planes of one buffer, not three copies
    for layer in ("Albedo", "Shading", "Residual"):  # the tiny model has a residual E
        assert len({base(seen[f"Relight.{layer}.{c}"]) for c in "RGB"}) == 1
    # a model without E (the shipped one): its black residual is one zero plane, not a 288 MB map
    session = state.SESSIONS[bpy.data.images[name][bl_images.PHOTO_ID]]
    session.decomposition._has_residual = False
    seen.clear()
    assert bpy.ops.relight_photo.save_layers(filepath=str(folder / "l.exr"), image_name=name) == {"FINISHED"}
    residual = [seen[f"Relight.Residual.{c}"] for c in "RGB"]
    assert all(np.shares_memory(residual[0], c) for c in residual) and not residual[0].any()
    assert not any(np.shares_memory(residual[0], c) for c in relit_rgb)


def test_a_pooled_rgba_buffer_holds_the_relit_planes_and_the_alpha(relit, monkeypatch):
    """With a 384 MB RGBA buffer kept for reuse (24 MP), the relit photo takes three of its planes
    and the alpha the fourth: no new memory for either; the file is the same."""
    import relight.files.exr

    from blender_addon.logic import pixel_buffers

    name, folder = relit
    assert bpy.ops.relight_photo.save_layers(filepath=str(folder / "fresh.exr"), image_name=name) == {"FINISHED"}
    monkeypatch.setattr(pixel_buffers.BufferPool, "MIN_VALUES", 1)  # the test photo's buffer counts as large
    h, w = state.SESSIONS[bpy.data.images[name][bl_images.PHOTO_ID]].photo.shape[:2]
    kept = np.empty(h * w * 4, np.float32)
    pixel_buffers.BUFFERS.clear()
    pixel_buffers.BUFFERS.give(kept)
    seen, write = {}, relight.files.exr.write_exr
    monkeypatch.setattr(relight.files.exr, "write_exr", lambda path, channels, **kw: seen.update(channels) or
                        write(path, channels, **kw))
    assert bpy.ops.relight_photo.save_layers(filepath=str(folder / "pooled.exr"), image_name=name) == {"FINISHED"}
    for channel in ("Relight.Relit.R", "Relight.Relit.G", "Relight.Relit.B", "Relight.Alpha.A"):
        assert np.shares_memory(seen[channel], kept), channel
    assert pixel_buffers.BUFFERS.take_pooled(h * w * 4) is kept  # handed back for the next write
    fresh, pooled = _exr(folder / "fresh.exr"), _exr(folder / "pooled.exr")
    for channel in fresh:
        np.testing.assert_array_equal(pooled[channel], fresh[channel])
