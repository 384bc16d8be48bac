"""Save Layers' worker: the relit photo and its layers under the dials, as one multi-layer EXR
written in bands of rows (relight.files.exr.write_exr_bands), named as
relight.files.photo.write_layers_exr names them (Blender's render-layer naming).

Each full-size map is made once, into one working buffer (the pooled RGBA buffer when one is
kept), and its planes are staged in a scratch file without a name beside the target; the EXR is
then written from that file a band of BAND_ROWS rows at a time. The worker so holds one
full-size buffer while it makes the maps and a band (a few MB) while it writes, where the EXR
writer took every channel whole (1.1 GB at 24 MP, beside Blender's own images). The staged
planes go through the page cache, not Blender's memory; the file has no name, so nothing is left
behind, whatever happens. Esc is looked at before each map and each band: the write stops there
and leaves nothing (each band is also a short stretch for Blender's main thread: OpenEXR keeps
the GIL while it compresses one).
"""

from __future__ import annotations

import os
import shutil
import tempfile

import numpy as np

from . import engine, jobs, people
from ..logic import pixel_buffers

BAND_ROWS = 32  # rows per band: 7.7 MB of 15 float channels at 4000 px wide, compressed in tens of ms
PASSES = (("Relit", "RGBA"), ("Albedo", "RGB"), ("Shading", "RGB"), ("Residual", "RGB"), ("Alpha", "A"),
          ("Shadow", "X"))  # Shadow: the share of the light's key the body leaves (a value pass, Blender's X)
LAYER_STAGES = {"alpha": ("Making the alpha layer", 0.15), "shadow": ("Making the shadow layer", 0.17),
                "albedo": ("Making the albedo layer", 0.20),
                "shading": ("Making the shading layer", 0.30), "residual": ("Making the residual layer", 0.40)}
WRITING = ("Writing the EXR file", 0.50)
# Save Layers writes 15 float32 channels, compressed at best to about half, and stages 14 planes
# at most: the free space asked for before any work
LAYERS_EXR_CHANNELS, STAGED_PLANES = 15, 14


def channel_names(people: int = 1) -> list[str]:
    """The EXR's channels, in the order of a band's planes; with more than one person relit, a matte
    pass each after them (Person1.A the largest: they sum to Alpha.A)."""
    from relight.files.photo import LAYER_NAME

    passes = PASSES + tuple((f"Person{k}", "A") for k in range(1, people + 1) if people > 1)
    return [f"{LAYER_NAME}.{name}.{c}" for name, channels in passes for c in channels]


