"""What the add-on's worker threads do: plain Python, no bpy.

The Relight job (read and check the photo, person matte, network, relight,
pack the outputs into Blender's layout), the restore job after a file is
opened, and writing a saved decomposition. The bl_* modules (bl_ops, bl_dials,
bl_saved) gather their inputs on Blender's main thread and hand their buffers
to Blender.
"""

from __future__ import annotations

import time

import numpy as np

from . import engine, jobs, state
from ..logic import light_sources, mask_choice, output_names, photo_checks, photo_pixels, pixel_buffers, quality

EVERYONE = 0  # the panel's Person "Everyone": all the people found, under the photo's one light
PREVIEW_LONG_SIDE = 1024  # px: the screen-sized preview shown while a dial moves on a large photo


def make_mask(inputs: dict, pixels: photo_pixels.PhotoPixels, quality_key: str) -> tuple:
    """(mask or None, people found or 0) on the worker: AUTO runs the person matte the
    quality preset names."""
    if inputs["mode"] == "AUTO":
        # Everyone with one person relit (a saved relight restored): that person is the largest
        person = max(1, inputs["person"])
        return engine.person_matte(pixels.rgb, person, quality.preset(quality_key).matte_method)
    alpha = pixels.alpha if inputs["use_photo_alpha"] else None
    # a mask image lies over the photo as Blender shows both (stored): upright, as the photo is read
    rgb, mask_alpha = (None if a is None else pixel_buffers.upright(a, pixels.orientation)
                       for a in (inputs["rgb"], inputs["alpha"]))
    return mask_choice.choose_mask(inputs["mode"], pixels.rgb.shape[:2], alpha, rgb, mask_alpha,
                                inputs["name"]), 0


def mattes_found_before(decomposition) -> list | None:
    """Everyone's person mattes of the last Relight of this photo under Everyone (a group's, or the one
    person found), for the next press not to look for the people again; None when not all are known."""
    group = getattr(decomposition, "group", None)
    if group is not None:
        mattes = list(getattr(group, "mattes", ()))
        return mattes if mattes and len(mattes) == group.count else None
    matte = getattr(decomposition, "person_matte", None)
    return [matte] if matte is not None and matte.count == 1 else None


def mask_key(inputs: dict) -> tuple:
    """What the mask was made from: (mode, mask image name, or the person's number for AUTO)."""
    return (inputs["mode"], str(inputs["person"]) if inputs["mode"] == "AUTO" else inputs["name"])


def layer_names(session: state.PhotoSession, with_relit: bool = False) -> list[str]:
    """The output layers this session gets, in the order they are handed to Blender."""
    names = ["relit"] if with_relit else []
    names += ["alpha", "albedo", "shading"]
    if session.decomposition.has_residual:  # else black under every light (a model without E): no image
        names.append("residual")
    if session.mask_key[0] == "AUTO" and session.decomposition.mask is not None:
        names.append("matte")
    return output_names.layers_in_order(names)


def layer_source(session: state.PhotoSession, layer: str):
    """The decomposition a layer is made from: the photo's own, or for `.matte` (the cut-out that
    shows what the person matte found, a check) the screen-sized preview of a large photo: a
    full-size float image costs 384 MB at 24 MP."""
    if layer == "matte" and session.preview is not None and session.preview.mask is not None:
        return session.preview
    return session.decomposition


def layer_size(session: state.PhotoSession, layer: str) -> tuple[int, int]:
    """(H, W) of a layer's image."""
    return layer_source(session, layer).size


def layer_buffer(session: state.PhotoSession, layer: str, dials) -> np.ndarray:
    """One output layer as a buffer in Blender's layout (worker-safe). Callers make and hand over
    one layer at a time: a 24 MP map is 288 MB, its buffer 384 MB, its Blender image 384 MB more."""
    light, rotation, exposure, strength = dials
    decomposition = layer_source(session, layer)
    if layer == "relit":
        return engine.relit_rgba(decomposition, light, rotation, exposure, strength, orientation=session.orientation)
    if layer == "matte":  # the photo cut out by the person matte, so the user can check what was found
        return pixel_buffers.to_blender_rgba(decomposition.photo, alpha=decomposition.mask,
                                             orientation=session.orientation)
    coeffs = engine.coefficients(decomposition, light, rotation)
    h, w = decomposition.size
    rgba = pixel_buffers.BUFFERS.take(h * w * 4)
    # Blender's layout: bottom row first, the photo as its file stores it
    view = pixel_buffers.blender_view(rgba, (h, w), session.orientation)
    if layer == "alpha":  # one channel (96 MB at 24 MP), grey in Blender: packed as it is
        return pixel_buffers.to_blender_rgba(decomposition.layer(layer, coeffs, exposure), rgba,
                                             orientation=session.orientation)
    # made in the buffer itself: no full-size map besides it (288 MB at 24 MP)
    decomposition.layer(layer, coeffs, exposure, out=view[..., :3])
    view[..., 3] = 1.0
    return rgba


