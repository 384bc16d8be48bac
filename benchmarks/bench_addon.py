"""The add-on at photo scale, under headless bpy: how long Blender's main thread is blocked.

    .venv/bin/python benchmarks/bench_addon.py [--size 6000x4000] [--quality BALANCED] [--dials 5]
                                               [--mask AUTO] [--synthetic]

Makes a 24 MP JPEG (HxW, default 6000 high x 4000 wide) in a temporary folder
(never committed): the bundled public-domain photo
evaluation/data/matte_eval/obama_standing.jpg enlarged to that size (Lanczos),
or with --synthetic a lit figure on a textured background. Loads it into bpy and
drives the add-on as Blender's UI would: the modal Relight operator ticked by
timer events, dial changes through the idle timer, the full-size relight when
the dial rests, then save, reopen and a dial after reopening. Uses the shipped
model of the quality preset.

The main-thread probe: the benchmark's main loop wakes every PROBE_MS; each
time it measures how late it woke. A late wake-up is a stretch the UI could
not draw, whether the add-on's own main-thread call or a worker holding the
GIL. Prints one Markdown table; the goals are issue 17's.
"""

from __future__ import annotations

import argparse
import math
import os
import resource
import shutil
import sys
import tempfile
import time
import types
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
PROBE_MS = 20.0  # a UI frame rate; finer wake-ups would mostly measure GIL hand-overs


REAL_PHOTO = REPO / "evaluation" / "data" / "matte_eval" / "obama_standing.jpg"


def make_real_photo(path: Path, height: int, width: int) -> None:
    """The bundled photo enlarged to cover height x width, centre-cropped."""
    from photos import enlarged_photo  # benchmarks/photos.py

    enlarged_photo(path, size=(width, height), source=REAL_PHOTO)


def make_photo(path: Path, height: int, width: int) -> None:
    """A figure (ellipse, 40% of the width) with a shading gradient on a textured background."""
    from PIL import Image

    y, x = np.mgrid[0:height, 0:width].astype(np.float32)
    inside = ((x - width / 2) / (width / 5)) ** 2 + ((y - height / 2) / (height / 2.4)) ** 2 <= 1
    rgb = np.empty((height, width, 3), np.uint8)
    rgb[..., 0] = 40 + (x % 50)
    rgb[..., 1] = 60 + (y % 40)
    rgb[..., 2] = 90
    shade = 0.6 + 0.4 * (x / width)
    for c, v in enumerate((220, 170, 140)):
        rgb[..., c][inside] = (v * shade[inside]).astype(np.uint8)
    Image.fromarray(rgb).save(path, quality=90)


class Probe:
    """Main-thread responsiveness: the longest interval between wake-ups beyond PROBE_MS."""

    def __init__(self):
        self.worst = 0.0
        self.worst_what = ""
        self.last = time.perf_counter()

    def tick(self, what: str) -> None:
        now = time.perf_counter()
        stretch = now - self.last - PROBE_MS / 1e3
        if stretch > self.worst:
            self.worst, self.worst_what = stretch, what
        self.last = now

    def call(self, what: str, fn, *args):
        """Run a main-thread step; the probe wakes right before and right after it."""
        self.tick("idle")
        out = fn(*args)
        self.tick(what)
        return out

    def idle(self, seconds: float, what: str = "worker running") -> None:
        end = time.perf_counter() + seconds
        while time.perf_counter() < end:
            time.sleep(PROBE_MS / 1e3)
            self.tick(what)


class _WindowManager:
    def __init__(self, bpy):
        self.relight_photo_status = bpy.context.window_manager.relight_photo_status

    def progress_update(self, value):
        pass

    def progress_end(self):
        pass

    def event_timer_remove(self, _timer):
        pass


class _Workspace:
    def status_text_set(self, text):
        pass


def operator_stand_in(cls, **fields) -> types.SimpleNamespace:
    """An instance of the add-on's operator class `cls` without bpy's Operator (headless bpy has no
    window to run one): `fields` as its properties and state, a report() that prints, and every
    method of the operator's own classes bound to it."""
    op = types.SimpleNamespace(**fields, report=lambda kind, text: print(f"  [{'/'.join(kind)}] {text}"))
    for klass in reversed([k for k in cls.__mro__ if k.__module__.startswith("blender_addon")]):
        for name, value in vars(klass).items():
            if isinstance(value, types.FunctionType) and not name.startswith("__"):
                setattr(op, name, value.__get__(op))
    return op


def modal_operator(bpy, bl_ops, image_name: str):
    """The Relight operator as Blender's window manager drives it (headless bpy has no window)."""
    cls = bl_ops.RELIGHT_PHOTO_OT_relight
    op = operator_stand_in(cls, image_name=image_name, synchronous=False, _job=None, _timer=None, _plan=None,
                           _pending=None, _result=None, _started=0.0, _dial_values=cls._dial_values)
    context = types.SimpleNamespace(scene=bpy.context.scene, window_manager=_WindowManager(bpy),
                                    workspace=_Workspace(), space_data=None, window=None)
    return op, context


