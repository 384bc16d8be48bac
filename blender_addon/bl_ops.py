"""Operators: Relight (network off the UI thread, Esc cancels) and Save Layers; the
dial, World, save and load handlers.

The main thread only gathers inputs (settings, the light) and hands finished
buffers to Blender (one foreach_set per image); reading and decoding the
photo, the network, relighting and packing pixels run on a worker thread.
"""

import math
import os
import time

import bpy
import numpy as np
from bpy.props import BoolProperty, StringProperty

from . import bl_images, bl_world, engine, jobs, pipeline, quality, state, work

SYNC_ENV = "RELIGHT_PHOTO_SYNC"   # 1: every Relight runs synchronously (tests, scripts)
POLL_SECONDS = 0.05               # how often the main thread looks at a running job
REST_SECONDS = 0.3                # a dial untouched this long is at rest: the full-size relight starts
LAYER_ORDER = ("relit", "alpha", "albedo", "shading", "residual", "matte")  # relit first: what the user sees


# ------------------------------------------------------------------ helpers

def _settings(context):
    return context.scene.relight_photo


def _status(context):
    return context.window_manager.relight_photo_status


def _set_status(context, message: str, is_error: bool = False) -> None:
    status = _status(context)
    status.message, status.is_error = message, is_error


def _editor_image(context):
    space = getattr(context, "space_data", None)
    if space is not None and space.type == "IMAGE_EDITOR":
        return space.image
    return None


def source_image(context, image_name: str = ""):
    """The photo to relight: `image_name`, else the editor's image (an output maps back to its photo)."""
    if image_name:
        image = bpy.data.images.get(image_name)
        if image is None:
            raise ValueError(f"There is no image called '{image_name}'.")
    else:
        image = _editor_image(context)
        if image is None:
            raise ValueError("Open a photo in the Image Editor first.")
    owner = bl_images.owner_of(image)
    if owner:
        photo = bl_images.photo_by_id(owner)
        if photo is None:
            raise ValueError(f"'{image.name}' is a relit output whose photo was deleted: open the photo itself.")
        return photo
    name = pipeline.source_of(image.name, set(bpy.data.images.keys()))
    return bpy.data.images[name]


def current_session(context):
    """The session the dials drive (its photo still exists), or None."""
    session = state.SESSIONS.get(_settings(context).last_photo_id)
    if session is None:
        return None
    photo = bl_images.photo_by_id(session.photo_id)
    if photo is None:
        return None
    session.source = photo.name  # follows a rename
    return session


def session_of(image):
    """The session of a photo datablock, or None."""
    pid = bl_images.photo_id(image)
    return state.SESSIONS.get(pid) if pid else None


def _mask_inputs(settings, image) -> dict:
    """What the worker needs to make the mask; errors a user can fix are raised here, at once."""
    width, height = image.size
    inputs = dict(mode=settings.mask_mode, rgb=None, alpha=None, name="", use_photo_alpha=False,
                  person=int(settings.person) if settings.person.isdigit() else 1)
    if settings.mask_mode == "IMAGE":
        mask_image = settings.mask_image
        if mask_image is not None:
            # stored values (code values of 8/16-bit files), not decoded colour: a mask is data
            stored = bl_images.rgba_pixels(mask_image)
            inputs["rgb"] = stored[..., :3] if stored.shape[2] >= 3 else np.repeat(stored[..., :1], 3, axis=2)
            inputs["alpha"] = stored[..., 3] if stored.shape[2] == 4 else None
            inputs["name"] = mask_image.name
        pipeline.choose_mask("IMAGE", (height, width), None, inputs["rgb"], inputs["alpha"], inputs["name"])
    elif settings.mask_mode == "IMAGE_ALPHA":
        if not bl_images.has_alpha(image):
            raise ValueError("The photo has no alpha channel to use as the mask.")
        inputs["use_photo_alpha"] = True
    return inputs


def _light_image_key(settings, model_path: str) -> tuple | None:
    if settings.light_kind != "IMAGE" or settings.light_image is None:
        return None
    return (bl_images.photo_id(settings.light_image, create=True), model_path, settings.quality)