def layer_buffers(session: state.PhotoSession, dials, with_relit: bool = True) -> dict:
    """Every output layer as a buffer at once: for a small photo only (a reopened file's saved
    preview); full-size layers go one at a time (layer_buffer)."""
    return {layer: layer_buffer(session, layer, dials) for layer in layer_names(session, with_relit)}


def relight_work(plan: dict, progress: jobs.Progress, token: engine.CancelToken) -> dict:
    """The worker thread's whole job: plain data in, a session and image buffers out (no bpy)."""
    progress.enter("Reading the photo", 0.02)
    pixels = plan["read_photo"]()
    token.check()
    photo_checks.check_photo_content(pixels.rgb)  # a photo with no visible person fails before anything loads
    relighter = plan["relighter"] or engine.open_relighter(plan["model_path"])
    light = plan["light"]
    if isinstance(light, tuple):  # a preset name or an HDR path: checked before the network runs
        kind, value = light
        light = light_sources.preset_light(value, relighter.sh_order) if kind == "PRESET" else \
            light_sources.hdr_file_light(value, relighter.sh_order)
    previous = plan.get("previous")
    everyone = plan["mask"]["mode"] == "AUTO" and plan["mask"]["person"] == EVERYONE
    same_matte = previous is not None and previous.digest == pixels.digest \
        and previous.mask_key == mask_key(plan["mask"]) and plan["mask"]["mode"] == "AUTO" \
        and quality.preset(previous.quality).matte_method == quality.preset(plan["quality"]).matte_method
    found_before = mattes_found_before(previous.decomposition) if everyone and same_matte else None
    if everyone:  # the person matte and the network for each person at once (engine.decompose_everyone)
        if found_before is None:
            progress.enter("Finding the people in the photo", 0.05)
        mask, people = None, 0
    elif same_matte:
        # the same photo, person and segmenter as its last Relight: the person matte would be the same again
        mask, people = previous.decomposition.mask, previous.people
    else:
        if plan["mask"]["mode"] == "AUTO":
            progress.enter("Finding the people in the photo", 0.05)
        mask, people = make_mask(plan["mask"], pixels, plan["quality"])
    token.check()
    progress.enter(jobs.NETWORK_STAGE, 0.10)
    network_start = time.monotonic()
    options = quality.network_options(plan["quality"])
    if everyone:
        decomposition = engine.decompose_everyone(relighter, pixels.rgb, plan["long_side"], token,
                                                  quality.preset(plan["quality"]).matte_method, found_before,
                                                  **options)
        people = getattr(decomposition, "count", 0) or decomposition.person_matte.count
    else:
        decomposition = engine.decompose(relighter, pixels.rgb, mask, plan["long_side"], token, **options)
    light_decomposition = None
    if plan["light_reader"] is not None:
        progress.enter("Estimating the light of the other photo", 0.45)
        other = plan["light_reader"]()
        photo_checks.check_photo_content(other.rgb)
        light_decomposition = light_photo_decomposition(relighter, other, plan, token, options)
        light = light_decomposition
    elif light is None:
        light = plan["light_cached"]
    network_seconds = time.monotonic() - network_start
    session = state.PhotoSession(
        photo_id=plan["photo_id"], source=plan["source"], photo=pixels.rgb, decomposition=decomposition,
        model_path=plan["model_path"], quality=plan["quality"], mask_key=mask_key(plan["mask"]),
        digest=pixels.digest, people=people, orientation=pixels.orientation)
    progress.enter("Relighting at full size", 0.60)
    dials = (light, plan["rotation"], plan["exposure"], plan["strength"])
    token.check()
    # the relit image only: the other layers follow one at a time (bl_layers), so that no more
    # than one full-size buffer waits for Blender
    buffers = {"relit": engine.relit_rgba(decomposition, *dials, orientation=session.orientation)}
    progress.enter("Preparing the preview", 0.90)
    session.preview = engine.preview_decomposition(decomposition, PREVIEW_LONG_SIDE)
    progress.enter("Writing the images", 0.95)
    return dict(session=session, buffers=buffers, light_decomposition=light_decomposition,
                network_seconds=network_seconds, dials=dials)


def light_photo_decomposition(relighter, other: photo_pixels.PhotoPixels, plan: dict, token, options: dict):
    """The decomposition whose light the Other Photo light takes, as `relight image --light-from`
    makes it: the other photo's alpha when it marks a person (it varies), else its person matte
    (the preset's segmenter; the largest person), not the relighting network's own alpha (mean IoU
    0.49 against 0.97, docs/MATTE.md)."""
    from relight.person.matte import NoPersonError

    alpha = other.alpha
    mask = alpha if alpha is not None and alpha.min() < 1.0 and alpha.max() > 0.0 else None
    try:
        return engine.decompose(relighter, other.rgb, mask, plan["long_side"], token, matte="person",
                                matte_method=quality.preset(plan["quality"]).matte_method, **options)
    except NoPersonError:
        raise ValueError("No person was found in the photo to take the light from: choose a photo "
                         "where a person is clearly visible.") from None


