"""Torch-free runtime: decompose a photo once with the ONNX network, then relight it many times.

    r = Relighter("model.onnx")                        # SHA-256 and metadata checked before loading
    d = r.decompose(photo)                             # photo: linear float32 [H, W, 3]; person matte
    out = d.relight(sh_light("studio", d.sh_order, rotation_deg=90))   # linear float32 [H, W, 3]

The network runs on a crop around the person resized to the working size
(longest side; the quality presets of relight/network/quality.py), so its cost and
memory do not grow with the photo. This module finds the person, crops,
resizes and runs the network; the rooms around it each do one job:
relight.models.session (the hash-checked onnxruntime session), relight.network.decomposition
(the network's outputs and the relighting formula), relight.network.composite (the
threaded, tiled compositing at full resolution), relight.imaging.resample (the
resizers), relight.lighting.light (any light -> SH coefficients). docs/runtime.md
explains the choices. Nothing here imports torch or bpy.
"""

from __future__ import annotations

import math
import os
from pathlib import Path

import numpy as np

from relight.network import quality
from relight.imaging.box import Box
from relight.network.composite import ALPHA_FLOOR
from relight.network.decomposition import Decomposition, RelightStats  # the runtime's result types
from relight.network.level import METADATA_KEY, LevelPrior, leveled
from relight.person.linear_photo import check_photo
from relight.models import REGISTRY_PATH, default_model_path
from relight.network.prt import to_network_input
from relight.imaging.resample import resize_longest
from relight.models.session import ModelSession

__all__ = ["Relighter", "Decomposition", "RelightStats", "MATTE_SOURCES", "check_working_size"]

DEFAULT_WORKING_SIZE = quality.preset(quality.DEFAULT).working_size  # the presets' table: relight/network/quality.py
_DEFAULT_OPTIONS = quality.preset(quality.DEFAULT).decompose_options(working_size=False)  # decompose's defaults
FIND_SIZE = 256          # longest side of the first, person-finding pass
FIND_THRESHOLD = 0.5     # alpha above which a low-res pixel counts as the person
CROP_MARGIN = 0.05       # context kept around the person's box, as a fraction of its longest side
MATTE_SOURCES = ("person", "network")  # where decompose() takes the matte from when no mask is given


# ------------------------------------------------------------------ validation


def _check_mask(mask, shape) -> np.ndarray:
    m = np.asarray(mask)
    if m.ndim == 3 and m.shape[2] == 1:
        m = m[..., 0]
    if m.shape != tuple(shape):
        raise ValueError(f"mask must be [H, W] = {tuple(shape)} like the photo, got {m.shape}")
    if m.dtype == bool:
        m = m.astype(np.float32)
    if not np.issubdtype(m.dtype, np.number):
        raise ValueError(f"mask must be numeric or bool, got dtype {m.dtype}")
    m = m.astype(np.float32, copy=False)
    if not np.all(np.isfinite(m)) or m.min() < 0 or m.max() > 1:
        raise ValueError("mask values must be finite and in [0, 1]")
    if not m.max() > 0:
        raise ValueError("mask is empty (all zero): it marks no person")
    return m


def _with_margin(box: Box, height: int, width: int) -> Box:
    """The crop around the person's box: CROP_MARGIN of its longest side (at least 2 px) more."""
    y0, y1, x0, x1 = box
    return box.grown(max(2, int(math.ceil(CROP_MARGIN * max(y1 - y0, x1 - x0)))), height, width)


def check_working_size(size) -> int:
    """The longest side of the network's crop, an integer in [16, 4096] (a quality preset's
    is relight.network.quality.preset(key).working_size)."""
    if isinstance(size, bool) or not isinstance(size, (int, np.integer)) or not 16 <= size <= 4096:
        raise ValueError(f"working size must be an integer in [16, 4096], got {size!r}")
    return int(size)


# ------------------------------------------------------------------ the network


