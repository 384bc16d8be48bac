"""Peak memory (and time) of the add-on's 24 MP operations, each in a fresh process under headless bpy.

    .venv/bin/python benchmarks/bench_addon_memory.py [--size 6000x4000] [--quality BALANCED]
                                                      [--mask AUTO] [--flows relight,ui,save_layers,reopen]

Each flow runs in its own child process (so ru_maxrss is that flow's peak):

- relight: `bpy.ops.relight_photo.relight(synchronous=True)` on the photo as
  the Image Editor shows it (its pixels loaded), every output written;
- ui: the same press as Blender's UI drives it: the modal operator ticked by
  timer events (the relit image first), then the other layers' worker;
- again: Relight, then Relight again with the outputs there (its peak alone);
- save_layers: Relight, then `bpy.ops.relight_photo.save_layers` (timed alone);
- save_layers_ui: the same Save Layers as the file browser's confirm runs it with a UI: the
  operator's execute, then its modal handler ticked by timer events every 0.05 s; the longest
  main-thread stretch (a probe between ticks) is recorded;
- reopen: Relight, save the .blend, `wm.open_mainfile` (peak of the open and
  restore only: the maximum is reset before it);
- reopen_ui: the same with a UI: the Relight modal, the save's thread, the
  saved preview first, then the restore's worker and the full-size layers one
  per timer call.

The photo is the bundled public-domain evaluation/data/matte_eval/obama_standing.jpg
enlarged to the size (made once in a temporary folder). A sampler thread reads
the process's resident set every 2 ms and keeps, for the highest reading, what
every thread was doing (the innermost add-on or relight functions on its stack),
so the table says where the peak is.
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import threading
import time
import traceback
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
FLOWS = ("relight", "ui", "again", "save_layers", "save_layers_ui", "reopen", "reopen_ui")
PAGE = os.sysconf("SC_PAGE_SIZE")


def rss_bytes() -> int:
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * PAGE


class PeakSampler:
    """The resident set every `interval` s on a thread; the stacks of all threads at its highest."""

    def __init__(self, interval: float = 0.002):
        self.interval, self.peak, self.where = interval, 0, ""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def __enter__(self):
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()

    def reset(self) -> None:
        self.peak, self.where = rss_bytes(), "start"

    def _run(self) -> None:
        me = threading.get_ident()
        while not self._stop.wait(self.interval):
            rss = rss_bytes()
            if rss > self.peak:
                self.peak = rss
                self.where = "; ".join(filter(None, (_ours(frame) for ident, frame in
                                                     sys._current_frames().items() if ident != me)))


def _ours(frame) -> str:
    """The innermost frames of the project's code on a thread's stack (two at most)."""
    names = []
    for summary in reversed(traceback.extract_stack(frame)):
        path = summary.filename.replace(os.sep, "/")
        if "/blender_addon/" in path or "/relight/" in path:
            names.append(f"{Path(path).stem}.{summary.name}")
            if len(names) == 2:
                break
    return " < ".join(names)


def child(flow: str, photo: str, quality: str, mask: str, out: str) -> None:
    import bpy

    import blender_addon
    from blender_addon.blender import bl_ops, bl_saved, bl_session

    folder = Path(tempfile.mkdtemp(prefix="bench_mem_"))
    blender_addon.register()
    if flow in ("ui", "reopen_ui"):
        bl_session.updates_immediately = lambda: False  # as with a UI: workers, timers, previews
    image = bpy.data.images.load(photo)
    image.pixels[0]  # the Image Editor showing the photo has loaded it before Relight is pressed
    settings = bpy.context.scene.relight_photo
    settings.quality, settings.light_kind, settings.preset, settings.mask_mode = quality, "PRESET", "studio", mask
    for timer in bl_ops._TIMERS:
        if bpy.app.timers.is_registered(timer):
            bpy.app.timers.unregister(timer)
    result = dict(flow=flow, before=rss_bytes())
    with PeakSampler() as sampler:
        sampler.reset()
        t = time.perf_counter()
        if flow in ("ui", "reopen_ui"):
            _modal_relight(bpy, bl_ops, bl_session, image.name)
        else:
            assert bpy.ops.relight_photo.relight(image_name=image.name, synchronous=True) == {"FINISHED"}
        result["relight_s"] = time.perf_counter() - t
        result["relight_peak"], result["relight_where"] = sampler.peak, sampler.where
        result["after"] = rss_bytes()
        if flow == "again":
            sampler.reset()
            t = time.perf_counter()
            assert bpy.ops.relight_photo.relight(image_name=image.name, synchronous=True) == {"FINISHED"}
            result["step_s"], result["step_peak"], result["step_where"] = \
                time.perf_counter() - t, sampler.peak, sampler.where
        elif flow == "save_layers":
            sampler.reset()
            t = time.perf_counter()
            status = bpy.ops.relight_photo.save_layers(filepath=str(folder / "layers.exr"), image_name=image.name)
            assert status == {"FINISHED"}, status
            result["step_s"], result["step_peak"], result["step_where"] = \
                time.perf_counter() - t, sampler.peak, sampler.where
            result["exr_mb"] = (folder / "layers.exr").stat().st_size / 1e6
        elif flow == "save_layers_ui":
            sampler.reset()
            t = time.perf_counter()
            result["main_stretch"] = _modal_save_layers(bpy, bl_ops, bl_session, image.name, folder / "layers.exr")
            result["step_s"], result["step_peak"], result["step_where"] = \
                time.perf_counter() - t, sampler.peak, sampler.where
            result["exr_mb"] = (folder / "layers.exr").stat().st_size / 1e6
        elif flow in ("reopen", "reopen_ui"):
            blend = folder / "bench.blend"
            bpy.ops.wm.save_as_mainfile(filepath=str(blend))
            bl_saved.wait_for_saves()
            sampler.reset()
            t = time.perf_counter()
            bpy.ops.wm.open_mainfile(filepath=str(blend))
            if flow == "reopen_ui":  # Blender's timers, called as it would
                from benchmarks.bench_addon import Probe, run_timer

                run_timer(Probe(), bl_saved.poll_restore, "restore")
                run_timer(Probe(), bl_ops.poll_layers, "layers")
            result["step_s"], result["step_peak"], result["step_where"] = \
                time.perf_counter() - t, sampler.peak, sampler.where
    result["maxrss"] = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    Path(out).write_text(json.dumps(result))


def _modal_relight(bpy, bl_ops, bl_session, image_name: str) -> None:
    """Relight as the UI runs it: the modal operator on timer ticks, then the layers' worker."""
    from benchmarks.bench_addon import Probe, modal_operator, run_timer

    import types

    op, context = modal_operator(bpy, bl_ops, image_name)
    op._start(context, layers_later=True)
    tick = types.SimpleNamespace(type="TIMER")
    result = {"PASS_THROUGH"}
    while result == {"PASS_THROUGH"}:
        time.sleep(bl_session.POLL_SECONDS)
        result = op.modal(context, tick)
    assert result == {"FINISHED"}, result
    run_timer(Probe(), bl_ops.poll_layers, "layers")


