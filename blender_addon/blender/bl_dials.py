"""The dials: relight from the cached decomposition when a dial or the World moves;
a screen-sized preview while a dial moves, the full-size image on a worker once it rests."""

import bpy

from . import bl_images, bl_session, bl_world
from ..worker import engine, jobs, state
from ..logic import output_names, pixel_buffers
from .bl_light import current_dials
from .bl_session import POLL_SECONDS, current_session, release_job, set_status, write_output

REST_SECONDS = 0.3                # a dial untouched this long is at rest: the full-size relight starts


def missing_photo_notice(session: state.PhotoSession) -> str:
    """The lasting panel notice of a session reopened without its photo ('' otherwise)."""
    return state.NOTICES.get(session.photo_id, "") if session.photo_missing else ""


def compute_relit(context, session: state.PhotoSession, dials=None):
    """Linear RGB [H, W, 3] of the cached decomposition relit with the current dials."""
    light, rotation, exposure, strength = dials or current_dials(context, session)
    relit = engine.relight(session.decomposition, light, rotation, exposure)
    return pixel_buffers.blend(relit, session.photo, strength)


def render_relit(context, session: state.PhotoSession, dials=None):
    """Relight the cached decomposition with the current dials and write '<photo>.relit' (this thread)."""
    dials = dials or current_dials(context, session)
    rgba = engine.relit_rgba(session.decomposition, *dials, orientation=session.orientation)
    return write_output(session, "relit", rgba, session.photo.shape[:2])


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
        dials = current_dials(context, session)
        if preview and session.preview is not None and not session.photo_missing:
            rgba = engine.relit_rgba(session.preview, *dials, orientation=session.orientation)
            write_output(session, "preview", rgba, session.preview.size)
            show_in_editors(session, "preview")
            set_status(context, "Preview: the full-size image follows when the dial rests.")
            _arm_full_size()
        else:
            render_relit(context, session, dials)
            # reopened without its photo: the notice stays while the dials work on the saved preview
            set_status(context, missing_photo_notice(session), is_error=bool(session.photo_missing))
    except ValueError as exc:
        set_status(context, str(exc), is_error=True)


def deferred_refresh():
    refresh_relit(bpy.context, preview=True)
    return None  # run once


def schedule_refresh(context) -> None:
    """A dial moved: relight now without a UI, else once the UI is idle.

    Dragging a slider sends an update per mouse move; deferring to a timer
    coalesces them, so a drag stays smooth.
    """
    if bl_session.updates_immediately():
        refresh_relit(context)
    elif not bpy.app.timers.is_registered(deferred_refresh):
        bpy.app.timers.register(deferred_refresh, first_interval=0.0)


def _arm_full_size() -> None:
    """(Re)start the rest timer: the full-size relight waits until the dial stops moving."""
    if bpy.app.timers.is_registered(full_when_resting):
        bpy.app.timers.unregister(full_when_resting)
    bpy.app.timers.register(full_when_resting, first_interval=REST_SECONDS)


def start_full_size(session: state.PhotoSession, dials):
    """Relight the full-size photo on a worker; poll_full_size writes it if no dial moved since."""
    generation = session.dial_generation
    job = jobs.BackgroundJob(lambda: {"relit": engine.relit_rgba(session.decomposition, *dials,
                                                                 orientation=session.orientation)},
                             label="full-size")
    job.session, job.generation = session, generation
    state.RUNNING["dial"] = job
    if not bpy.app.timers.is_registered(poll_full_size):
        bpy.app.timers.register(poll_full_size, first_interval=POLL_SECONDS)
    return job


def full_when_resting():
    context = bpy.context
    session = current_session(context)
    if session is None:
        return None
    running = state.RUNNING.get("dial")
    if running is not None and not running.finished:
        return POLL_SECONDS  # one full-size relight at a time: start when that one ends
    if session.provisional:  # reopening: the full photo is still being read, or is gone
        return None if session.photo_missing else POLL_SECONDS
    try:
        dials = current_dials(context, session)
    except ValueError as exc:
        set_status(context, str(exc), is_error=True)
        return None
    start_full_size(session, dials)
    return None


