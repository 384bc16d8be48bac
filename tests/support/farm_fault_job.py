"""A stand-in scene module for the runner's fault tests (SceneOptions + render_scene).

Faults come from the environment, which workers inherit:
  FARM_FAULT_DIR   folder for the event log (one line per event: "start INDEX PID",
                   "unreaped INDEX N" (the farm's exited workers not yet waited for),
                   "end INDEX PID"), tmpdirs.log ("PID TEMPDIR": every scene leaves a
                   scratch file in its temp folder) and once-only markers
  FARM_FAULTS      JSON {index: fault}; faults: "crash-once" (SIGKILL itself on the first
                   attempt), "hang-once" (sleep past any timeout on the first attempt),
                   "raise" (always raise), "enospc" (raise ENOSPC), "fill" (write a
                   64 MiB temp file: a real ENOSPC on a small disk), "slow" (sleep
                   FARM_FAULT_SLOW seconds, then render)
  FARM_FAULT_SLOW_ALL  non-empty: every scene is "slow"
  FARM_FAULT_REAL  "1": render with the real farm.scene.render_scene, else write a tiny
                   valid scene through relight.files.dataset.write_scene
"""

from __future__ import annotations

import dataclasses
import errno
import json
import os
import signal
import tempfile
import time
from pathlib import Path

import numpy as np

from farm.synthesis.scene_options import SceneOptions  # the real options: same fields, same JSON


def _log(event: str, index: int, value: int | None = None) -> None:
    """One line "EVENT INDEX VALUE" of the events log; VALUE is this worker's pid unless given."""
    with open(Path(os.environ["FARM_FAULT_DIR"]) / "events.log", "a") as f:
        f.write(f"{event} {index} {os.getpid() if value is None else value}\n")
        f.flush()


def _first_time(name: str) -> bool:
    marker = Path(os.environ["FARM_FAULT_DIR"]) / f"once-{name}"
    try:
        marker.touch(exist_ok=False)
        return True
    except FileExistsError:
        return False


def _tiny_scene(index: int, seed: int, options: SceneOptions, out_dir: Path) -> Path:
    """An 8x8 scene in the real format (relight.files.dataset.write_scene), fast to write."""
    from relight.files.dataset import write_scene

    rng = np.random.default_rng([seed, index])
    size, k, n = 8, options.lights, (options.sh_order + 1) ** 2
    channels = {
        "alpha": np.ones((size, size), np.float32),
        "albedo": rng.random((size, size, 3), dtype=np.float32),
        "normal": rng.random((size, size, 3), dtype=np.float32),
        "material": rng.random((size, size, 3), dtype=np.float32),
        "depth": np.full((size, size), 3.0, np.float32),
    }
    if "prt" in options.passes:
        channels["transport"] = rng.random((size, size, n), dtype=np.float32)
    if "pt" in options.passes:
        for light in range(k):
            channels[f"image.L{light}"] = rng.random((size, size, 3), dtype=np.float32)
    lights = [{"name": f"L{j}", "sh": np.zeros((n, 3)), "sh8": np.zeros((81, 3))} for j in range(k)]
    meta = {"index": index, "seed": seed, "sh_order": options.sh_order, "lights": lights,
            "passes": {"asked": sorted(options.passes), "skipped": ["specular"]},
            "timings": {"total": 0.0}}
    _, json_path = write_scene(Path(out_dir) / f"scene_{index:06d}", channels, meta)
    return Path(json_path)


def _scratch(index: int) -> None:
    """Leave a file in the temp folder, as Cycles' intermediate EXRs do; note where."""
    folder = Path(tempfile.gettempdir())
    (folder / f"scratch_{index}.exr").write_bytes(b"scratch")
    with open(Path(os.environ["FARM_FAULT_DIR"]) / "tmpdirs.log", "a") as f:
        f.write(f"{os.getpid()} {folder}\n")


def _exited_siblings() -> int:
    """The farm's children that have exited but were not waited for (zombies), this one aside."""
    count = 0
    for stat in Path("/proc").glob("[0-9]*/stat"):
        try:
            fields = stat.read_text().rsplit(")", 1)[1].split()
        except (OSError, IndexError):
            continue
        count += fields[0] == "Z" and int(fields[1]) == os.getppid()
    return count


def render_scene(index: int, seed: int, options: SceneOptions, out_dir: Path) -> Path:
    _log("start", index)
    _log("unreaped", index, _exited_siblings())
    _scratch(index)
    fault = json.loads(os.environ.get("FARM_FAULTS", "{}")).get(str(index))
    if fault == "crash-once" and _first_time(f"crash-{index}"):
        os.kill(os.getpid(), signal.SIGKILL)
    if fault == "hang-once" and _first_time(f"hang-{index}"):
        time.sleep(3600)
    if fault == "raise":
        raise RuntimeError(f"injected failure in scene {index}")
    if fault == "enospc":
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(out_dir))
    if fault == "fill":  # a real ENOSPC from the kernel: write a temp EXR larger than the disk
        with open(Path(out_dir) / f".scene_{index:06d}.exr.fill.tmp.exr", "wb") as f:
            for _ in range(64):
                f.write(b"\0" * (1 << 20))
                f.flush()
    if fault == "slow" or os.environ.get("FARM_FAULT_SLOW_ALL"):
        time.sleep(float(os.environ.get("FARM_FAULT_SLOW", "2")))
    if os.environ.get("FARM_FAULT_REAL") == "1":
        from farm import scene

        path = scene.render_scene(index, seed, scene.SceneOptions(**dataclasses.asdict(options)), out_dir)
    else:
        path = _tiny_scene(index, seed, options, out_dir)
    _log("end", index)
    return path