def target_light(context, order: int, model_path: str):
    """(light, extra rotation in degrees) for the current settings.

    The light is a relight.light.Light (a preset, an HDR file or the World),
    SH coefficients (a restored light transfer) or the Decomposition of another
    photo: engine.coefficients turns any of them into what a relight takes;
    ValueError says what is missing.
    """
    settings = _settings(context)
    kind = settings.light_kind
    if kind == "PRESET":
        if settings.preset == "NONE":
            raise ValueError("No light preset is installed.")
        return pipeline.preset_light(settings.preset, order), 0.0
    if kind == "HDR":
        path = bpy.path.abspath(settings.hdr_path) if settings.hdr_path else ""
        return pipeline.hdr_file_light(path, order), 0.0
    if kind == "WORLD":
        world = context.scene.world
        if world is None:
            raise ValueError("The scene has no World to take the light from.")
        return _world_light(world, order)
    if kind == "IMAGE":
        if settings.light_image is None:
            raise ValueError("Choose the photo to take the light from.")
        light = state.LIGHT_SOURCES.get(_light_image_key(settings, model_path))
        if light is None:
            raise ValueError(f"Press Relight to estimate the light of '{settings.light_image.name}'.")
        return light, 0.0
    raise ValueError(f"Unknown light kind {kind!r}.")


def _world_light(world, order: int):
    """(Light, rotation) of the world, read (or baked) and projected once per
    state of its nodes (a hash of them: bl_world.fingerprint)."""
    key = bl_world.fingerprint(world)
    cached = state.WORLDS.get(key)
    if cached is None:
        cached = (bl_world.read_world(world), {})
        state.remember_world(key, cached)
    light, projected = cached
    if order not in projected:
        projected[order] = pipeline.equirect_light(light.equirect, order)
    return projected[order], light.rotation_deg


def _dials(context, session: state.PhotoSession):
    """(light, rotation degrees, exposure EV, strength) of the current settings."""
    return _dials_for(context, session.decomposition.sh_order, session.model_path)


def _dials_for(context, order: int, model_path: str):
    settings = _settings(context)
    light, extra_rotation = target_light(context, order, model_path)
    return light, math.degrees(settings.rotation) + extra_rotation, settings.exposure, settings.strength


def compute_relit(context, session: state.PhotoSession, dials=None):
    """Linear RGB [H, W, 3] of the cached decomposition relit with the current dials."""
    light, rotation, exposure, strength = dials or _dials(context, session)
    relit = engine.relight(session.decomposition, light, rotation, exposure)
    return pipeline.blend(relit, session.photo, strength)


def _write_output(session: state.PhotoSession, layer: str, rgba: np.ndarray, size: tuple[int, int]):
    """Hand a prepared buffer to Blender; the buffer goes back to the pool (nobody reads it after)."""
    colorspace = bl_images.NON_COLOR if layer == "alpha" else bl_images.LINEAR
    height, width = size
    try:
        return bl_images.write_rgba(pipeline.output_name(session.source, layer), rgba, width, height,
                                    colorspace=colorspace, owner=session.photo_id, layer=layer)
    finally:
        pipeline.BUFFERS.give(rgba)


def render_relit(context, session: state.PhotoSession, dials=None):
    """Relight the cached decomposition with the current dials and write '<photo>.relit' (this thread)."""
    dials = dials or _dials(context, session)
    rgba = engine.relit_rgba(session.decomposition, *dials)
    return _write_output(session, "relit", rgba, session.photo.shape[:2])


# ------------------------------------------------------------------ dials

def refresh_relit(context, preview: bool = False) -> None:
    """Property-update hook: redo the relit image from the cache (no network run).

    With `preview` (a UI is there) a large photo gets its screen-sized
    preview now and the full-size image from a worker once the dial rests.
    """
    bl_images.sync_output_names()
    session = current_session(context)
    if session is None:
        return
    session.dial_generation += 1
    try:
        dials = _dials(context, session)
        if preview and session.preview is not None:
            rgba = engine.relit_rgba(session.preview, *dials)
            _write_output(session, "preview", rgba, session.preview.size)
            show_in_editors(session, "preview")
            _set_status(context, "Preview: the full-size image follows when the dial rests.")
            _arm_full_size()
        else:
            render_relit(context, session, dials)
            _set_status(context, "")
    except ValueError as exc:
        _set_status(context, str(exc), is_error=True)


def _updates_immediately() -> bool:
    # without a UI (tests, scripts) timers never fire: relight at once
    return bpy.app.background or pipeline.env_flag(SYNC_ENV)


def _deferred_refresh():
    refresh_relit(bpy.context, preview=True)
    return None  # run once


def schedule_refresh(context) -> None:
    """A dial moved: relight now without a UI, else once the UI is idle.

    Dragging a slider sends an update per mouse move; deferring to a timer
    coalesces them, so a drag stays smooth.
    """
    if _updates_immediately():
        refresh_relit(context)
    elif not bpy.app.timers.is_registered(_deferred_refresh):
        bpy.app.timers.register(_deferred_refresh, first_interval=0.0)


