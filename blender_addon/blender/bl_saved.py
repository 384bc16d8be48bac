"""Save and reopen: each photo's decomposition is kept next to the .blend on save and
brought back (its screen-sized preview first) when the file is opened."""

import os
import threading

import bpy

from . import bl_dials, bl_images, bl_layers, bl_session
from ..worker import engine, jobs, state, work
from ..logic import mask_choice, output_names, pixel_buffers
from .bl_dials import show_in_editors
from .bl_light import current_dials, dials_for
from .bl_session import POLL_SECONDS, addon_settings, set_notice, set_status, write_output

SAVING: list = []  # [(thread, session, failures)] writing decomposition files after a save


def wait_for_saves(context=None) -> None:
    """Let the decomposition files being written finish (before a file is opened), and
    show in the panel every photo whose file was not written, in one sentence."""
    failed = []
    while SAVING:
        thread, _session, failures = SAVING.pop(0)
        thread.join()
        failed += failures
    if failed and context is not None:
        set_status(context, work.save_failures_message(failed), is_error=True)


def poll_saves():
    if any(thread.is_alive() for thread, _s, _f in SAVING):
        return 0.2
    wait_for_saves(bpy.context)
    return None


@bpy.app.handlers.persistent
def on_save_post(filepath="", *_args) -> None:
    """Keep each decomposition next to the .blend (`<name>_relight/<photo id>.npz`), so
    reopening the file restores the results without a network run.

    `filepath` is the file Blender wrote: File > Save Copy writes another file than
    bpy.data.filepath, and its copy gets decompositions of its own. With a UI the
    files are written by threads (compressing takes ~0.4 s at 24 MP); they are not
    daemons, so quitting Blender waits for them, and opening a file waits for them first."""
    blend = filepath if isinstance(filepath, str) and filepath else bpy.data.filepath
    if not blend:
        return
    copy = os.path.abspath(blend) != os.path.abspath(bpy.data.filepath or blend)
    failures: list = []  # (photo, reason) of the files written here and now
    for session in list(state.SESSIONS.values()):
        if bl_images.photo_by_id(session.photo_id) is None:
            continue
        path = output_names.saved_relight_path(blend, session.photo_id)
        if session.provisional:
            if session.saved_to and os.path.abspath(session.saved_to) != os.path.abspath(path):
                _copy_saved(session.saved_to, path)  # a reopened preview: its file goes along
            continue
        if session.saved_to == path and os.path.isfile(path):
            continue
        meta = work.save_meta(session)
        if not copy:
            session.saved_to = path
        if bl_session.updates_immediately():
            work.save_one(session, path, meta, failures)
            continue
        own: list = []
        thread = threading.Thread(target=work.save_one, args=(session, path, meta, own),
                                  name="relight-save", daemon=False)
        thread.start()
        SAVING.append((thread, session, own))
        if not bpy.app.timers.is_registered(poll_saves):
            bpy.app.timers.register(poll_saves, first_interval=0.2)
    if failures:
        set_status(bpy.context, work.save_failures_message(failures), is_error=True)


def _copy_saved(source: str, target: str) -> None:
    """A saved decomposition copied beside another .blend (Save As / Save Copy of a file
    whose photo was not read again), atomically."""
    from relight.files.fileio import atomic_path

    try:
        os.makedirs(os.path.dirname(target), exist_ok=True)
        with open(source, "rb") as src, atomic_path(target, ".npz") as tmp:
            with open(tmp, "wb") as dst:
                dst.write(src.read())
    except OSError as exc:
        set_status(bpy.context, f"The saved relight could not be copied next to the .blend "
                                f"({exc.strerror or exc}): it will need Relight after reopening.", is_error=True)


def _restore_plan(context, image, path: str) -> dict:
    arrays, meta = engine.load_decomposition_arrays(path)
    missing = bl_images.file_missing(image)
    reader = None
    if not missing:
        try:
            reader = bl_images.photo_reader(image, max_megapixels=addon_settings(context).max_megapixels)
        except ValueError as exc:
            missing = str(exc)
    inputs = mask_choice.saved_mask_inputs(meta["mask_key"])
    if inputs["mode"] == "IMAGE":
        mask_name = inputs["name"]
        mask_image = bpy.data.images.get(mask_name)
        if mask_image is None:
            raise ValueError(f"The mask image '{mask_name}' of '{image.name}' is gone: press Relight.")
        inputs["rgb"], inputs["alpha"] = mask_choice.mask_channels(bl_images.rgba_pixels(mask_image))
    work.restore_lights(meta.get("lights", []))
    dials = dials_for(context, int(meta["sh_order"]), meta["model_path"])
    return dict(arrays=arrays, meta=meta, reader=reader, mask=inputs, source=image.name, path=path,
                dials=dials, missing=missing)


