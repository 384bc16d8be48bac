"""A photo's output layers made and handed to Blender one at a time.

At 24 MP each layer is a 288 MB map, a 384 MB buffer in Blender's layout and
a 384 MB Blender image: making them all before writing any held every buffer
at once (issue 24: a Relight peaked at 3.4 GB, a restore at 4.4). Here a
worker makes one layer, the main thread writes it (the buffer goes back to the
pool), and only then is the next one made. Without a UI the same happens on
the calling thread.
"""

import bpy

from . import bl_images
from ..worker import engine, jobs, state, work
from .bl_dials import show_in_editors
from .bl_light import current_dials
from .bl_session import (POLL_SECONDS, addon_settings, current_session, make_output, release_job, set_status,
                         updates_immediately, write_output)


def _queue() -> list:
    """(session, dials, layer names) waiting for the running chain to end; kept in state.RUNNING,
    so opening another file (state.clear) forgets it."""
    return state.RUNNING.setdefault("layers_queue", [])


def write_layers_now(session: state.PhotoSession, dials, with_relit: bool = False) -> None:
    """Without a UI: each layer made and written in turn, on this thread."""
    cancel_layers(session.photo_id)
    for layer in work.layer_names(session, with_relit):
        write_output(session, layer, work.layer_buffer(session, layer, dials), work.layer_size(session, layer))


def start_layers(session: state.PhotoSession, dials, with_relit: bool = False) -> None:
    """The layers (the relit image too with `with_relit`) on a worker, one after another;
    poll_layers writes each as it comes. A chain already running for this photo is dropped."""
    cancel_layers(session.photo_id)
    names = work.layer_names(session, with_relit)
    if names:
        _queue().append((session, dials, names))
    if "layers" not in state.RUNNING:
        _start_next()
    if not bpy.app.timers.is_registered(poll_layers):
        bpy.app.timers.register(poll_layers, first_interval=POLL_SECONDS)


def cancel_layers(photo_id: str) -> None:
    """Forget the layers still to come for this photo (a newer Relight or restore replaces them)."""
    _queue()[:] = [entry for entry in _queue() if entry[0].photo_id != photo_id]
    job = state.RUNNING.get("layers")
    if job is not None and job.session.photo_id == photo_id:
        job.cancel()
        del state.RUNNING["layers"]
        if getattr(job, "made", False) and bl_images.photo_by_id(photo_id) is not None:
            bl_images.remove_unwritten(photo_id)


def _start_next() -> None:
    queue = _queue()
    while queue:
        session, dials, names = queue.pop(0)
        if _current(session):
            state.RUNNING["layers"] = _layer_job(session, dials, names)
            return


def _layer_job(session: state.PhotoSession, dials, names: list):
    layer = names[0]
    job = jobs.BackgroundJob(lambda: work.layer_buffer(session, layer, dials), label=f"layer-{layer}")
    job.session, job.dials, job.layer, job.rest = session, dials, layer, names[1:]
    job.generation = session.dial_generation  # a relit image made before a dial moved is not shown
    return job


def _current(session: state.PhotoSession) -> bool:
    return state.SESSIONS.get(session.photo_id) is session and bl_images.photo_by_id(session.photo_id) is not None


def poll_layers():
    """Timer: write the finished layer, start the next (one image per call: the UI draws between)."""
    job, wait = jobs.finished_job(state.RUNNING, "layers", POLL_SECONDS)
    if job is None:
        if wait is None:
            _start_next()
            return POLL_SECONDS if "layers" in state.RUNNING else None
        return wait
    session = job.session
    job_state = job.poll()
    writes = job_state is jobs.JobState.DONE and _current(session) and \
        (job.layer != "relit" or job.generation == session.dial_generation)
    if writes and not getattr(job, "made", False) and make_output(session, job.layer,
                                                                   work.layer_size(session, job.layer)):
        job.made = True  # Blender allocated the image at this call: its pixels at the next
        return POLL_SECONDS
    release_job(job, "layers")
    if job_state is jobs.JobState.FAILED:
        set_status(bpy.context, str(engine.user_error(job.error)), is_error=True)
    elif job_state is jobs.JobState.DONE and _current(session):
        if writes:
            write_output(session, job.layer, job.result, work.layer_size(session, job.layer))
            if job.layer == "relit":
                show_in_editors(session, "relit")
        elif getattr(job, "made", False):
            bl_images.remove_unwritten(session.photo_id)
        if job.rest:
            state.RUNNING["layers"] = _layer_job(session, job.dials, job.rest)
            return POLL_SECONDS
    _start_next()
    return POLL_SECONDS if "layers" in state.RUNNING else None


@bpy.app.handlers.persistent
def on_undo_redo(*_args) -> None:
    """Undo and redo bring back the settings, not the outputs' pixels: Blender keeps no image
    buffers in its undo steps (an output it reads back comes back black, the others keep what
    they showed last). Every output of the photo the panel drives is made again from its
    decomposition under the settings the step brought back, as a dial change would."""
    context = bpy.context
    session = current_session(context)
    if session is None or (session.provisional and not session.photo_missing):
        return  # nothing relit, or a reopened file's photo still being read: the restore writes them
    session.dial_generation += 1  # a full-size relight of the dials before the step is dropped
    try:
        dials = current_dials(context, session)
    except ValueError as exc:
        set_status(context, str(exc), is_error=True)
        return
    settings = addon_settings(context)
    if settings.quality != session.quality:
        set_status(context, f"The layers are those of the last Relight ({session.quality.title()} quality): "
                            f"press Relight to run the network at {settings.quality.title()}.")
    if session.photo_missing or updates_immediately():  # (a missing photo's layers are screen-sized)
        cancel_layers(session.photo_id)
        for layer in work.layer_names(session, with_relit=True):
            write_output(session, layer, work.layer_buffer(session, layer, dials), work.layer_size(session, layer))
    else:
        start_layers(session, dials, with_relit=True)  # on a worker, one image per timer call