def _arm_full_size() -> None:
    """(Re)start the rest timer: the full-size relight waits until the dial stops moving."""
    if bpy.app.timers.is_registered(_full_when_resting):
        bpy.app.timers.unregister(_full_when_resting)
    bpy.app.timers.register(_full_when_resting, first_interval=REST_SECONDS)


def start_full_size(session: state.PhotoSession, dials, with_layers: bool = False):
    """Relight the full-size photo on a worker; _poll_full_size writes it if no dial moved since."""
    generation = session.dial_generation
    if with_layers:
        job = jobs.BackgroundJob(lambda: work.layer_buffers(session, dials), label="full-size")
    else:
        job = jobs.BackgroundJob(lambda: {"relit": engine.relit_rgba(session.decomposition, *dials)},
                                 label="full-size")
    job.session, job.generation = session, generation
    state.RUNNING["dial"] = job
    if not bpy.app.timers.is_registered(_poll_full_size):
        bpy.app.timers.register(_poll_full_size, first_interval=POLL_SECONDS)
    return job


def _full_when_resting():
    context = bpy.context
    session = current_session(context)
    if session is None:
        return None
    running = state.RUNNING.get("dial")
    if running is not None and not running.finished:
        return POLL_SECONDS  # one full-size relight at a time: start when that one ends
    if session.provisional:
        return POLL_SECONDS  # reopening: the full photo is still being read
    try:
        dials = _dials(context, session)
    except ValueError as exc:
        _set_status(context, str(exc), is_error=True)
        return None
    start_full_size(session, dials)
    return None


def _poll_full_size():
    """Timer: wait for the full-size job, then write its images one per call (each
    foreach_set of a large image is a stretch of its own, so the UI draws between)."""
    job = state.RUNNING.get("dial")
    if job is None:
        return None
    job_state = job.poll()
    if job_state is jobs.JobState.RUNNING:
        return POLL_SECONDS
    if finish_full_size(bpy.context, job, one_layer=True):
        return 0.0  # more layers to write
    _release(job, "dial")
    return None


def finish_full_size(context, job, one_layer: bool = False) -> bool:
    """Write a finished full-size job's images unless a dial moved since it started;
    with `one_layer`, only the next one. True while layers are left to write."""
    session = job.session
    if job.poll() is jobs.JobState.FAILED:
        _set_status(context, str(engine.user_error(job.error)), is_error=True)
        return False
    if job.poll() is not jobs.JobState.DONE or state.SESSIONS.get(session.photo_id) is not session \
            or session.dial_generation != job.generation or bl_images.photo_by_id(session.photo_id) is None:
        return False
    session.source = bl_images.photo_by_id(session.photo_id).name
    buffers = job.result
    for layer in [layer for layer in LAYER_ORDER if layer in buffers]:
        _write_output(session, layer, buffers.pop(layer), session.photo.shape[:2])
        if layer == "relit":
            show_in_editors(session, "relit")
        if one_layer and buffers:
            return True
    _set_status(context, "")
    return False


def show_in_editors(session: state.PhotoSession, layer: str, windows=None) -> int:
    """Image Editors showing this photo's relit image or its preview switch to `layer`
    ("preview" while a dial moves, "relit" at rest); returns how many switched.

    Two datablocks, so the full-size image is never resized (Blender refills a
    resized 24 MP buffer, ~0.5 s); the zoom is scaled by the size ratio, so
    the picture keeps its size on screen.
    """
    target = bl_images.output_by_tag(session.photo_id, layer)
    other = bl_images.output_by_tag(session.photo_id, "relit" if layer == "preview" else "preview")
    if target is None or other is None:
        return 0
    switched = 0
    if windows is None:
        windows = getattr(bpy.context.window_manager, "windows", [])
    for window in windows:
        for area in window.screen.areas:
            space = area.spaces.active
            if area.type != "IMAGE_EDITOR" or space.image != other:
                continue
            zoom = space.zoom[0] * other.size[0] / max(1, target.size[0])
            space.image = target
            switched += 1
            region = next((r for r in area.regions if r.type == "WINDOW"), None)
            if region is None:
                continue
            try:  # display comfort only: a failure leaves Blender's own zoom
                with bpy.context.temp_override(window=window, area=area, region=region):
                    bpy.ops.image.view_zoom_ratio(ratio=zoom)
            except (RuntimeError, TypeError):
                pass
    return switched


# ------------------------------------------------------------------ World edits

_in_handler = False