def restore_work(plan: dict) -> tuple:
    """Worker: re-read the photo, check it is the one that was relit, rebuild the decomposition:
    (session, buffers). Without a UI the buffers hold the relit image at full size; with one
    (plan["preview_first"]) a large photo's relit preview, else nothing: the full-size images
    follow one at a time (bl_layers)."""
    meta = plan["meta"]
    pixels = plan["reader"]()
    if pixels.digest != meta["digest"]:
        raise PhotoChanged(f"The photo '{plan['source']}' changed since it was relit.")
    if "people" in meta:  # everyone relit: each person's matte again (the photo's pixels are the same)
        mattes = engine.people_mattes(pixels.rgb, quality.preset(meta["quality"]).matte_method)
        wanted = [entry["index"] for entry in meta["people"]]
        if not all(index in mattes for index in wanted):
            raise ValueError(f"The people in '{plan['source']}' are not found as they were: press Relight.")
        decomposition = engine.rebuild_people(plan["arrays"], meta, pixels.rgb, [mattes[i] for i in wanted])
        people = len(mattes)
    else:
        mask, people = make_mask(plan["mask"], pixels, meta["quality"])  # the matte it was relit with
        decomposition = engine.rebuild_decomposition(plan["arrays"], meta, pixels.rgb, mask)
    session = state.PhotoSession(
        photo_id=meta["photo_id"], source=plan["source"], photo=pixels.rgb, decomposition=decomposition,
        model_path=meta["model_path"], quality=meta["quality"], mask_key=tuple(meta["mask_key"]),
        digest=pixels.digest, preview=engine.preview_decomposition(decomposition, PREVIEW_LONG_SIDE),
        saved_to=plan["path"], people=people, orientation=pixels.orientation)
    if not plan["preview_first"]:
        return session, {"relit": engine.relit_rgba(decomposition, *plan["dials"], orientation=session.orientation)}
    if session.preview is not None:
        return session, {"preview": engine.relit_rgba(session.preview, *plan["dials"], orientation=session.orientation)}
    return session, {}


class PhotoChanged(ValueError):
    """The photo's pixels are not the ones its saved decomposition was made from."""


def restore_all(plans: list) -> list:
    """restore_work for each plan; a plan that fails gives its error instead (ValueError in the
    artist's words), so one unreadable photo does not stop the others."""
    out = []
    for plan in plans:
        try:
            out.append(restore_work(plan))
        except Exception as exc:  # reported per photo on the main thread, never raised here
            out.append(exc if isinstance(exc, ValueError) else engine.user_error(exc))
    return out


def lights_to_save() -> list:
    out = []
    for (pid, model_path, quality_key), light in state.LIGHT_SOURCES.items():
        coeffs = getattr(light, "light", light)  # a Decomposition's estimate, or restored coefficients
        out.append([pid, model_path, quality_key, np.asarray(coeffs, np.float64).tolist()])
    return out


def restore_lights(saved: list) -> None:
    """The light-transfer sources lights_to_save stored, back as coefficients
    (a source already known is kept)."""
    for pid, model_path, quality_key, coeffs in saved:
        state.LIGHT_SOURCES.setdefault((pid, model_path, quality_key), np.asarray(coeffs, np.float64))


def save_meta(session: state.PhotoSession) -> dict:
    """What is stored beside a saved decomposition to bring the session back."""
    return dict(photo_id=session.photo_id, digest=session.digest, model_path=session.model_path,
                quality=session.quality, mask_key=list(session.mask_key), source=session.source,
                lights=lights_to_save(), orientation=session.orientation)


def save_one(session: state.PhotoSession, path: str, meta: dict, failures: list) -> None:
    """Write one photo's decomposition; a failure is appended to `failures` as (photo, reason)."""
    try:
        # a small photo is its own preview: kept too, so reopening shows the result without the file
        engine.save_decomposition(path, session.decomposition, meta, session.preview or session.decomposition)
    except OSError as exc:
        session.saved_to = ""
        failures.append((session.source, exc.strerror or str(exc)))


def save_failures_message(failures: list) -> str:
    """One sentence naming every photo whose saved relight was not written ('' when none)."""
    if not failures:
        return ""
    names = [f"'{name}'" for name, _ in failures]
    reasons = list(dict.fromkeys(reason for _, reason in failures))
    if len(names) == 1:
        return (f"The relight of {names[0]} could not be saved next to the .blend ({reasons[0]}): "
                "it will need Relight after reopening.")
    listed = ", ".join(names[:-1]) + " and " + names[-1]
    return (f"The relights of {len(names)} photos, {listed}, could not be saved next to the .blend "
            f"({'; '.join(reasons)}): they will need Relight after reopening.")