def run_timer(probe: Probe, fn, what: str) -> None:
    """Call a bpy.app.timers function as Blender would, until it stops re-arming itself."""
    import bpy

    if bpy.app.timers.is_registered(fn):
        bpy.app.timers.unregister(fn)
    while True:
        again = probe.call(what, fn)
        if again is None:
            return
        probe.idle(again)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="6000x4000", help="photo HxW")
    parser.add_argument("--mask", default="AUTO", help="Mask setting: AUTO (person matte) or NETWORK")
    parser.add_argument("--synthetic", action="store_true", help="a drawn figure instead of the real photo")
    parser.add_argument("--quality", default="BALANCED")
    parser.add_argument("--dials", type=int, default=5, help="dial changes to time")
    args = parser.parse_args(argv)
    height, width = (int(v) for v in args.size.lower().split("x"))

    import bpy

    import blender_addon
    from blender_addon.blender import bl_dials, bl_images, bl_ops, bl_saved, bl_session
    from blender_addon.worker import state

    load_before = os.getloadavg()[0]
    tmp = Path(tempfile.mkdtemp(prefix="bench_addon_"))
    photo_path = tmp / "photo.jpg"
    (make_photo if args.synthetic else make_real_photo)(photo_path, height, width)
    blender_addon.register()
    bl_session.updates_immediately = lambda: False  # behave as with a UI: timers, previews, workers
    image = bpy.data.images.load(str(photo_path))
    image.pixels[0]  # the Image Editor showing the photo has loaded its pixels before Relight is pressed
    settings = bpy.context.scene.relight_photo
    settings.quality, settings.light_kind, settings.preset = args.quality, "PRESET", "studio"
    settings.mask_mode = args.mask
    for timer in bl_ops._TIMERS:  # the property updates above armed the idle timer
        if bpy.app.timers.is_registered(timer):
            bpy.app.timers.unregister(timer)
    rows = []
    baseline = Probe()  # the machine's own noise: the probe with no add-on work at all
    baseline.idle(5.0, "nothing (baseline)")
    rows.append(("Baseline: longest probe stretch with no add-on work (5 s)", baseline.worst, None))
    probe = Probe()

    # ---- Relight, modal, ticked every POLL_SECONDS like Blender's event timer
    op, context = modal_operator(bpy, bl_ops, image.name)
    t0 = time.perf_counter()
    probe.call("Relight pressed (plan)", lambda: op._start(context, layers_later=True))  # as invoke() does
    timer_event = types.SimpleNamespace(type="TIMER")
    result = {"PASS_THROUGH"}
    while result == {"PASS_THROUGH"}:
        probe.idle(bl_session.POLL_SECONDS)
        result = probe.call("modal tick (poll or one image write)", op.modal, context, timer_event)
    relit_shown = time.perf_counter() - t0
    assert result == {"FINISHED"}, result
    stages = op._job.progress.durations(op._job.finished_at)
    run_timer(probe, bl_ops.poll_layers, "layers: poll / one image write")
    relight_wall = time.perf_counter() - t0
    rows.append(("Relight: press to the relit image shown (wall)", relit_shown, None))
    rows.append(("Relight: press to all outputs written (wall)", relight_wall, None))
    for stage, seconds in stages:
        rows.append((f"  worker: {stage.lower()}", seconds, None))
    rows.append(("Relight: longest main-thread stretch", probe.worst, 0.100))
    rows.append(("  ... during", probe.worst_what, None))
    session = state.SESSIONS[image[bl_images.PHOTO_ID]]
    photo_name, had_preview = image.name, session.preview is not None
    print(f"photo {width} x {height}, crop {session.decomposition.box}, working "
          f"{session.decomposition.working_size}, preview "
          f"{session.preview.size if session.preview is not None else None}")

    # ---- dials: preview at once, full size when the dial rests
    previews, fulls = [], []
    dial_probe = Probe()
    for k in range(args.dials):
        settings.rotation = math.radians(20.0 * (k + 1))  # the property update arms the idle timer
        t = time.perf_counter()
        run_timer(dial_probe, bl_dials.deferred_refresh, "dial: preview")
        previews.append(time.perf_counter() - t)
        dial_probe.idle(bl_dials.REST_SECONDS, "waiting for the dial to rest")
        t = time.perf_counter()
        run_timer(dial_probe, bl_dials.full_when_resting, "dial rests: full-size job started")
        run_timer(dial_probe, bl_dials.poll_full_size, "full-size poll / write")
        fulls.append(time.perf_counter() - t)
    assert tuple(bpy.data.images[f"{image.name}.relit"].size) == (width, height)
    rows.append(("Dial: preview shown (median)", float(np.median(previews)), 0.150))
    rows.append(("Dial: full size shown after the dial rests (median)", float(np.median(fulls)), 3.0))
    rows.append(("Dials: longest main-thread stretch", dial_probe.worst, 0.100))
    rows.append(("  ... during", dial_probe.worst_what, None))

    # ---- Relight again: the outputs exist and the buffers are pooled
    again_probe = Probe()
    op, context = modal_operator(bpy, bl_ops, image.name)
    t0 = time.perf_counter()
    again_probe.call("Relight pressed (plan)", lambda: op._start(context, layers_later=True))
    result = {"PASS_THROUGH"}
    while result == {"PASS_THROUGH"}:
        again_probe.idle(bl_session.POLL_SECONDS)
        result = again_probe.call("modal tick (poll or one image write)", op.modal, context, timer_event)
    run_timer(again_probe, bl_ops.poll_layers, "layers: poll / one image write")
    rows.append(("Relight again (outputs exist): press to all written", time.perf_counter() - t0, None))
    rows.append(("Relight again: longest main-thread stretch", again_probe.worst, 0.100))
    rows.append(("  ... during", again_probe.worst_what, None))

    # ---- save and reopen
    blend = tmp / "bench.blend"
    t = time.perf_counter()
    probe_save = Probe()
    probe_save.call("save", lambda: bpy.ops.wm.save_as_mainfile(filepath=str(blend)))
    rows.append(("Save .blend (main thread)", time.perf_counter() - t, None))
    while any(thread.is_alive() for thread, _s, _f in bl_saved.SAVING):
        probe_save.idle(0.05, "decomposition file written by a thread")
    rows.append(("Save: decomposition file written (thread)", time.perf_counter() - t, None))
    rows.append(("Save: longest main-thread stretch", probe_save.worst, 0.100))
    reopen_probe = Probe()
    t = time.perf_counter()
    # the add-on's load_post handler is called by hand right after Blender's own loading,
    # as Blender would, so the two are timed apart
    bpy.app.handlers.load_post.remove(bl_saved.on_load)
    reopen_probe.call("open the .blend (Blender's own loading)",
                      lambda: bpy.ops.wm.open_mainfile(filepath=str(blend)))
    blender_open = time.perf_counter() - t
    bpy.app.handlers.load_post.append(bl_saved.on_load)
    reopen_probe.call("the add-on's load handler (saved preview)", bl_saved.on_load)
    handler = time.perf_counter() - t - blender_open
    opened = time.perf_counter() - t  # the saved preview is shown: visible, dials live
    assert f"{photo_name}.preview" in bpy.data.images or not had_preview
    settings = bpy.context.scene.relight_photo
    settings.rotation = math.radians(15.0)
    td = time.perf_counter()
    run_timer(reopen_probe, bl_dials.deferred_refresh, "dial on the saved preview")
    dial_on_preview = time.perf_counter() - td
    run_timer(reopen_probe, bl_saved.poll_restore, "restore: poll")
    photo_read = time.perf_counter() - t
    run_timer(reopen_probe, bl_ops.poll_layers, "restore: full-size layers, one per call")
    full_back = time.perf_counter() - t
    settings.rotation = math.radians(5.0)
    td = time.perf_counter()
    run_timer(reopen_probe, bl_dials.deferred_refresh, "dial after reopen")
    dial_after = time.perf_counter() - td
    rows.append(("Reopen: Blender's own open_mainfile", blender_open, None))
    rows.append(("Reopen: the add-on's load handler (main thread)", handler, 0.100))
    rows.append(("Reopen: open until the relit preview shows, dials live", opened, 1.0))
    rows.append(("Reopen: a dial on the saved preview", dial_on_preview, 0.150))
    rows.append(("Reopen: full photo read again (the full size can follow)", photo_read, None))
    rows.append(("Reopen: all layers at full size", full_back, None))
    rows.append(("Reopen: a dial after the full photo is back (preview)", dial_after, 0.150))
    rows.append(("Reopen: longest main-thread stretch", reopen_probe.worst, 0.100))
    rows.append(("  ... during", reopen_probe.worst_what, None))
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024 ** 2
    rows.append(("Peak memory (GB)", peak, None))

    print(f"\nRelight Photo at {width} x {height} ({'synthetic' if args.synthetic else REAL_PHOTO.name}), "
          f"{args.quality}, mask {args.mask}, {os.cpu_count()} cores, probe every {PROBE_MS:.0f} ms, "
          f"load average before {load_before:.1f}\n")
    print("| measure | s | goal | met |")
    print("|---|---|---|---|")
    for name, value, goal in rows:
        if isinstance(value, str):
            print(f"| {name} | {value} | | |")
            continue
        met = "" if goal is None else ("yes" if value <= goal else f"no (+{value - goal:.2f} s)")
        print(f"| {name} | {value:.3f} | {'' if goal is None else f'<= {goal:g}'} | {met} |")
    blender_addon.unregister()
    shutil.rmtree(tmp, ignore_errors=True)  # the 24 MP photo, the .blend and its saved relight
    return 0


if __name__ == "__main__":
    sys.exit(main())