@bpy.app.handlers.persistent
def on_depsgraph_update(scene, depsgraph) -> None:
    """A World edit that changes its light (mapping, sky, image) relights live."""
    global _in_handler
    if _in_handler or bl_world.baking():
        return  # bl_world.baking(): the updates our own bake scene causes
    if depsgraph.id_type_updated("IMAGE"):  # a photo renamed: its outputs follow at once
        _in_handler = True
        try:
            bl_images.sync_output_names()
        finally:
            _in_handler = False
    if not depsgraph.id_type_updated("WORLD"):
        return
    settings = getattr(scene, "relight_photo", None)
    if settings is None or settings.light_kind != "WORLD" or scene.world is None:
        return
    if current_session(bpy.context) is None:
        return
    if bl_world.fingerprint(scene.world) in state.WORLDS:
        return  # an update that does not change the light
    _in_handler = True
    try:
        schedule_refresh(bpy.context)
    finally:
        _in_handler = False


# ------------------------------------------------------------------ save and reopen

_SAVING: list = []  # [(thread, session, failures)] writing decomposition files after a save


def wait_for_saves(context=None) -> None:
    """Let the decomposition files being written finish (before a file is opened), and
    show a failure in the panel."""
    while _SAVING:
        thread, _session, failures = _SAVING.pop(0)
        thread.join()
        if failures and context is not None:
            _set_status(context, failures[0], is_error=True)


def _poll_saves():
    if any(thread.is_alive() for thread, _s, _f in _SAVING):
        return 0.2
    wait_for_saves(bpy.context)
    return None


@bpy.app.handlers.persistent
def on_save_post(*_args) -> None:
    """Keep each decomposition next to the .blend (`<name>_relight/<photo id>.npz`), so
    reopening the file restores the results without a network run.

    With a UI the files are written by threads (compressing takes ~0.4 s at 24 MP);
    they are not daemons, so quitting Blender waits for them, and opening a file
    waits for them first."""
    import threading

    blend = bpy.data.filepath
    if not blend:
        return
    for session in list(state.SESSIONS.values()):
        if bl_images.photo_by_id(session.photo_id) is None:
            continue
        path = pipeline.saved_relight_path(blend, session.photo_id)
        if session.provisional or (session.saved_to == path and os.path.isfile(path)):
            continue  # a provisional session's file is the one it came from
        meta = dict(photo_id=session.photo_id, digest=session.digest, model_path=session.model_path,
                    quality=session.quality, mask_key=list(session.mask_key), source=session.source,
                    lights=work.lights_to_save())
        session.saved_to = path
        failures: list = []
        if _updates_immediately():
            work.save_one(session, path, meta, failures)
            if failures:
                _set_status(bpy.context, failures[0], is_error=True)
            continue
        thread = threading.Thread(target=work.save_one, args=(session, path, meta, failures),
                                  name="relight-save", daemon=False)
        thread.start()
        _SAVING.append((thread, session, failures))
        if not bpy.app.timers.is_registered(_poll_saves):
            bpy.app.timers.register(_poll_saves, first_interval=0.2)


def _restore_plan(context, image, path: str) -> dict:
    arrays, meta = engine.load_decomposition_arrays(path)
    reader = bl_images.photo_reader(image)
    mode, mask_name = meta["mask_key"]
    inputs = dict(mode=mode, rgb=None, alpha=None, name=mask_name, use_photo_alpha=mode == "IMAGE_ALPHA",
                  person=int(mask_name) if mode == "AUTO" else 1)
    if mode == "IMAGE":
        mask_image = bpy.data.images.get(mask_name)
        if mask_image is None:
            raise ValueError(f"The mask image '{mask_name}' of '{image.name}' is gone: press Relight.")
        stored = bl_images.rgba_pixels(mask_image)
        inputs["rgb"] = stored[..., :3] if stored.shape[2] >= 3 else np.repeat(stored[..., :1], 3, axis=2)
        inputs["alpha"] = stored[..., 3] if stored.shape[2] == 4 else None
    for pid, model_path, quality_key, coeffs in meta.get("lights", []):
        state.LIGHT_SOURCES.setdefault((pid, model_path, quality_key), np.asarray(coeffs, np.float64))
    dials = _dials_for(context, int(meta["sh_order"]), meta["model_path"])
    return dict(arrays=arrays, meta=meta, reader=reader, mask=inputs, source=image.name, path=path,
                dials=dials)


