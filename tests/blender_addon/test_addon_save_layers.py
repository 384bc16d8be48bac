"""Relight Photo add-on: Save Layers runs on a worker thread, with progress and Esc (issues 40, 48).

It ran on the main thread: 10-14 s with Blender frozen for a 24 MP photo. Now, after the file
browser, the main thread checks the target and gathers the light; relighting, the layers and the
EXR are made on a worker into a temporary file beside the target, which takes the chosen name when
it is whole; Esc leaves nothing. Issue 48: the maps are made one at a time into one working buffer
and staged, and the EXR is written in bands of rows (relight.files.exr.write_exr_bands), so the
worker holds one full-size buffer and a band, not every channel whole (1.1 GB at 24 MP), and Esc
stops the write at the next band (it went on writing the whole file). The modal path is driven
with the timer and Esc events Blender would send, as the Relight tests do.
"""

from __future__ import annotations

import threading
import time
import types
from pathlib import Path

import numpy as np
import pytest

import bpy

from blender_addon.blender import bl_images, bl_ops, bl_session
from blender_addon.logic import pixel_buffers
from blender_addon.worker import engine, jobs, save_layers, state
from relight.files.exr import read_exr
from addon_support import H, addon_in_empty_scene, pixels


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

    threads, gate, band_rows = [], threading.Event(), []
    write = relight.files.exr.write_exr_bands

    def write_on_the_worker(path, names, height, width, bands, **kw):
        threads.append(threading.current_thread())
        gate.wait(30)  # held until the main thread has seen the writing stage

        def drawn():
            for band in bands:
                threads.append(threading.current_thread())
                band_rows.append(band.shape[0])
                yield band
        return write(path, names, height, width, drawn(), **kw)

    monkeypatch.setattr(relight.files.exr, "write_exr_bands", write_on_the_worker)
    target = folder / "ui.exr"
    op, context = _ui_operator(name, target)
    assert op.execute(context) == {"RUNNING_MODAL"}
    # back before the work: the writer waits for the gate, which only the timer calls below open
    assert op._job.poll() is jobs.JobState.RUNNING and context.window_manager.handlers == [op]
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
    # bounded pieces, top to bottom: every band but the last BAND_ROWS rows, together the image
    assert band_rows == [save_layers.BAND_ROWS] * (H // save_layers.BAND_ROWS) + [H % save_layers.BAND_ROWS]
    assert gate.is_set() and "Writing the EXR file" in stages  # seen by the main thread, while it ran
    assert [stage for stage, _ in op_job.progress.history] == [
        "Relighting at full size", "Making the alpha layer", "Making the shadow layer", "Making the albedo layer",
        "Making the shading layer",
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
    # the same file relight.files.photo.write_layers_exr writes of the whole maps, channel for channel
    from relight.files.photo import write_layers_exr

    session = state.SESSIONS[bpy.data.images[name][bl_images.PHOTO_ID]]
    d, (light, rotation, exposure, strength) = session.decomposition, bl_ops.current_dials(bpy.context, session)
    coeffs = engine.coefficients(d, light, rotation)
    whole = pixel_buffers.blend(d.relight(coeffs, exposure_ev=exposure), d.photo, strength)
    write_layers_exr(folder / "whole.exr", whole, d.layers(coeffs, exposure_ev=exposure))
    whole_exr = _exr(folder / "whole.exr")
    assert sorted(whole_exr) == sorted(set(got) - {"Relight.Shadow.X"})  # and the Shadow layer (issue 46)
    for channel in whole_exr:
        np.testing.assert_array_equal(got[channel], whole_exr[channel])
    np.testing.assert_array_equal(got["Relight.Shadow.X"], d.shadow_layer(coeffs, exposure))


class _RecordingWriter:
    """relight.files.exr's writers as Save Layers calls them, recording the rows each hands on to be
    written (a whole file's write_exr, or each band write_exr_bands draws) in `events`, after ("Esc",)
    once the test pressed it; the first rows wait for `gate`."""

    def __init__(self, monkeypatch, height: int):
        import relight.files.exr

        self.height, self.events, self.gate, self.writing = height, [], threading.Event(), threading.Event()
        whole, banded = relight.files.exr.write_exr, relight.files.exr.write_exr_bands

        def write_exr(path, channels, **kw):
            self._rows(self.height)
            return whole(path, channels, **kw)

        def write_exr_bands(path, names, height, width, bands, **kw):
            def drawn():
                for band in bands:
                    self._rows(band.shape[0])
                    yield band
            return banded(path, names, height, width, drawn(), **kw)

        monkeypatch.setattr(relight.files.exr, "write_exr", write_exr)
        monkeypatch.setattr(relight.files.exr, "write_exr_bands", write_exr_bands)

    def _rows(self, rows: int) -> None:
        if not self.writing.is_set():
            self.writing.set()
            self.gate.wait(30)
        self.events.append(("rows", rows))


def test_esc_while_writing_stops_the_write(relit, monkeypatch):
    """Issue 48: a cancelled Save Layers went on writing the whole file (then deleted it)."""
    name, folder = relit
    monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)
    writer = _RecordingWriter(monkeypatch, H)
    earlier = folder / "cancelled.exr"
    earlier.write_bytes(b"an earlier save")  # what the file browser asked to overwrite
    op, context = _ui_operator(name, earlier)
    assert op.execute(context) == {"RUNNING_MODAL"}
    job = op._job
    assert writer.writing.wait(30)  # the first rows are on their way to the file
    assert op.modal(context, types.SimpleNamespace(type="ESC")) == {"CANCELLED"}
    writer.events.append(("Esc",))
    writer.gate.set()
    assert job.wait(30) is jobs.JobState.CANCELLED and job.finished
    assert isinstance(job.error, engine.Cancelled)
    # the band drawn when Esc came goes on, no other is drawn: less than the image reaches the writer
    esc = writer.events.index(("Esc",))
    assert writer.events[esc + 1:] == [("rows", save_layers.BAND_ROWS)], writer.events
    # the earlier file kept whole, no temporary left
    assert earlier.read_bytes() == b"an earlier save" and list(folder.glob("*.exr")) == [earlier]
    assert list(folder.glob(".*")) == []
    assert op.reports[-1] == ({"WARNING"}, "Saving the layers cancelled: nothing was written.")


@pytest.mark.parametrize("when", ["while making the maps", "while writing", "written, not yet handed over"])
def test_esc_leaves_no_file_and_no_temporary(relit, monkeypatch, when):
    name, folder = relit
    monkeypatch.setattr(bl_session, "updates_immediately", lambda: False)
    gate = threading.Event()
    if when == "while making the maps":
        add = save_layers.StagedPlanes.add
        monkeypatch.setattr(save_layers.StagedPlanes, "add", lambda self, plane: gate.wait(30) and add(self, plane))
    else:
        import relight.files.exr

        write = relight.files.exr.write_exr_bands
        monkeypatch.setattr(relight.files.exr, "write_exr_bands", lambda *a, **k: gate.wait(30) and write(*a, **k))
    target = folder / "cancelled.exr"
    op, context = _ui_operator(name, target)
    assert op.execute(context) == {"RUNNING_MODAL"}
    if when == "written, not yet handed over":
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


@pytest.fixture
def large_relit(model, tmp_path):
    """A 600 x 400 photo relit (the tiny model): a full-size plane (0.96 MB) dwarfs the
    working-resolution arrays. Yields (image name, folder, session)."""
    from PIL import Image

    from addon_support import photo_session

    y, x = np.mgrid[0:600, 0:400]
    rgb = np.dstack([40 + (x * 3) % 50, 60 + (y * 2) % 40, np.full_like(x, 90)]).astype(np.uint8)
    rgb[((x - 200) / 100) ** 2 + ((y - 300) / 230) ** 2 <= 1] = (220, 170, 140)
    with addon_in_empty_scene(tmp_path, model, rotation=0.4, exposure=0.5, strength=0.8):
        Image.fromarray(rgb).save(tmp_path / "large.png")
        name = bpy.data.images.load(str(tmp_path / "large.png")).name
        assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
        yield name, tmp_path, photo_session(name)


class _PhasePeaks:
    """tracemalloc's peak over each stage of Save Layers' worker (jobs.Progress.enter marks them):
    `making` the maps (every stage before "Writing the EXR file"), `writing` the file."""

    def __init__(self, monkeypatch):
        import tracemalloc

        self.making = self.writing = 0
        self._stage, self._base, enter = None, 0, jobs.Progress.enter

        def marked(progress, stage, fraction):
            self._close()
            self._stage = stage
            return enter(progress, stage, fraction)

        monkeypatch.setattr(jobs.Progress, "enter", marked)
        self._tracemalloc = tracemalloc

    def _close(self) -> None:
        t = self._tracemalloc
        if self._stage is not None:
            peak = t.get_traced_memory()[1] - self._base
            if self._stage == save_layers.WRITING[0]:
                self.writing = max(self.writing, peak)
            else:
                self.making = max(self.making, peak)
        t.reset_peak()

    def run(self, fn):
        t = self._tracemalloc
        t.start()
        try:
            self._base, self._stage = t.get_traced_memory()[0], None
            fn()
            self._close()
        finally:
            t.stop()


def _band_sink(monkeypatch, rows: list) -> None:
    """relight.files.exr.write_exr_bands replaced by a writer that holds nothing: each band drawn,
    counted in `rows` and dropped (an empty file made), so the memory of the save's own part is
    measured without the writer's, which depends on its threads' timing."""
    import relight.files.exr

    def sink(path, names, height, width, bands, **kw):
        for band in bands:
            assert band.shape[1:] == (width, len(names))
            rows.append(band.shape[0])
            del band
        Path(path).write_bytes(b"")
        return Path(path)

    monkeypatch.setattr(relight.files.exr, "write_exr_bands", sink)


def test_save_layers_holds_one_full_size_buffer_and_a_band(large_relit, monkeypatch):
    """Issue 48: the EXR writer took every channel whole (14 full-size planes at once, 1.1 GB at
    24 MP). Now the maps go one at a time through one 3-plane buffer, and the file is written from
    bands of BAND_ROWS rows; the file holds what relight.files.photo.write_layers_exr writes of
    the whole maps."""
    import tracemalloc

    from relight.files.photo import write_layers_exr

    name, folder, session = large_relit
    d = session.decomposition
    light, rotation, exposure, strength = bl_ops.current_dials(bpy.context, session)
    coeffs = engine.coefficients(d, light, rotation)
    pixel_buffers.BUFFERS.clear()
    rgb, alpha = np.empty((600, 400, 3), np.float32), np.empty((600, 400), np.float32)
    makers = [lambda: d.relight(coeffs, exposure_ev=exposure, out=rgb), lambda: d.layer("alpha", out=alpha),
              lambda: d.shadow_layer(coeffs, exposure, out=alpha)] + \
        [lambda layer=layer: d.layer(layer, coeffs, exposure, out=rgb) for layer in ("albedo", "shading", "residual")]
    for make in makers:  # what the decomposition prepares once (its upsampled alpha, its edge colours)
        make()
    tracemalloc.start()
    try:  # what the core itself needs beside the map it makes (its strips and their temporaries)
        core = []
        for make in makers:
            tracemalloc.reset_peak()
            before = tracemalloc.get_traced_memory()[0]
            make()
            core.append(tracemalloc.get_traced_memory()[1] - before)
    finally:
        tracemalloc.stop()
    peaks, rows = _PhasePeaks(monkeypatch), []
    with monkeypatch.context() as patch:
        _band_sink(patch, rows)
        peaks.run(lambda: bpy.ops.relight_photo.save_layers(filepath=str(folder / "sunk.exr"), image_name=name))
    plane, band = 600 * 400 * 4, len(save_layers.channel_names()) * save_layers.BAND_ROWS * 400 * 4
    print(f"making {peaks.making / plane:.2f} planes (core {max(core) / plane:.2f}), writing "
          f"{peaks.writing / plane:.2f} (a band {band / plane:.2f})")
    assert sum(rows) == 600 and max(rows) == save_layers.BAND_ROWS
    # making the maps: one 3-plane working buffer and what the core needs to make one map into it
    # (plane // 4 for the small things: progress records, the scratch file's views, the operator's own)
    assert peaks.making <= 3 * plane + max(core) + plane // 4
    # writing: the band being read and its finite check (the writer's own memory is the writer's);
    # every channel whole was 14 planes
    assert peaks.writing <= 2 * band + plane // 4
    target = folder / "layers.exr"  # the file, by the real writer
    assert bpy.ops.relight_photo.save_layers(filepath=str(target), image_name=name) == {"FINISHED"}
    whole = pixel_buffers.blend(d.relight(coeffs, exposure_ev=exposure), d.photo, strength)
    write_layers_exr(folder / "whole.exr", whole, d.layers(coeffs, exposure_ev=exposure))
    want, got = _exr(folder / "whole.exr"), _exr(target)
    assert sorted(set(got) - {"Relight.Shadow.X"}) == sorted(want)  # and the Shadow layer (issue 46)
    for channel in want:
        np.testing.assert_array_equal(got[channel], want[channel])
    np.testing.assert_array_equal(got["Relight.Shadow.X"], d.shadow_layer(coeffs, exposure))
    assert sorted(p.name for p in folder.iterdir() if p.suffix == ".exr") == ["layers.exr", "sunk.exr", "whole.exr"]


def test_a_pooled_rgba_buffer_is_the_working_buffer(large_relit, monkeypatch):
    """With a 384 MB RGBA buffer kept for reuse (24 MP), the maps are made in its planes: no
    3-plane buffer of their own; the buffer is handed back for the next write; the same file."""
    name, folder, session = large_relit
    monkeypatch.setattr(pixel_buffers.BufferPool, "MIN_VALUES", 1)
    peaks = _PhasePeaks(monkeypatch)

    def save(file_name):
        assert bpy.ops.relight_photo.save_layers(filepath=str(folder / file_name), image_name=name) == {"FINISHED"}

    pixel_buffers.BUFFERS.clear()
    peaks.run(lambda: save("fresh.exr"))
    fresh = peaks.making
    kept = np.empty(600 * 400 * 4, np.float32)
    pixel_buffers.BUFFERS.clear()
    pixel_buffers.BUFFERS.give(kept)
    peaks.making = 0
    peaks.run(lambda: save("pooled.exr"))
    plane = 600 * 400 * 4
    assert peaks.making <= fresh - 3 * plane + plane // 10, (fresh / plane, peaks.making / plane)
    assert pixel_buffers.BUFFERS.take_pooled(600 * 400 * 4) is kept
    want, got = _exr(folder / "fresh.exr"), _exr(folder / "pooled.exr")
    for channel in want:
        np.testing.assert_array_equal(got[channel], want[channel])
