"""The add-on's side of relight.network.runtime: open a model, decompose, relight, save.

Plain Python (no bpy). Keeps one onnxruntime session per model file, and
the measured network time per (model, working size) so the progress bar of
the next run can estimate how far along it is.
"""

from __future__ import annotations

import json
import os
import threading
import time
from pathlib import Path

import numpy as np

from ..logic import light_sources, pixel_buffers

_RELIGHTERS: dict[tuple, object] = {}
_SECONDS: dict[tuple, float] = {}   # (model path, working size) -> last network time


def open_relighter(model_path: str):
    """A cached relight.network.runtime.Relighter for the file (reopened when the file changes)."""
    from relight.network.runtime import Relighter

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


class Cancelled(Exception):
    """The user pressed Esc: the work stopped where it was."""


class CancelToken:
    """Shared by the main thread (cancel) and the worker (check); terminates a running inference."""

    def __init__(self):
        self._event = threading.Event()
        self._run_options = []
        self.stopped_inference = False  # True when cancel() ended a network pass while it ran

    def cancel(self) -> None:
        self._event.set()
        for options in list(self._run_options):
            options.terminate = True  # onnxruntime stops the running session.run and raises

    @property
    def cancelled(self) -> bool:
        return self._event.is_set()

    def check(self) -> None:
        if self._event.is_set():
            raise Cancelled()

    def run_options(self):
        import onnxruntime as ort

        options = ort.RunOptions()
        self._run_options.append(options)
        if self._event.is_set():
            options.terminate = True
        return options


def known_sh_order(model_path: str) -> int | None:
    """The SH order of a model without opening it: an open session's, else the model
    registry's metadata for a shipped file; None when only opening it would tell."""
    p = Path(model_path)
    for (path, _mtime, _size), relighter in _RELIGHTERS.items():
        if path == str(p.resolve()):
            return int(relighter.sh_order)
    from relight import models

    try:
        registry = models.load_registry(models.REGISTRY_PATH)
    except (OSError, ValueError):
        return None
    for entry in registry.get("models", {}).values():
        if (models.REGISTRY_PATH.parent / entry["file"]).resolve() == p.resolve():
            order = entry.get("metadata", {}).get("relight.sh_order")
            return int(order) if order is not None else None
    return None


def decompose(relighter, photo: np.ndarray, mask: np.ndarray | None, working_size: int,
              cancel: CancelToken | None = None, augment=(), refine: int = 0,
              augment_until_agreed: float | None = None, ensemble=(), matte: str = "network",
              matte_method: str = "ensemble"):
    """Run the network (the slow step; called on the worker thread): once, or once per
    augmentation of the quality preset (and per network of its ensemble), and refine the
    light when it says so.

    Without `mask`, `matte` says where the matte comes from (Relighter.decompose): "network", the
    relighting network's own alpha (the panel's Network Matte), or "person", the person matte
    (`matte_method`: its segmenter), as `relight image --light-from` finds the person in the
    photo whose light it takes.

    With `cancel`, each inference runs with onnxruntime RunOptions that
    CancelToken.cancel() terminates (relight.models.session.cancellable, on this network and the
    ensemble's), so Esc stops even a running network pass.
    """
    start = time.monotonic()
    from relight.models.session import cancellable

    networks = [relighter] + [relighter.member(name) for name in ensemble]
    if cancel is not None:
        cancel.check()
    try:
        # the panel's mask modes decide the matte: AUTO passes the person matte as `mask`,
        # NETWORK passes None for the network's own alpha; another photo's light, matte="person"
        with cancellable(networks if cancel is not None else (), cancel.run_options() if cancel else None):
            decomposition = relighter.decompose(photo, mask=mask, working_size=working_size, matte=matte,
                                                matte_method=matte_method, augment=augment, refine=refine,
                                                augment_until_agreed=augment_until_agreed, ensemble=ensemble)
    except Exception:
        if cancel is not None and cancel.cancelled:
            cancel.stopped_inference = True  # onnxruntime gave up the run it was in
            raise Cancelled() from None
        raise
    _SECONDS[(str(relighter.model_path), working_size, tuple(augment), refine, tuple(ensemble))] = \
        time.monotonic() - start
    return decomposition