def restore_saved(context) -> int:
    """Bring back every photo's saved decomposition and its outputs; returns how many.

    Without a UI this runs here; with one, the photos are re-read on a worker
    and the outputs written when it is done (a large photo's preview first).
    """
    blend = bpy.data.filepath
    if not blend:
        return 0
    plans = []
    for image in bpy.data.images:
        pid = bl_images.photo_id(image)
        if not pid or bl_images.owner_of(image):
            continue
        path = pipeline.saved_relight_path(blend, pid)
        if not os.path.isfile(path):
            continue
        try:
            plans.append(_restore_plan(context, image, path))
        except ValueError as exc:
            _set_status(context, str(exc), is_error=True)
    if not plans:
        return 0
    immediately = _updates_immediately()
    for plan in plans:
        plan["preview_first"] = not immediately
        if not immediately:
            _show_saved_preview(context, plan)
    if immediately:
        job = _start_restore(plans)
        job.wait()
        _finish_restore(context, job)
    else:
        # the worker starts on the first timer tick: starting a thread can wait for the
        # scheduler, a stretch better not added to this one
        state.RUNNING["restore_plans"] = plans
        bpy.app.timers.register(_poll_restore, first_interval=0.0)
    return len(plans)


def _start_restore(plans: list):
    job = jobs.BackgroundJob(lambda: [work.restore_work(p) for p in plans], label="restore")
    job.plans = plans
    state.RUNNING["restore"] = job
    return job


def _show_saved_preview(context, plan: dict) -> None:
    """Right after opening: the saved screen-sized photo relit into '<photo>.preview'
    and a provisional session on it, so the result shows and the dials work while
    the worker re-reads the full photo."""
    meta = plan["meta"]
    preview = engine.saved_preview(plan["arrays"], meta)
    if preview is None:
        return
    session = state.PhotoSession(
        photo_id=meta["photo_id"], source=plan["source"], photo=preview.photo, decomposition=preview,
        model_path=meta["model_path"], quality=meta["quality"], mask_key=tuple(meta["mask_key"]),
        digest=meta["digest"], preview=preview, saved_to=plan["path"], provisional=True)
    state.SESSIONS[session.photo_id] = session
    _write_output(session, "preview", engine.relit_rgba(preview, *plan["dials"]), preview.size)
    show_in_editors(session, "preview")
    settings = _settings(context)
    if settings.last_photo_id not in state.SESSIONS:
        settings.last_photo_id = session.photo_id


def _poll_restore():
    plans = state.RUNNING.pop("restore_plans", None)
    if plans is not None:
        _start_restore(plans)
        return POLL_SECONDS
    job = state.RUNNING.get("restore")
    if job is None:
        return None
    if job.poll() is jobs.JobState.RUNNING:
        return POLL_SECONDS
    _finish_restore(bpy.context, job)
    return None


def _finish_restore(context, job) -> None:
    state.RUNNING.pop("restore", None)
    if job.poll() is jobs.JobState.FAILED:
        _set_status(context, str(engine.user_error(job.error)), is_error=True)
        return
    if job.poll() is not jobs.JobState.DONE:
        return
    settings = _settings(context)
    for (session, buffers), plan in zip(job.result, job.plans):
        provisional = state.SESSIONS.get(session.photo_id)
        state.SESSIONS[session.photo_id] = session
        if "albedo" in buffers:
            for layer in LAYER_ORDER:
                if layer in buffers:
                    _write_output(session, layer, buffers[layer], session.photo.shape[:2])
            continue
        dials = plan["dials"]
        if provisional is not None and provisional.provisional:
            # the dials may have moved on the provisional preview: carry on from there
            # (the full-size layers below use the dials as they are now: no rest timer needed)
            session.dial_generation = provisional.dial_generation
            if bpy.app.timers.is_registered(_full_when_resting):
                bpy.app.timers.unregister(_full_when_resting)
            try:
                dials = _dials(context, session)
            except ValueError as exc:
                _set_status(context, str(exc), is_error=True)
                continue
        else:  # no saved preview: show the one just made, then every layer at full size
            _write_output(session, "preview", buffers["relit"], session.preview.size)
            show_in_editors(session, "preview")
        start_full_size(session, dials, with_layers=True)
    if settings.last_photo_id not in state.SESSIONS and job.result:
        settings.last_photo_id = job.result[0][0].photo_id


@bpy.app.handlers.persistent
def on_load(*_args) -> None:
    """A new .blend: forget the old file's photos, bring back this file's saved relights."""
    wait_for_saves(bpy.context)
    state.clear()
    try:
        restore_saved(bpy.context)
    except Exception as exc:  # a handler must never raise into Blender's file loading
        _set_status(bpy.context, f"Saved relights could not be restored ({exc}): press Relight.", is_error=True)


# ------------------------------------------------------------------ the Relight job