def _modal_save_layers(bpy, bl_ops, bl_session, image_name: str, path: Path) -> float:
    """Save Layers as the UI runs it (execute after the file browser, then timer ticks); returns the
    longest main-thread stretch in seconds."""
    import types

    from benchmarks.bench_addon import Probe, operator_stand_in

    class WindowManager:
        relight_photo_status = bpy.context.window_manager.relight_photo_status

        def __getattr__(self, name):  # progress_begin/update/end, event_timer_add/remove, modal_handler_add
            return lambda *a, **k: None

    bl_session.updates_immediately = lambda: False
    cls = bl_ops.RELIGHT_PHOTO_OT_save_layers
    op = operator_stand_in(cls, filepath=str(path), image_name=image_name, synchronous=False, _job=None,
                           _timer=None, _plan=None, _started=0.0, SLOT=cls.SLOT)
    context = types.SimpleNamespace(scene=bpy.context.scene, window_manager=WindowManager(), workspace=None,
                                    space_data=None, window=object())
    probe, tick = Probe(), types.SimpleNamespace(type="TIMER")
    result = probe.call("save layers: execute", op.execute, context)
    while result == {"RUNNING_MODAL"} or result == {"PASS_THROUGH"}:
        probe.idle(bl_session.POLL_SECONDS)
        result = probe.call("save layers: modal tick", op.modal, context, tick)
    assert result == {"FINISHED"}, result
    return probe.worst


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", default="6000x4000", help="photo HxW")
    parser.add_argument("--quality", default="BALANCED")
    parser.add_argument("--mask", default="AUTO")
    parser.add_argument("--flows", default=",".join(FLOWS))
    parser.add_argument("--child", nargs=3, metavar=("FLOW", "PHOTO", "OUT"), help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.child:
        flow, photo, out = args.child
        child(flow, photo, args.quality, args.mask, out)
        return 0
    height, width = (int(v) for v in args.size.lower().split("x"))
    load = os.getloadavg()
    with tempfile.TemporaryDirectory(prefix="bench_mem_") as tmp:
        photo = Path(tmp) / "photo.jpg"
        from benchmarks.bench_addon import make_real_photo

        make_real_photo(photo, height, width)
        rows = []
        for flow in args.flows.split(","):
            out = Path(tmp) / f"{flow}.json"
            cmd = [sys.executable, __file__, "--quality", args.quality, "--mask", args.mask,
                   "--child", flow, str(photo), str(out)]
            subprocess.run(cmd, check=True, cwd=REPO)
            rows.append(json.loads(out.read_text()))
    gb = 1024 ** 3
    import bpy

    print(f"\nRelight Photo memory at {width} x {height}, {args.quality}, mask {args.mask}, bpy "
          f"{bpy.app.version_string}, Python {sys.version.split()[0]}, load average "
          f"{load[0]:.1f} {load[1]:.1f} {load[2]:.1f}\n")
    print("| flow | RSS before (GB) | Relight peak (GB) | Relight s | RSS after (GB) | second step | its peak (GB) "
          "| its s | process max RSS (GB) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        step = {"again": "Relight again", "save_layers": "Save Layers", "save_layers_ui": "Save Layers (UI)",
                "reopen": "open_mainfile", "reopen_ui": "open_mainfile"}.get(r["flow"], "")
        step_cols = (f"{step} | {r['step_peak'] / gb:.2f} | {r['step_s']:.1f}" if step else " | | ")
        print(f"| {r['flow']} | {r['before'] / gb:.2f} | {r['relight_peak'] / gb:.2f} | {r['relight_s']:.1f} | "
              f"{r['after'] / gb:.2f} | {step_cols} | {r['maxrss'] / gb:.2f} |")
    print("\nWhere each peak was (the project's innermost functions on every thread's stack):\n")
    for r in rows:
        print(f"- {r['flow']}: Relight: {r['relight_where'] or '-'}")
        if "step_where" in r:
            print(f"  - second step: {r['step_where'] or '-'}")
        if "exr_mb" in r:
            print(f"  - layers EXR: {r['exr_mb']:.0f} MB")
        if "main_stretch" in r:
            print(f"  - longest main-thread stretch while saving: {r['main_stretch']:.3f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