def check_layers_target(path: str, height: int, width: int, people: int = 1) -> None:
    """ValueError, in the artist's words, when the layers cannot be written to `path`:
    checked before anything is computed (a 24 MP photo's layers take seconds)."""
    folder = os.path.dirname(path) or "."
    if os.path.isdir(path):
        raise ValueError(f"'{path}' is a folder: choose a file name for the layers.")
    if not os.path.isdir(folder):
        raise ValueError(f"The folder '{folder}' does not exist: choose another place for the layers.")
    if not os.access(folder, os.W_OK):
        raise ValueError(f"The folder '{folder}' cannot be written to: choose another place for the layers.")
    mattes = people if people > 1 else 0  # a matte pass per person, written and staged
    need = ((LAYERS_EXR_CHANNELS + mattes) // 2 + STAGED_PLANES + mattes) * 4 * height * width
    free = shutil.disk_usage(folder).free
    if free < need:
        raise ValueError(f"The disk holding '{folder}' has {free / 1e6:.0f} MB free; the layers need about "
                         f"{need / 1e6:.0f} MB while they are written: free some space or choose another place.")


class StagedPlanes:
    """Full-size float32 planes [H, W] kept in a scratch file, read back a band of rows at a time."""

    def __init__(self, folder: str, height: int, width: int):
        self.height, self.width, self.count = height, width, 0
        self._file = tempfile.TemporaryFile(dir=folder, prefix=".relight_layers_", buffering=0)

    def close(self) -> None:
        self._file.close()

    def add(self, plane: np.ndarray) -> int:
        """Append a contiguous [H, W] plane; returns its index."""
        data = memoryview(np.ascontiguousarray(plane, np.float32)).cast("B")
        self._file.seek(self.count * data.nbytes)
        while data:  # a large write may be partial
            data = data[self._file.write(data):]
        self.count += 1
        return self.count - 1

    def read_rows(self, index: int, r0: int, out: np.ndarray) -> None:
        """Rows r0:r0 + len(out) of plane `index` into `out` ([rows, W] float32, contiguous)."""
        row = 4 * self.width
        self._file.seek(index * row * self.height + r0 * row)
        view = memoryview(out).cast("B")
        while view:
            got = self._file.readinto(view)
            if not got:
                raise OSError("the scratch file of the layers ended early")
            view = view[got:]


def stage_maps(d, dials, staged: StagedPlanes, progress: jobs.Progress, check) -> dict[str, int]:
    """Make the relit photo and each layer at full size, one at a time, into one working buffer,
    staging their planes; returns {channel name: staged plane} (a channel not there is constant:
    Relit.A is 1, a residual without E is 0)."""
    light, rotation, exposure, strength = dials
    h, w = d.size
    everyone = people.people_of(d)
    prefix = channel_names()[0].rsplit(".", 2)[0]  # the render layer's name
    where: dict[str, int] = {}
    # a pooled RGBA buffer when one is kept (its planes taken as they are), else three planes of
    # their own (288 MB at 24 MP, not the pool's 384)
    pooled = pixel_buffers.BUFFERS.take_pooled(h * w * 4)
    planes = np.empty((3, h, w), np.float32) if pooled is None else pooled.reshape(4, h, w)
    rgb = planes[:3].transpose(1, 2, 0)

    def stage_rgb(pass_name: str) -> None:
        for c, channel in enumerate("RGB"):
            where[f"{prefix}.{pass_name}.{channel}"] = staged.add(rgb[..., c])

    try:
        progress.enter("Relighting at full size", 0.02)
        check()
        coeffs = engine.coefficients(d, light, rotation)
        d.relight(coeffs, exposure_ev=exposure, out=rgb)
        pixel_buffers.blend_into(rgb, d.photo, strength)
        stage_rgb("Relit")
        progress.enter(*LAYER_STAGES["alpha"])
        check()
        where[f"{prefix}.Alpha.A"] = staged.add(d.layer("alpha", coeffs, exposure, out=planes[0]))
        progress.enter(*LAYER_STAGES["shadow"])  # the person's own shadow under the dials' light (issue 46)
        check()
        where[f"{prefix}.Shadow.X"] = staged.add(d.shadow_layer(coeffs, exposure, out=planes[0]))
        for layer in ("albedo", "shading", "residual"):
            progress.enter(*LAYER_STAGES[layer])
            check()
            if layer == "residual" and not d.has_residual:  # E is zero (the shipped model): black
                continue
            d.layer(layer, coeffs, exposure, out=rgb)
            stage_rgb(layer.capitalize())
        for k, person in enumerate(everyone if len(everyone) > 1 else (), 1):  # one matte pass per person
            progress.enter(f"Making person {k}'s matte", LAYER_STAGES["residual"][1])
            check()
            where[f"{prefix}.Person{k}.A"] = staged.add(person.full_alpha(out=planes[0]))
    finally:
        if pooled is not None:  # nothing reads it any more
            pixel_buffers.BUFFERS.give(pooled)
    return where


def bands(staged: StagedPlanes, where: dict[str, int], progress: jobs.Progress, check, names=None):
    """[rows, W, C] bands from the top, the C channels in `names` (channel_names()) order (each its own
    array: a writer may hold a few while it compresses them)."""
    names = names or channel_names()
    opaque = [i for i, name in enumerate(names) if name.endswith(".Relit.A")]  # the relit frame is the whole photo
    h, w = staged.height, staged.width
    start, share = WRITING[1], 0.99 - WRITING[1]
    for r0 in range(0, h, BAND_ROWS):
        check()
        rows = min(BAND_ROWS, h - r0)
        band = np.zeros((len(names), rows, w), np.float32)
        band[opaque] = 1.0
        for c, name in enumerate(names):
            if name in where:
                staged.read_rows(where[name], r0, band[c])
        if not np.isfinite(band).all():
            raise ValueError("The layers to save contain NaN or Inf values.")
        progress.fraction = start + share * (r0 + rows) / h
        yield band.transpose(1, 2, 0)
        del band  # the writer's now: not held while the next is read


def save_layers_work(plan: dict, progress: jobs.Progress, token: engine.CancelToken) -> str:
    """Save Layers' worker: the relit photo and its layers under the dials, written to plan["tmp"]
    beside the chosen file (the main thread puts it in place; Esc leaves nothing). Returns the path."""
    from relight.files.exr import write_exr_bands
    from relight.files.photo import EXR_COMPRESSION, exr_threads

    session, tmp = plan["session"], plan["tmp"]
    d = session.decomposition
    h, w = d.size
    staged = StagedPlanes(os.path.dirname(tmp) or ".", h, w)
    try:
        where = stage_maps(d, plan["dials"], staged, progress, token.check)
        progress.enter(*WRITING)
        exr_threads()
        names = channel_names(len(people.people_of(d)))  # a matte pass per person relit
        write_exr_bands(tmp, names, h, w, bands(staged, where, progress, token.check, names),
                        compression=EXR_COMPRESSION)
        with plan["handover"]:  # Esc now or never: the main thread cancels under the same lock
            token.check()
            plan["written"] = True
    except BaseException:
        os.unlink(tmp) if os.path.exists(tmp) else None
        raise
    finally:
        staged.close()
    return tmp