def start_layers(session: state.PhotoSession, dials):
    """The layers other than relit (albedo, shading, residual, alpha, matte) on a worker,
    after Relight has shown the relit image; _poll_layers writes them one per tick."""
    job = jobs.BackgroundJob(lambda: work.layer_buffers(session, dials, with_relit=False), label="layers")
    job.session = session
    previous = state.RUNNING.get("layers")
    if previous is not None:
        previous.cancel()
    state.RUNNING["layers"] = job
    if not bpy.app.timers.is_registered(_poll_layers):
        bpy.app.timers.register(_poll_layers, first_interval=POLL_SECONDS)
    return job


def _poll_layers():
    job = state.RUNNING.get("layers")
    if job is None:
        return None
    job_state = job.poll()
    if job_state is jobs.JobState.RUNNING:
        return POLL_SECONDS
    session = job.session
    if job_state is jobs.JobState.FAILED:
        _set_status(bpy.context, str(engine.user_error(job.error)), is_error=True)
    elif job_state is jobs.JobState.DONE and state.SESSIONS.get(session.photo_id) is session \
            and bl_images.photo_by_id(session.photo_id) is not None:
        buffers = job.result
        for layer in [layer for layer in LAYER_ORDER if layer in buffers]:
            _write_output(session, layer, buffers.pop(layer), session.photo.shape[:2])
            if buffers:
                return 0.0  # one image per call: the UI draws in between
    _release(job, "layers")
    return None


def _release(job, slot: str = "job") -> None:
    """Forget the running job, if it is still this one."""
    if job is not None and state.RUNNING.get(slot) is job:
        del state.RUNNING[slot]


# ------------------------------------------------------------------ operators