def restore_saved(context) -> int:
    """Bring back every photo's saved decomposition and its outputs; returns how many.

    Without a UI this runs here; with one, the photos are re-read on a worker
    and the outputs written when it is done (a large photo's preview first).
    A photo that cannot be read gets its result from the saved decomposition
    alone; a photo with nothing to restore from loses its outputs (Blender kept
    their names, not their pixels). Either way the panel says so, lastingly.
    """
    blend = bpy.data.filepath
    if not blend:
        return 0
    plans = []
    for image_name in [image.name for image in bpy.data.images]:
        image = bpy.data.images.get(image_name)  # None: an output removed by _drop_outputs below
        if image is None:
            continue
        pid = bl_images.photo_id(image)
        if not pid or bl_images.owner_of(image):
            continue
        path = output_names.saved_relight_path(blend, pid)
        try:
            if not os.path.isfile(path):
                raise ValueError(f"The saved relight of '{image.name}' is not next to this .blend "
                                 f"({os.path.basename(os.path.dirname(path))}/ was not moved with it): press Relight.")
            plan = _restore_plan(context, image, path)
        except ValueError as exc:
            if _drop_outputs(pid):  # only a photo that had results needs saying
                set_notice(context, pid, str(exc))
            continue
        if plan["missing"]:
            _restore_from_saved(context, plan, plan["missing"])
        else:
            plans.append(plan)
    if not plans:
        return 0
    immediately = bl_session.updates_immediately()
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
        bpy.app.timers.register(poll_restore, first_interval=0.0)
    return len(plans)


def _drop_outputs(pid: str) -> int:
    """Remove a photo's output images that cannot be filled again (Blender keeps their
    names, not their pixels): black images must not pose as results. Returns how many."""
    bl_layers.cancel_layers(pid)
    outputs = [image for image in bpy.data.images if bl_images.owner_of(image) == pid]
    for image in outputs:
        bpy.data.images.remove(image)
    return len(outputs)


FIND_THE_PHOTO = "point the image at the photo again (Image > Replace) and press Relight."
RELIGHT_THE_NEW_PHOTO = "press Relight to relight the photo as it is now."


def _restore_from_saved(context, plan: dict, reason: str, changed: bool = False) -> None:
    """The photo cannot be read (moved, deleted, not an image) or is not the one relit: the saved
    decomposition alone gives every output at the saved preview's size (a small photo's own), the
    dials keep working on it, and the panel says why and what brings the full size back."""
    pid = plan["meta"]["photo_id"]
    preview = engine.saved_preview(plan["arrays"], plan["meta"])
    if preview is None:  # saved by an add-on that kept no preview of small photos
        _drop_outputs(pid)
        set_notice(context, pid, f"{reason} Its saved relight has no copy of the photo: "
                                 "point the image at the photo again (Image > Replace) and press Relight.")
        return
    session, dials = state.SESSIONS.get(pid), plan["dials"]
    if session is not None and session.provisional:  # shown while the photo was read: the dials may have moved
        try:
            dials = current_dials(context, session)
        except ValueError:
            pass
    else:
        session = _show_saved_preview(context, plan)
    session.photo_missing = reason
    session.advice = RELIGHT_THE_NEW_PHOTO if changed else FIND_THE_PHOTO
    buffers = work.layer_buffers(session, dials)  # screen-sized: all at once is small
    for layer in output_names.layers_in_order(buffers):
        write_output(session, layer, buffers[layer], work.layer_size(session, layer))
    height, width = pixel_buffers.stored_size(session.photo.shape[:2], session.orientation)
    if changed:
        set_notice(context, pid, f"{reason} The saved relight of the photo as it was is shown at {width} x "
                                 f"{height} and the dials work; {session.advice}")
    else:
        set_notice(context, pid, f"{reason} The saved relight is shown at {width} x {height} and the dials work; "
                                 f"for full size or Save Layers, {session.advice}")


