"""One scene of a job module, rendered and reported: the steps a local worker (farm/worker.py)
and a Ray task (farm/execution/ray_executor.py) share. The job module is any module with
`SceneOptions` and `render_scene` (farm.scene, farm.clips, a test's fault-injecting one)."""

from __future__ import annotations

import errno
import importlib
import os
import sys
import time
import traceback
from pathlib import Path

ENOSPC_TEXT = os.strerror(errno.ENOSPC)  # "No space left on device"


def load_job(module_name: str):
    """Import the job module; returns (SceneOptions class, render_scene function)."""
    module = importlib.import_module(module_name)
    for attr in ("SceneOptions", "render_scene"):
        if not hasattr(module, attr):
            raise ValueError(f"job module {module_name} has no {attr}")
    return module.SceneOptions, module.render_scene


def is_disk_full(exc: BaseException) -> bool:
    """True when exc (or what caused it) is ENOSPC, also when a library re-raised it as text."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, OSError) and exc.errno in (errno.ENOSPC, errno.EDQUOT):
            return True
        if ENOSPC_TEXT.lower() in str(exc).lower():
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def render_one(render_scene, options, index: int, seed: int, out_dir: Path) -> dict:
    """Render one scene; returns a protocol message (never raises for scene errors)."""
    start = time.monotonic()
    try:
        json_path = render_scene(index, seed, options, Path(out_dir))
    except Exception as exc:  # the scene's failure is reported, the worker is retired
        traceback.print_exc(file=sys.stderr)
        text = f"{type(exc).__name__}: {exc}".replace("\n", " ")[:500]
        return {
            "event": "failed",
            "index": index,
            "error": text,
            "disk_full": is_disk_full(exc),
            "seconds": time.monotonic() - start,
        }
    return {
        "event": "done",
        "index": index,
        "json": str(json_path),
        "seconds": time.monotonic() - start,
    }