class Relighter(ModelSession):
    """A relighting network (relight.models.session.ModelSession: SHA-256 and metadata checked) that
    decomposes photos.

    model_path: the .onnx file (default: the registry's default model);
    threads: intra-op threads, 1 to the cores this process may use (None: all of them);
    providers: onnxruntime execution providers (default CPU only);
    working_size: longest side, in pixels, of the crop the network sees (a quality preset's:
    relight.network.quality.preset(key).working_size).
    """

    def __init__(self, model_path: str | os.PathLike | None = None, threads: int | None = None,
                 providers: list | None = None, working_size: int = DEFAULT_WORKING_SIZE,
                 registry_path: str | os.PathLike = REGISTRY_PATH):
        path = Path(model_path) if model_path is not None else default_model_path(registry_path)
        self.working_size = check_working_size(working_size)
        super().__init__(path, threads, providers, registry_path)
        self._open = dict(threads=threads, providers=providers, registry_path=registry_path)
        self._members: dict[str, Relighter] = {}  # the ensemble's other networks, opened on first use
        self.level_prior = LevelPrior.from_metadata(self.metadata.get(METADATA_KEY))  # None: the model has none

    def member(self, name: str) -> "Relighter":
        """Another relighting network of the registry (by name) to average with this one's
        answers (decompose's `ensemble`), opened once; it must use the same SH order."""
        if name not in self._members:
            from relight.models import load_registry

            registry_path = Path(self._open["registry_path"])
            entry = load_registry(registry_path)["models"].get(name)
            if entry is None:
                raise ValueError(f"ensemble model {name!r} is not in {registry_path}")
            other = Relighter(registry_path.parent / entry["file"], working_size=self.working_size, **self._open)
            if other.sh_order != self.sh_order:
                raise ValueError(f"ensemble model {name!r} has SH order {other.sh_order}, not {self.sh_order}")
            self._members[name] = other
        return self._members[name]

    def run_crop(self, crop: np.ndarray, matte: np.ndarray | None) -> dict[str, np.ndarray]:
        """The network's outputs ([h, w, C] maps, "light" [n, 3]) for a linear [h, w, 3] image at its
        working size and its matte ([h, w] or None): padded to size_multiple, unpadded after. Every
        run of the network goes through here (decompose's, find_person's, relight.network.tta's)."""
        h, w = crop.shape[:2]
        m = self.size_multiple
        x = to_network_input(crop, matte)
        ph, pw = -h % m, -w % m
        if ph or pw:
            x = np.pad(x, ((0, ph), (0, pw), (0, 0)), mode="edge")
        out = self.run(x.transpose(2, 0, 1)[None])
        res = {k: v[0, :, :h, :w].transpose(1, 2, 0) for k, v in out.items() if k != "light"}
        res["light"] = out["light"][0]
        for k, v in res.items():
            if k == "residual" and self.residual_is_zero:
                continue  # transport * 0 by construction: not used, not scanned
            if not np.all(np.isfinite(v)):
                raise ValueError(f"the network produced NaN/Inf in {k!r}: model weights are broken")
        return res

    def find_person(self, photo: np.ndarray) -> Box:
        """Crop box around the person, from a low-resolution pass of the network's alpha
        head; the whole frame when it finds nobody."""
        H, W = photo.shape[:2]
        small = resize_longest(photo, min(FIND_SIZE, self.working_size))
        h, w = small.shape[:2]
        alpha = self.run_crop(small, None)["alpha"][..., 0]
        box = Box.around(alpha, FIND_THRESHOLD)
        if box is None:
            return Box.whole(H, W)
        return _with_margin(box.rescaled((h, w), (H, W)), H, W)

    def decompose(self, photo, mask=None, working_size: int | None = None, *,
                  matte: str = "person", person: int | None = None,
                  matte_method: str = _DEFAULT_OPTIONS["matte_method"], augment=_DEFAULT_OPTIONS["augment"],
                  refine: int = _DEFAULT_OPTIONS["refine"],
                  augment_until_agreed: float | None = _DEFAULT_OPTIONS["augment_until_agreed"],
                  ensemble=_DEFAULT_OPTIONS["ensemble"], level: bool = True,
                  person_matte=None) -> Decomposition:
        """Decompose the person in `photo` (linear float32 [H, W, 3]). The defaults are the
        default quality preset's, Balanced (quality.preset("balanced").decompose_options(): the
        network at 128 px averaged with its run on the mirrored crop, the ensemble person matte),
        so a bare `decompose(photo)` gives what `relight image` gives; another preset's are
        `**quality.preset(key).decompose_options()`, the network once `augment=()`.

        With `mask` ([H, W] in [0, 1]) the crop is the mask's box, the network
        input is masked, and the mask is the matte. Without one, `matte` says
        where the matte comes from: "person" (the default, as in `relight image`
        and the add-on: mean IoU 0.97 on the bundled photos, docs/MATTE.md) runs
        the person segmenter (relight.person.matte.person_matte; `person` picks one of
        several, 1 = the largest; NoPersonError when there is nobody) and uses
        its matte as the mask; "network" (for comparison, and for images that
        are not photos, such as renders the segmenter was not made for) takes
        the box from a low-resolution pass of the network's alpha head and that
        alpha as the matte (mean IoU 0.49 there). The chosen PersonMatte is kept
        as `person_matte` on the result; `matte_method` is relight.person.matte's ("ensemble", or
        "selfie": faster, less exact).

        `augment` ([(scale, mirrored)], relight.network.tta.AUGMENTATIONS) runs the network again on
        the crop mirrored and/or resized and averages the answers, stopping after the first
        when its answer is within `augment_until_agreed` of the network's own (relight.network.tta.
        disagreement; None: all run); `ensemble` (registry names of other relighting networks,
        `member`) adds their answers on the same crops (the plain one and the runs made) to the
        average; `level` shrinks the light's level and colour toward the model's training lights
        (relight.network.level, when the model carries a LevelPrior; False: the network's as it is);
        `refine` (iterations, 0: off) refits the photo's light to its shading gradients
        (relight.network.refine). What was done is recorded in the result's `choices` (the output's metadata).
        `person_matte`: one person's relight.person.matte.PersonMatte found on this `photo` before
        (relight.network.group: the photo checked there, as the "person" matte checks it), the
        matte and the crop's box taken from it as they are, nothing found or checked again.
        """
        if matte not in MATTE_SOURCES:
            raise ValueError(f"matte must be one of {MATTE_SOURCES}, got {matte!r}")
        # the Relighter's own working size was checked when it was made (and is passed again by
        # callers that take it from a quality preset): only another one is checked here
        same = working_size is None or (type(working_size) is int and working_size == self.working_size)
        size = self.working_size if same else check_working_size(working_size)
        found = person_matte
        if found is not None:
            mask = found.alpha
            box = _with_margin(found.box, *photo.shape[:2])
        elif mask is None and matte == "person":
            from relight.person import matte as segmenter

            # finite=False: the matte checks its block average, which a NaN or Inf survives (one
            # cheap check of every pixel, not a second full-photo scan)
            photo = check_photo(photo, segmenter.MIN_SIDE, finite=False, purpose="a person matte")
            found = segmenter.matte_of_checked_photo(photo, person, method=matte_method,
                                                     threads=self._open["threads"])  # --threads reaches the matte
            mask = found.alpha
            box = _with_margin(found.box, *photo.shape[:2])
        elif mask is not None:
            photo = check_photo(photo)
            mask = _check_mask(mask, photo.shape[:2])
            box = _with_margin(Box.around(mask), *photo.shape[:2])
        else:
            photo = check_photo(photo)
            box = self.find_person(photo)
        y0, y1, x0, x1 = box
        crop = resize_longest(photo[y0:y1, x0:x1], size)  # the working-size crop and matte, made once
        h, w = crop.shape[:2]
        small_mask = None if mask is None else np.clip(resize_longest(mask[y0:y1, x0:x1], size), 0.0, 1.0)
        out = self.run_crop(crop, small_mask)
        if small_mask is not None:
            alpha = small_mask
        else:
            alpha = np.where(out["alpha"][..., 0] < ALPHA_FLOOR, 0.0, out["alpha"][..., 0]).astype(np.float32)
        # the one Decomposition of this photo: the graph's answer (light, albedo, transport; no
        # residual when the model has none: residual_is_zero, its output neither copied nor scanned)
        d = Decomposition(
            albedo=np.ascontiguousarray(out["albedo"]), transport=np.ascontiguousarray(out["transport"]),
            residual=None if self.residual_is_zero else np.ascontiguousarray(out["residual"]),
            light=np.asarray(out["light"], np.float32),
            alpha=np.ascontiguousarray(alpha, dtype=np.float32), box=box, working_size=(h, w),
            photo=photo, photo_working=crop, mask=mask, sh_order=self.sh_order, person_matte=found,
            network_alpha=np.ascontiguousarray(out["alpha"][..., 0]),
            depth=np.ascontiguousarray(out["depth"][..., 0]) if "depth" in out else None)  # the depth head's
        choices = {"working_size": size, "network_input": [h, w], "person_px": max(y1 - y0, x1 - x0),
                   "matte": "mask" if found is None and mask is not None else
                   (f"person ({matte_method})" if found is not None else "network")}
        # The photo's light, changed in this one place (docs/ARCHITECTURE.md, "Where the photo's
        # light is estimated"): the graph's fit -> test-time average -> level prior -> refinement;
        # the albedo then follows from it once (Decomposition.with_light)
        transport, light = d.transport, d.light
        ran, done = list(augment), []
        if augment or ensemble:
            from relight.network import tta

            done = tta.runs(self, d, tuple(augment), augment_until_agreed) if augment else []
            ran = ran[:len(done)]
            for name in ensemble:  # each other network: the plain crop and the runs made
                done += tta.runs(self.member(name), d, ((1.0, False), *ran))
            transport, light = tta.averaged(d, done)
        choices["augment"] = [[float(s), bool(m)] for s, m in ran]
        if ensemble:
            choices["ensemble"] = [str(name) for name in ensemble]
        if augment_until_agreed is not None and len(ran) < len(augment):
            choices["augment_stopped"] = f"the first run agreed within {augment_until_agreed:g}"
        if level and self.level_prior is not None:
            gains = None
            if not d.has_residual:
                light, gains = leveled(self.level_prior, transport, light, d.alpha)
            choices["level"] = "off (the network's E is not zero)" if gains is None else \
                {"gains": [round(float(g), 4) for g in gains]}
        else:
            choices["level"] = "off" if self.level_prior is not None else "off (the model has no level prior)"
        if refine:
            from relight.network.refine import RefineReport, refine_light

            report = RefineReport((), 0, "off")  # a network with E: its albedo is not photo-consistent
            if not d.has_residual:
                light, report = refine_light(transport, crop, d.alpha, light, refine)
            choices["refine"] = report.as_dict()
        else:
            choices["refine"] = {"iterations": 0, "stopped": "off"}
        # the graph's albedo saw the masked input: it follows from the light on the unmasked crop
        # (a network with E keeps its own unless test-time averaging changed the light)
        if not d.has_residual or done:
            d = d.with_light(light, transport)
        d.choices = choices
        return d