class RELIGHT_PHOTO_OT_relight(bpy.types.Operator):
    """Split the photo into albedo, light transport and light, then relight it with the chosen light"""

    bl_idname = "relight_photo.relight"
    bl_label = "Relight"
    bl_options = {"REGISTER", "UNDO"}  # undoing a run removes its output images

    image_name: StringProperty(name="Image", default="", options={"SKIP_SAVE"},
                               description="Photo to relight (default: the Image Editor's image)")
    synchronous: BoolProperty(name="Synchronous", default=False, options={"SKIP_SAVE", "HIDDEN"},
                              description="Run the network on the calling thread (tests, scripts)")

    _job = None
    _timer = None
    _plan = None
    _pending = None     # output layers still to hand to Blender, one per timer tick
    _result = None
    _started = 0.0

    # the plan gathers every input on the main thread before the worker starts
    def _make_plan(self, context) -> dict:
        settings = _settings(context)
        bl_images.sync_output_names()
        image = source_image(context, self.image_name)
        read_photo = bl_images.photo_reader(image)  # checks the photo has pixels and a usable size
        mask = _mask_inputs(settings, image)
        model_path = str(pipeline.model_path_for(settings.quality, bpy.path.abspath(settings.model_path)))
        order = engine.known_sh_order(model_path)
        # a shipped model opens on the worker; a custom one here, to learn its SH order
        relighter = engine.open_relighter(model_path) if order is None else None
        order = relighter.sh_order if relighter is not None else order
        long_side = quality.preset(settings.quality).working_size
        light = light_cached = light_reader = None
        light_key = _light_image_key(settings, model_path)
        rotation = math.degrees(settings.rotation)
        if settings.light_kind == "IMAGE":
            if settings.light_image is None:
                raise ValueError("Choose the photo to take the light from.")
            light_cached = state.LIGHT_SOURCES.get(light_key)
            if light_cached is None:
                light_reader = bl_images.photo_reader(settings.light_image)
        elif settings.light_kind in ("PRESET", "HDR"):
            # a name or a path: checked (and projected) by the worker, before the network runs
            light = ("PRESET", settings.preset) if settings.light_kind == "PRESET" else \
                ("HDR", bpy.path.abspath(settings.hdr_path) if settings.hdr_path else "")
            if light[0] == "PRESET" and light[1] == "NONE":
                raise ValueError("No light preset is installed.")
        else:
            # the World needs bpy: read here, before any time goes into the network
            light, extra = target_light(context, order, model_path)
            rotation += extra
        return dict(photo_id=bl_images.photo_id(image, create=True), source=image.name, read_photo=read_photo,
                    mask=mask, model_path=model_path, relighter=relighter, long_side=long_side,
                    quality=settings.quality, light=light, light_cached=light_cached, light_reader=light_reader,
                    light_key=light_key, rotation=rotation, exposure=settings.exposure,
                    strength=settings.strength, dials_at_start=self._dial_values(settings))

    @staticmethod
    def _dial_values(settings) -> tuple:
        return (settings.light_kind, settings.preset, settings.hdr_path, settings.rotation, settings.exposure,
                settings.strength, settings.light_image.name if settings.light_image else "")

    def _start(self, context, layers_later: bool = False):
        if "job" in state.RUNNING:
            raise ValueError("A relight is already running; press Esc to cancel it first.")
        self._started = time.monotonic()
        self._plan = self._make_plan(context)
        self._plan["layers_later"] = layers_later
        plan = self._plan
        token, progress = engine.CancelToken(), jobs.Progress()
        # the thread gets plain data only: never the operator, which Blender may free
        self._job = jobs.BackgroundJob(lambda: work.relight_work(plan, progress, token), label="relight",
                                       cancel_token=token, progress=progress)
        state.RUNNING["job"] = self._job

    def _install(self, context, result: dict) -> None:
        """The worker is done: keep its session; its images are written next."""
        plan = self._plan
        session = result["session"]
        if result["light_decomposition"] is not None:
            state.LIGHT_SOURCES[plan["light_key"]] = result["light_decomposition"]
        photo = bl_images.photo_by_id(session.photo_id)
        if photo is None:
            raise ValueError(f"The photo '{session.source}' was deleted while it was being relit.")
        session.source = photo.name
        state.SESSIONS[session.photo_id] = session
        settings = _settings(context)
        settings.last_photo_id = session.photo_id
        if session.people:
            settings.people_found = session.people
        self._result = result
        self._pending = [layer for layer in LAYER_ORDER if layer in result["buffers"]]

    def _write_next(self, context) -> None:
        session = self._result["session"]
        layer = self._pending.pop(0)
        image = _write_output(session, layer, self._result["buffers"].pop(layer), session.photo.shape[:2])
        if layer == "matte":
            image.alpha_mode = "STRAIGHT"  # shown as a cut-out over Blender's checkerboard
        if layer == "relit":
            space = getattr(context, "space_data", None)
            if space is not None and getattr(space, "type", "") == "IMAGE_EDITOR":
                space.image = image

    def _done(self, context) -> set:
        session = self._result["session"]
        wall = time.monotonic() - self._started
        message = (f"Relit '{session.source}' in {wall:.1f} s "
                   f"(network {self._result['network_seconds']:.1f} s).")
        if self._plan.get("layers_later"):
            start_layers(session, self._result["dials"])
            message = message[:-1] + "; the other layers follow."
        _set_status(context, message)
        self.report({"INFO"}, message)
        if self._dial_values(_settings(context)) != self._plan["dials_at_start"]:
            schedule_refresh(context)  # a dial moved while the network ran
        self._result = None
        return {"FINISHED"}

    def _error(self, context, exc: BaseException) -> set:
        if isinstance(exc, engine.Cancelled):
            self.report({"WARNING"}, "Relighting cancelled.")
            _set_status(context, "Relighting cancelled.")
            return {"CANCELLED"}
        message = str(exc) if isinstance(exc, ValueError) else str(engine.user_error(exc))
        self.report({"ERROR"}, message)
        _set_status(context, message, is_error=True)
        return {"CANCELLED"}

    def execute(self, context):
        # synchronous path: tests, scripts and background mode
        try:
            self._start(context)
            job_state = self._job.wait()
            if job_state is jobs.JobState.FAILED:
                raise engine.user_error(self._job.error) \
                    if not isinstance(self._job.error, engine.Cancelled) else self._job.error
            self._install(context, self._job.result)
            while self._pending:
                self._write_next(context)
        except (ValueError, engine.Cancelled) as exc:
            return self._error(context, exc)
        finally:
            _release(self._job)
        return self._done(context)

    def invoke(self, context, event):
        if self.synchronous or pipeline.env_flag(SYNC_ENV) or bpy.app.background or context.window is None:
            return self.execute(context)
        try:
            self._start(context, layers_later=True)
        except ValueError as exc:
            return self._error(context, exc)
        wm = context.window_manager
        self._timer = wm.event_timer_add(POLL_SECONDS, window=context.window)
        wm.modal_handler_add(self)
        wm.progress_begin(0, 100)
        _status(context).running = True
        return {"RUNNING_MODAL"}

    def _cleanup(self, context) -> None:
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        status = _status(context)
        status.running, status.stage, status.progress = False, "", 0.0
        _release(self._job)

    def _show_progress(self, context) -> None:
        progress = self._job.progress
        elapsed = time.monotonic() - self._started
        fraction = progress.fraction
        if progress.stage.startswith("Running the network") and self._plan:
            expected = engine.expected_seconds(self._plan["model_path"], self._plan["long_side"])
            if expected:  # inside the network stage, interpolate by the last run's time
                share = min(1.0, (time.monotonic() - progress.stage_started) / expected)
                fraction += share * (0.45 if self._plan["light_reader"] is None else 0.30)
        status = _status(context)
        status.stage, status.progress, status.elapsed = progress.stage, min(fraction, 0.99), elapsed
        context.window_manager.progress_update(int(100 * status.progress))
        if context.workspace is not None:
            context.workspace.status_text_set(
                f"Relight Photo: {progress.stage.lower()} ({elapsed:.1f} s), Esc to cancel")

    def modal(self, context, event):
        if event.type == "ESC":
            self._job.cancel()
            self._cleanup(context)
            return self._error(context, engine.Cancelled())
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._result is not None:
            try:
                self._write_next(context)  # one image per tick: the UI stays responsive
            except ValueError as exc:
                self._cleanup(context)
                return self._error(context, exc)
            if self._pending:
                return {"PASS_THROUGH"}
            self._cleanup(context)
            return self._done(context)
        job_state = self._job.poll()
        if job_state is jobs.JobState.RUNNING:
            self._show_progress(context)
            return {"PASS_THROUGH"}
        if job_state is jobs.JobState.FAILED:
            self._cleanup(context)
            error = self._job.error
            return self._error(context, error if isinstance(error, engine.Cancelled) else engine.user_error(error))
        try:
            self._install(context, self._job.result)
        except ValueError as exc:
            self._cleanup(context)
            return self._error(context, exc)
        _status(context).stage = "Writing the images"
        return {"PASS_THROUGH"}


