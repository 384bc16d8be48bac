"""The add-on's only contact with relight.runtime: open a model, decompose, relight, save.

Plain Python (no bpy). Keeps one onnxruntime session per model file, and
the measured network time per (model, working size) so the progress bar of
the next run can estimate how far along it is.
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np

_RELIGHTERS: dict[tuple, object] = {}
_SECONDS: dict[tuple, float] = {}   # (model path, working size) -> last network time


def open_relighter(model_path: str):
    """A cached relight.runtime.Relighter for the file (reopened when the file changes)."""
    from relight.runtime import Relighter

    p = Path(model_path)
    if not p.is_file():
        raise ValueError(f"The model file '{model_path}' does not exist.")
    st = p.stat()
    key = (str(p.resolve()), st.st_mtime_ns, st.st_size)
    relighter = _RELIGHTERS.get(key)
    if relighter is None:
        try:
            relighter = Relighter(p)
        except ValueError as exc:
            raise ValueError(f"The model '{p.name}' cannot be used: {_sentence(exc)}") from None
        _RELIGHTERS.clear()  # one model in memory at a time
        _RELIGHTERS[key] = relighter
    return relighter


def decompose(relighter, photo: np.ndarray, mask: np.ndarray | None, working_size: int):
    """Run the network once (the slow step; called on the worker thread)."""
    start = time.monotonic()
    decomposition = relighter.decompose(photo, mask=mask, working_size=working_size)
    _SECONDS[(str(relighter.model_path), working_size)] = time.monotonic() - start
    return decomposition


def expected_seconds(model_path: str, working_size: int) -> float | None:
    """How long the last run of this model at this size took, if there was one."""
    return _SECONDS.get((str(Path(model_path)), working_size))


def sh_order(relighter_or_decomposition) -> int:
    return int(relighter_or_decomposition.sh_order)


def relight(decomposition, light, rotation_deg: float, exposure_ev: float) -> np.ndarray:
    """The photo relit, linear [H, W, 3]: the person composited over the untouched background."""
    return decomposition.relight(light, rotation_deg=rotation_deg, exposure_ev=exposure_ev)


def layers(decomposition, light, rotation_deg: float, exposure_ev: float) -> dict[str, np.ndarray]:
    """albedo, shading, residual [H, W, 3] under the target light, and alpha [H, W]."""
    return decomposition.layers(light, rotation_deg=rotation_deg, exposure_ev=exposure_ev)


def save_layers(path: str, relit: np.ndarray, layer_maps: dict[str, np.ndarray]) -> Path:
    """Multi-layer EXR (Blender's render-layer naming), written atomically."""
    from relight.photo import write_layers_exr

    return write_layers_exr(path, np.ascontiguousarray(relit, dtype=np.float32), layer_maps)


def user_error(exc: BaseException | None) -> Exception:
    """A worker-thread exception as a one-sentence ValueError for self.report."""
    if isinstance(exc, ValueError):
        return ValueError(_sentence(exc))
    if isinstance(exc, MemoryError):
        return ValueError("Out of memory while running the network: choose a lower quality.")
    return ValueError(f"The network failed ({type(exc).__name__}: {_sentence(exc)})")


def _sentence(exc: BaseException) -> str:
    lines = str(exc).strip().splitlines()
    text = lines[0] if lines else type(exc).__name__
    return text if text.endswith(".") else text + "."
