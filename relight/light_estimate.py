"""The photo's light read off the person by the light estimator (issue 25): its input, its
run, and how its answer joins a decomposition. numpy + onnxruntime.

The geometry-first network fits the photo's light to its albedo prior, so the light's
colour and level are only as right as that prior; a small network trained for the light
alone (model/light_estimator.py) reads them better off the same person (docs/EVALUATION.md,
"The photo's light"). Its input is the crop the relighting network saw, masked, padded to
a square and shrunk to 64 px, plus the matte:

    x = estimator_input(crop, matte)        # [1, 4, 64, 64] float32
    answer = LightEstimate().run(x)          # {"light": [n, 3], "albedo_mean": [3]}, or None without the model
    d = with_albedo_level(d, answer["albedo_mean"])   # the network's light rescaled, its albedo re-derived
"""

from __future__ import annotations

import os
import threading

import numpy as np

from relight.models import REGISTRY_PATH
from relight.prt import to_network_input
from relight.resample import resize_linear

__all__ = ["INPUT_SIZE", "MODEL_NAME", "MODEL_FILE", "LightEstimate", "estimator_input", "with_albedo_level",
           "with_light_colour"]

INPUT_SIZE = 64
MODEL_NAME, MODEL_FILE = "light-estimator", "light_estimator.onnx"


def square(image: np.ndarray) -> np.ndarray:
    """[h, w, C] zero-padded to a centred square (the training crops are squares already)."""
    h, w = image.shape[:2]
    side = max(h, w)
    out = np.zeros((side, side) + image.shape[2:], dtype=np.float32)
    y, x = (side - h) // 2, (side - w) // 2
    out[y:y + h, x:x + w] = image
    return out


def estimator_input(crop: np.ndarray, matte: np.ndarray) -> np.ndarray:
    """[1, 4, 64, 64]: the linear crop [h, w, 3] masked by `matte` [h, w] in the network's
    encoding (relight.prt.to_network_input), and the matte mapped to [-1, 1]."""
    crop = np.asarray(crop, dtype=np.float32)
    matte = np.clip(np.asarray(matte, dtype=np.float32), 0.0, 1.0)
    if crop.ndim != 3 or crop.shape[2] != 3 or matte.shape != crop.shape[:2]:
        raise ValueError(f"estimator_input needs a crop [h, w, 3] and its matte [h, w], got {crop.shape}, "
                         f"{matte.shape}")
    both = resize_linear(square(np.concatenate([crop, matte[..., None]], axis=-1)), INPUT_SIZE, INPUT_SIZE)
    small_matte = np.clip(both[..., 3], 0.0, 1.0)
    x = np.concatenate([to_network_input(both[..., :3], small_matte), small_matte[..., None] * 2.0 - 1.0], -1)
    return np.ascontiguousarray(x.transpose(2, 0, 1)[None], dtype=np.float32)


class LightEstimate:
    """The installed light estimator (hash-checked, relight.session.open_session), opened once
    per registry and thread count; `available` is False when the registry has none."""

    _lock = threading.Lock()
    _sessions: dict = {}

    def __init__(self, threads: int | None = None, registry_path: str | os.PathLike = REGISTRY_PATH):
        from relight.models import load_registry

        entry = load_registry(registry_path)["models"].get(MODEL_NAME)
        self.path = None if entry is None else os.path.join(os.path.dirname(os.fspath(registry_path)), entry["file"])
        self.threads, self.registry_path = threads, registry_path

    @property
    def available(self) -> bool:
        return self.path is not None and os.path.isfile(self.path)

    def _session(self):
        from relight.session import open_session

        key = (self.path, self.threads)
        with self._lock:
            if key not in self._sessions:
                self._sessions[key] = open_session(self.path, threads=self.threads,
                                                   registry_path=self.registry_path)[0]
            return self._sessions[key]

    def run(self, x: np.ndarray) -> dict[str, np.ndarray] | None:
        """{"light": [n, 3], "albedo_mean": [3]} for one estimator_input; None when no estimator
        is installed."""
        if not self.available:
            return None
        session = self._session()
        names = [o.name for o in session.get_outputs()]
        values = session.run(names, {session.get_inputs()[0].name: x})
        out = {name: v[0].astype(np.float32) for name, v in zip(names, values)}
        if set(out) != {"light", "albedo_mean"}:
            raise ValueError(f"{self.path}: not a light estimator (outputs {sorted(out)})")
        if not all(np.all(np.isfinite(v)) for v in out.values()):
            raise ValueError("the light estimator produced NaN/Inf: its weights are broken")
        return out


INTERIOR = 0.999  # alpha from which a pixel is all person: the mean albedo is taken over these


def with_albedo_level(d, albedo_mean: np.ndarray):
    """Decomposition `d` with its light scaled per channel so that its photo-consistent albedo's
    mean over the person's fully covered pixels is `albedo_mean` [3]: the light's colour and
    level as the photo's pixels see them (the mean shading), which the network's fit takes
    from its albedo prior. Its shape (the fit's answer to the photo's shading) is kept; the
    albedo is re-derived by the network's own rule (relight.refine.consistent_albedo). Only
    for the geometry-first network (E zero); others are returned unchanged."""
    import dataclasses

    from relight.refine import consistent_albedo

    if d.has_residual:
        return d
    w = d.alpha >= INTERIOR
    if not w.any():
        w = d.alpha > 0
    if not w.any():
        return d
    own = d.albedo[w].astype(np.float64).mean(axis=0)
    want = np.clip(np.asarray(albedo_mean, np.float64), 1e-3, 1.0)
    # albedo = photo / shading: scaling channel c of the light by g divides its albedo by g
    gains = np.where(own > 1e-6, own / want, 1.0)
    new = (d.light.astype(np.float64) * gains[None, :]).astype(np.float32)
    return dataclasses.replace(d, light=new, albedo=consistent_albedo(d, d.transport, new))


def with_light_colour(d, light: np.ndarray, level: bool = True):
    """Decomposition `d` with its light given `light`'s colour and level: per-channel gains
    that make d.light's DC term `light`'s (the network's fit keeps the light's shape, read
    from the photo's shading), the albedo re-derived by the network's own photo-consistent
    rule (relight.refine.consistent_albedo), so relighting stays photo x shading' / shading.
    With `level` False only the colour: the gains keep d.light's DC luminance.
    Only for the geometry-first network (E zero); others are returned unchanged."""
    import dataclasses

    from relight.refine import consistent_albedo

    if d.has_residual:
        return d
    light = np.asarray(light, dtype=np.float64)
    own = d.light.astype(np.float64)
    # a channel the network lit with (almost) nothing keeps its own level: no gain from 0
    gains = np.where(own[0] > 1e-6, np.maximum(light[0], 0.0) / np.maximum(own[0], 1e-6), 1.0)
    if not level:
        from relight.colour import LUMINANCE_WEIGHTS

        weights = np.asarray(LUMINANCE_WEIGHTS, np.float64)
        gains *= float(own[0] @ weights) / max(float((own[0] * gains) @ weights), 1e-12)
    new = (own * gains[None, :]).astype(np.float32)
    return dataclasses.replace(d, light=new, albedo=consistent_albedo(d, d.transport, new))