class RELIGHT_PHOTO_OT_save_layers(bpy.types.Operator):
    """Save the relit photo and its layers (albedo, shading, residual, alpha) as one multi-layer EXR"""

    bl_idname = "relight_photo.save_layers"
    bl_label = "Save Layers"
    bl_options = {"REGISTER"}

    filepath: StringProperty(subtype="FILE_PATH", options={"SKIP_SAVE"})
    filter_glob: StringProperty(default="*.exr", options={"HIDDEN"})
    check_existing: BoolProperty(default=True, options={"HIDDEN"})  # the file browser warns on overwrite
    image_name: StringProperty(name="Image", default="", options={"SKIP_SAVE"})

    def _session(self, context):
        if self.image_name or _editor_image(context) is not None:
            session = session_of(source_image(context, self.image_name))
        else:
            session = current_session(context)
        if session is None:
            raise ValueError("Relight the photo first: there are no layers to save yet.")
        if session.provisional:
            raise ValueError("The photo is still being read after opening the file: save the layers in a moment.")
        return session

    def invoke(self, context, event):
        try:
            session = self._session(context)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        if not self.filepath:
            self.filepath = bpy.path.ensure_ext(bpy.path.clean_name(session.source) + "_layers", ".exr")
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def execute(self, context):
        try:
            session = self._session(context)
            if not self.filepath:
                raise ValueError("Choose a file to save the layers to.")
            path = bpy.path.abspath(bpy.path.ensure_ext(self.filepath, ".exr"))
            dials = _dials(context, session)
            relit = compute_relit(context, session, dials)
            engine.save_layers(path, relit, engine.layers(session.decomposition, *dials[:3]))
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            return {"CANCELLED"}
        except OSError as exc:
            self.report({"ERROR"}, f"Cannot write '{self.filepath}': {exc.strerror or exc}.")
            return {"CANCELLED"}
        self.report({"INFO"}, f"Saved the layers of '{session.source}' to {path}.")
        return {"FINISHED"}


CLASSES = (RELIGHT_PHOTO_OT_relight, RELIGHT_PHOTO_OT_save_layers)


_HANDLERS = ((bpy.app.handlers.depsgraph_update_post, on_depsgraph_update),
             (bpy.app.handlers.load_post, on_load),
             (bpy.app.handlers.save_post, on_save_post))
_TIMERS = (_deferred_refresh, _full_when_resting, _poll_full_size, _poll_restore, _poll_saves, _poll_layers)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for handlers, fn in _HANDLERS:
        if fn not in handlers:
            handlers.append(fn)


def unregister() -> None:
    wait_for_saves()
    for timer in _TIMERS:
        if bpy.app.timers.is_registered(timer):
            bpy.app.timers.unregister(timer)
    for handlers, fn in _HANDLERS:
        while fn in handlers:
            handlers.remove(fn)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