def poll_full_size():
    """Timer: wait for the full-size job, then write its images one per call (each
    foreach_set of a large image is a stretch of its own, so the UI draws between)."""
    job, wait = jobs.finished_job(state.RUNNING, "dial", POLL_SECONDS)
    if job is None:
        return wait
    if finish_full_size(bpy.context, job, one_layer=True):
        return 0.0  # more layers to write
    release_job(job, "dial")
    return None


def finish_full_size(context, job, one_layer: bool = False) -> bool:
    """Write a finished full-size job's images unless a dial moved since it started;
    with `one_layer`, only the next one. True while layers are left to write."""
    session = job.session
    if job.poll() is jobs.JobState.FAILED:
        set_status(context, str(engine.user_error(job.error)), is_error=True)
        return False
    if job.poll() is not jobs.JobState.DONE or state.SESSIONS.get(session.photo_id) is not session \
            or session.dial_generation != job.generation or bl_images.photo_by_id(session.photo_id) is None:
        return False
    session.source = bl_images.photo_by_id(session.photo_id).name
    buffers = job.result
    for layer in output_names.layers_in_order(buffers):
        write_output(session, layer, buffers.pop(layer), session.photo.shape[:2])
        if layer == "relit":
            show_in_editors(session, "relit")
        if one_layer and buffers:
            return True
    set_status(context, "")
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


# ------------------------------------------------------------------ renames

_RENAMES = object()  # the message bus owner of the rename subscription (Blender keeps its address: never freed)


def on_image_renamed(*_args) -> None:
    """An image's name was set: a relit photo's outputs take its new name at once."""
    bl_images.sync_output_names()


def follow_renames() -> None:
    """Subscribe on_image_renamed to every image's name on Blender's message bus. Blender 5 also
    sends a depsgraph update for a rename (on_depsgraph_update), Blender 4.2 none: its outputs
    were renamed only at the next dial. A file load clears the subscriptions: made again then."""
    bpy.msgbus.clear_by_owner(_RENAMES)
    bpy.msgbus.subscribe_rna(key=(bpy.types.Image, "name"), owner=_RENAMES, args=(), notify=on_image_renamed)


@bpy.app.handlers.persistent
def on_load_follow_renames(*_args) -> None:
    follow_renames()


def stop_following_renames() -> None:
    bpy.msgbus.clear_by_owner(_RENAMES)


# ------------------------------------------------------------------ World edits

_in_handler = False


@bpy.app.handlers.persistent
def on_depsgraph_update(scene, depsgraph) -> None:
    """A World edit that changes its light (mapping, sky, image), or a lamp moved, changed, added or
    removed (bl_world.lamps_changed), relights live."""
    global _in_handler
    if _in_handler or bl_world.baking():
        return  # bl_world.baking(): the updates our own bake scene causes
    if depsgraph.id_type_updated("IMAGE"):  # a photo renamed: its outputs follow at once
        _in_handler = True
        try:
            bl_images.sync_output_names()
        finally:
            _in_handler = False
    settings = getattr(scene, "relight_photo", None)
    lamps_moved = settings is not None and settings.light_kind == "WORLD" and bl_world.lamps_changed(scene, depsgraph)
    if not depsgraph.id_type_updated("WORLD") and not lamps_moved:
        return
    if settings is None or settings.light_kind != "WORLD" or (scene.world is None and not lamps_moved):
        return
    if current_session(bpy.context) is None:
        return
    if not lamps_moved and bl_world.fingerprint(scene.world) in state.WORLDS:
        return  # an update that does not change the light
    _in_handler = True
    try:
        schedule_refresh(bpy.context)
    finally:
        _in_handler = False