def _start_restore(plans: list):
    job = jobs.BackgroundJob(lambda: work.restore_all(plans), label="restore")
    job.plans = plans
    state.RUNNING["restore"] = job
    return job


def _show_saved_preview(context, plan: dict):
    """Right after opening: the saved screen-sized photo relit into '<photo>.preview'
    and a provisional session on it, so the result shows and the dials work while
    the worker re-reads the full photo."""
    meta = plan["meta"]
    preview = engine.saved_preview(plan["arrays"], meta)
    if preview is None:
        return None
    session = state.PhotoSession(
        photo_id=meta["photo_id"], source=plan["source"], photo=preview.photo, decomposition=preview,
        model_path=meta["model_path"], quality=meta["quality"], mask_key=tuple(meta["mask_key"]),
        digest=meta["digest"], preview=preview, saved_to=plan["path"], provisional=True,
        orientation=int(meta.get("orientation", 1)))
    state.SESSIONS[session.photo_id] = session
    write_output(session, "preview", engine.relit_rgba(preview, *plan["dials"], orientation=session.orientation),
                 preview.size)
    show_in_editors(session, "preview")
    settings = addon_settings(context)
    if settings.last_photo_id not in state.SESSIONS:
        settings.last_photo_id = session.photo_id
    return session


def poll_restore():
    plans = state.RUNNING.pop("restore_plans", None)
    if plans is not None:
        _start_restore(plans)
        return POLL_SECONDS
    job, wait = jobs.finished_job(state.RUNNING, "restore", POLL_SECONDS)
    if job is None:
        return wait
    _finish_restore(bpy.context, job)
    return None


def _finish_restore(context, job) -> None:
    state.RUNNING.pop("restore", None)
    if job.poll() is jobs.JobState.FAILED:  # restore_all reports per photo: this is a bug's way out
        for plan in job.plans:
            _restore_from_saved(context, plan, str(engine.user_error(job.error)))
        return
    if job.poll() is not jobs.JobState.DONE:
        return
    settings = addon_settings(context)
    for outcome, plan in zip(job.result, job.plans):
        if isinstance(outcome, Exception):
            _restore_from_saved(context, plan, str(outcome), changed=isinstance(outcome, work.PhotoChanged))
            continue
        session, buffers = outcome
        provisional = state.SESSIONS.get(session.photo_id)
        state.SESSIONS[session.photo_id] = session
        state.NOTICES.pop(session.photo_id, None)
        dials = plan["dials"]
        if not plan["preview_first"]:  # no UI: every layer at full size, here and now
            write_output(session, "relit", buffers["relit"], session.photo.shape[:2])
            bl_layers.write_layers_now(session, dials)
            continue
        if provisional is not None and provisional.provisional:
            # the dials may have moved on the provisional preview: carry on from there
            # (the full-size layers below use the dials as they are now: no rest timer needed)
            session.dial_generation = provisional.dial_generation
            if bpy.app.timers.is_registered(bl_dials.full_when_resting):
                bpy.app.timers.unregister(bl_dials.full_when_resting)
            try:
                dials = current_dials(context, session)
            except ValueError as exc:
                set_status(context, str(exc), is_error=True)
                continue
        elif "preview" in buffers:  # no saved preview: show the one just made
            write_output(session, "preview", buffers["preview"], session.preview.size)
            show_in_editors(session, "preview")
        # the relit image at full size, then the other layers, one at a time (bl_layers)
        bl_layers.start_layers(session, dials, with_relit=True)
    if settings.last_photo_id not in state.SESSIONS and job.result:
        first = next((outcome for outcome in job.result if not isinstance(outcome, Exception)), None)
        if first is not None:
            settings.last_photo_id = first[0].photo_id


@bpy.app.handlers.persistent
def on_load(*_args) -> None:
    """A new .blend: forget the old file's photos, bring back this file's saved relights."""
    wait_for_saves(bpy.context)
    state.clear()
    try:
        restore_saved(bpy.context)
    except Exception as exc:  # a handler must never raise into Blender's file loading
        set_status(bpy.context, f"Saved relights could not be restored ({exc}): press Relight.", is_error=True)