def decompose_everyone(relighter, photo: np.ndarray, working_size: int, cancel: CancelToken | None = None,
                       matte_method: str = "ensemble", mattes: list | None = None, **options):
    """Everyone in the photo (relight.network.group.decompose_people: each person at their own crop,
    the photo's one light from all of them) under the quality preset's `options`, as `relight image`
    does without --person: the Decomposition alone when one person is relit, else a people.People.
    `mattes`: the people's mattes found by the last press on this photo (not looked for again).
    Esc terminates a running network pass, as in decompose()."""
    from relight.network.group import decompose_people
    from relight.models.session import cancellable
    from relight.person.matte import NoPersonError

    from .people import People

    networks = [relighter] + [relighter.member(name) for name in options.get("ensemble", ())]
    if cancel is not None:
        cancel.check()
    try:
        with cancellable(networks if cancel is not None else (), cancel.run_options() if cancel else None):
            group = decompose_people(relighter, photo, matte_method=matte_method, working_size=working_size,
                                     mattes=mattes, **options)
    except NoPersonError:
        raise ValueError(NO_PERSON) from None
    except Exception:
        if cancel is not None and cancel.cancelled:
            cancel.stopped_inference = True
            raise Cancelled() from None
        raise
    return group.people[0] if len(group.people) == 1 else People(group)


NO_PERSON = ("No person was found in the photo: set Mask to Network Matte, Image Alpha or Other Image, "
             "or use a photo where a person is clearly visible.")


def person_matte(photo: np.ndarray, person: int, method: str = "ensemble") -> tuple[np.ndarray, int]:
    """(soft alpha [H, W], how many people the photo shows) for person `person`
    (1 = the largest), from relight.person.matte (`method`: its segmenter); errors in the artist's words."""
    from relight.person.matte import NoPersonError, PersonIndexError
    from relight.person.matte import person_matte as find

    try:
        found = find(photo, person, method=method)
    except NoPersonError:
        raise ValueError(NO_PERSON) from None
    except PersonIndexError as exc:
        count = exc.count
        raise ValueError(f"Person {person} is chosen, but the photo shows only {count} "
                         f"{'person' if count == 1 else 'people'}: choose another in the Person list.") from None
    return found.alpha, found.count


def preview_decomposition(decomposition, long_side: int):
    """The decomposition over a copy of the photo scaled to `long_side` (a screen), for
    relighting while a dial moves; None when the photo is not much larger than that.

    Same network outputs (working resolution), so the preview is the full
    result, only smaller.
    """
    from relight.network.decomposition import Decomposition
    from relight.imaging.resample import fit_longest, resize_linear

    from .people import People

    H, W = decomposition.size
    if max(H, W) <= 1.25 * long_side:
        return None
    if isinstance(decomposition, People):  # each person over the same smaller photo, one light
        from relight.network.group import Group

        people = [preview_decomposition(d, long_side) for d in decomposition.people]
        group = decomposition.group
        return People(Group(people=people, left=group.left, count=group.count))
    h, w = fit_longest(H, W, long_side)
    box = decomposition.box.rescaled((H, W), (h, w))
    # every k-th pixel first (k = half the reduction): the area filter then reads
    # 1/k^2 of the photo; a preview's slight aliasing is the price of ~10x less work
    k = max(1, int(min(H / h, W / w) // 2))
    mask = None
    if decomposition.mask is not None:
        mask = np.clip(resize_linear(decomposition.mask[::k, ::k], h, w), 0.0, 1.0)
    return Decomposition(
        albedo=decomposition.albedo, transport=decomposition.transport, residual=decomposition.residual,
        light=decomposition.light, alpha=decomposition.alpha, box=box, working_size=decomposition.working_size,
        photo=resize_linear(decomposition.photo[::k, ::k], h, w), photo_working=decomposition.photo_working,
        mask=mask, sh_order=decomposition.sh_order)


def coefficients(decomposition, light, rotation_deg: float) -> np.ndarray:
    """The SH coefficients a relight of `decomposition` takes: `light` (a relight.lighting.light.SHLight,
    SH coefficients or another photo's Decomposition) at the model's order, turned by
    rotation_deg about world Z."""
    from relight.lighting.light import SHLight

    cache = light_sources.light_cache()
    return SHLight.resolve(light, decomposition.sh_order, cache=cache).at(rotation_deg, cache)


def relit_rgba(decomposition, light, rotation_deg: float, exposure_ev: float, strength: float,
               out: np.ndarray | None = None, orientation: int = 1) -> np.ndarray:
    """The relit photo blended by `strength`, as a buffer in Blender's layout (worker-safe).

    Composited straight into the buffer (RGB of RGBA, bottom row first): no full-size
    RGB image besides it (288 MB at 24 MP). `orientation`: the photo file's EXIF orientation;
    the decomposition is upright, the buffer holds it as the file stores it (as Blender shows it)."""
    h, w = decomposition.size
    rgba = pixel_buffers.BUFFERS.take(h * w * 4) if out is None else out
    view = pixel_buffers.blender_view(rgba, (h, w), orientation)
    decomposition.relight(coefficients(decomposition, light, rotation_deg), exposure_ev=exposure_ev,
                          out=view[..., :3])
    view[..., 3] = 1.0
    pixel_buffers.blend_into(view[..., :3], decomposition.photo, strength)
    return rgba


# ------------------------------------------------------------------ saved decompositions

SAVE_FORMAT = "relight-photo-decomposition/1"
_HALF = ("albedo", "transport", "residual", "photo_working")  # fp16: ample for 8-bit photos and light


def save_decomposition(path: str | os.PathLike, decomposition, meta: dict, preview=None) -> Path:
    """Write the decomposition (network outputs at working resolution, no photo; the
    preview's screen-sized photo when given) as a compressed .npz, atomically; `meta`
    (plain values) is stored with it."""
    from .people import people_of

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # everyone relit (people.People): the largest person as one person is kept, each other person's
    # maps beside it under "person<k>." and their crops in info["people"] (one entry per person)
    everyone = people_of(decomposition)
    arrays, info = {}, dict(meta, format=SAVE_FORMAT, box=list(everyone[0].box),
                            working_size=list(everyone[0].working_size), sh_order=int(decomposition.sh_order))
    for k, d in enumerate(everyone, 1):
        arrays.update({_person_key(k, name): getattr(d, name).astype(np.float16 if name in _HALF else np.float32)
                       for name in (*_HALF, "alpha", "light")})
    if len(everyone) > 1:
        info["count"] = int(decomposition.count)
        info["people"] = [dict(index=int(d.choices.get("person", k)), box=list(d.box),
                               working_size=list(d.working_size)) for k, d in enumerate(everyone, 1)]
    if preview is not None:
        # the screen-sized photo (and mask) too: reopening shows a relit preview
        # and the dials work before the full photo has been read again
        arrays["preview_photo"] = preview.photo.astype(np.float16)
        for k, p in enumerate(people_of(preview), 1):
            if p.mask is not None:
                arrays[_person_key(k, "preview_mask")] = p.mask.astype(np.float16)
            (info if k == 1 else info["people"][k - 1])["preview_box"] = list(p.box)
    from relight.files.fileio import atomic_path

    with atomic_path(path, ".npz") as tmp:
        write_npz(tmp, dict(meta=np.array(json.dumps(info)), **arrays))
    return path


def write_npz(path, arrays: dict) -> None:
    """The file np.savez_compressed writes (np.load reads it), with the zip closed on every way out.

    numpy 1.x (bpy 4.2 to 5.0's) leaves its ZipFile open when a write fails; on a full disk its
    __del__ fails again, and Python prints "Exception ignored in ZipFile.__del__ ... [Errno 28]"
    once per file. Here the first error is the one raised, and the file is let go of."""
    import zipfile

    from numpy.lib import format as npy_format

    archive = zipfile.ZipFile(path, mode="w", compression=zipfile.ZIP_DEFLATED, allowZip64=True)
    try:
        for name, value in arrays.items():
            with archive.open(f"{name}.npy", "w", force_zip64=True) as member:
                npy_format.write_array(member, np.asanyarray(value), allow_pickle=False)
    except BaseException:
        try:
            archive.close()  # it lets go of the file even when its last write fails too
        except (OSError, ValueError):
            pass  # the disk is still full: the error raised below says so
        raise
    archive.close()


def load_decomposition_arrays(path: str | os.PathLike) -> tuple[dict, dict]:
    """(arrays as float32, meta) of a saved decomposition; ValueError when unreadable."""
    try:
        with np.load(path, allow_pickle=False) as data:
            meta = json.loads(str(data["meta"]))
            arrays = {k: data[k].astype(np.float32) for k in data.files if k != "meta"}
    except (OSError, ValueError, KeyError) as exc:
        raise ValueError(f"The saved relight '{Path(path).name}' cannot be read ({_sentence(exc)})") from None
    if meta.get("format") != SAVE_FORMAT:
        raise ValueError(f"The saved relight '{Path(path).name}' is from another version of the add-on.")
    return arrays, meta


def _person_key(k: int, name: str) -> str:
    """A saved array's key: person k's (1 = the largest) when everyone was relit; the first's as one person's."""
    return name if k == 1 else f"person{k}.{name}"


def rebuild_decomposition(arrays: dict, meta: dict, photo: np.ndarray, mask: np.ndarray | None,
                          box: tuple | None = None, k: int = 1):
    """A relight.network.decomposition.Decomposition from saved arrays over the (re-read) photo
    (`k`: which person of everyone relit)."""
    from relight.network.decomposition import Decomposition

    entry = meta if k == 1 else meta["people"][k - 1]
    a = {name: arrays[_person_key(k, name)] for name in (*_HALF, "alpha", "light")}
    d = Decomposition(albedo=a["albedo"], transport=a["transport"], residual=a["residual"],
                      light=a["light"], alpha=a["alpha"], box=tuple(box or entry["box"]),
                      working_size=tuple(entry["working_size"]), photo=photo,
                      photo_working=a["photo_working"], mask=mask, sh_order=int(meta["sh_order"]))
    if "people" in meta:
        d.choices["person"] = int(meta["people"][k - 1]["index"])
    return d


def rebuild_people(arrays: dict, meta: dict, photo: np.ndarray, masks: list, preview: bool = False):
    """Everyone relit (people.People) from saved arrays, each person over `photo` with their matte."""
    from relight.network.group import Group

    from .people import People

    people = [rebuild_decomposition(arrays, meta, photo, mask, k=k,
                                    box=tuple((meta if k == 1 else meta["people"][k - 1])["preview_box"])
                                    if preview else None) for k, mask in enumerate(masks, 1)]
    return People(Group(people=people, count=int(meta["count"])))


def people_mattes(photo: np.ndarray, method: str) -> dict:
    """{person index (1 = the largest): full-size matte} of everyone the person matte finds."""
    from relight.person.linear_photo import check_photo
    from relight.person.matte import MIN_SIDE, mattes_of_checked_photo

    photo = check_photo(photo, MIN_SIDE, finite=False, purpose="a person matte")
    return {m.index: m.alpha for m in mattes_of_checked_photo(photo, method=method)}


def saved_preview(arrays: dict, meta: dict):
    """The preview decomposition kept by save_decomposition, or None."""
    if "preview_photo" not in arrays:
        return None
    photo = np.ascontiguousarray(arrays["preview_photo"])
    if "people" in meta:
        return rebuild_people(arrays, meta, photo, [arrays.get(_person_key(k, "preview_mask"))
                                                    for k in range(1, len(meta["people"]) + 1)], preview=True)
    return rebuild_decomposition(arrays, meta, photo, arrays.get("preview_mask"), box=tuple(meta["preview_box"]))


def expected_seconds(model_path: str, working_size: int, augment=(), refine: int = 0,
                     augment_until_agreed: float | None = None, ensemble=()) -> float | None:
    """How long the last run of this model at this size (and test-time work) took, if there was one."""
    return _SECONDS.get((str(Path(model_path)), working_size, tuple(augment), refine, tuple(ensemble)))


def relight(decomposition, light, rotation_deg: float, exposure_ev: float) -> np.ndarray:
    """The photo relit, linear [H, W, 3]: the person composited over the untouched background."""
    return decomposition.relight(coefficients(decomposition, light, rotation_deg), exposure_ev=exposure_ev)


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
