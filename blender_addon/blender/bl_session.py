"""What every part of the add-on asks of Blender's context: the settings, the status
line, the photo in the editor and its session, handing an output buffer to Blender, and
what the operators that run a job on a worker thread share (WorkerOperator)."""

import time

import bpy
import numpy as np
from bpy.props import BoolProperty

from . import bl_images, bl_world
from ..worker import jobs, state
from ..logic import output_names, pixel_buffers

SYNC_ENV = "RELIGHT_PHOTO_SYNC"   # 1: every Relight runs synchronously (tests, scripts)
POLL_SECONDS = 0.05               # how often the main thread looks at a running job


def addon_settings(context):
    return context.scene.relight_photo


def status_of(context):
    return context.window_manager.relight_photo_status


def set_status(context, message: str, is_error: bool = False) -> None:
    status = status_of(context)
    status.message, status.is_error = message, is_error


def set_notice(context, photo_id: str, message: str) -> None:
    """A lasting notice about one photo (its saved relight could not be brought back in full): the
    panel shows it with that photo until the photo is relit, whatever the status line says since."""
    state.NOTICES[photo_id] = message
    set_status(context, message, is_error=True)


def notice_for(image) -> str:
    """The lasting notice of the photo `image` is (or is an output of), or ''."""
    if image is None:
        return ""
    return state.NOTICES.get(bl_images.owner_of(image) or bl_images.photo_id(image), "")


def tell(operator, context, message: str, is_error: bool = True) -> set:
    """An operator's outcome, said where the artist looks: Blender's info bar and the panel's
    status line; returns CANCELLED for an error, FINISHED otherwise."""
    operator.report({"ERROR" if is_error else "INFO"}, message)
    set_status(context, message, is_error=is_error)
    return {"CANCELLED"} if is_error else {"FINISHED"}


def editor_image(context):
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
        image = editor_image(context)
        if image is None:
            raise ValueError("Open a photo in the Image Editor first.")
    owner = bl_images.owner_of(image)
    if owner:
        photo = bl_images.photo_by_id(owner)
        if photo is None:
            raise ValueError(f"'{image.name}' is a relit output whose photo was deleted: open the photo itself.")
        return photo
    name = output_names.source_of(image.name, set(bpy.data.images.keys()))
    return bpy.data.images[name]


def current_session(context):
    """The session the dials drive (its photo still exists), or None."""
    session = state.SESSIONS.get(addon_settings(context).last_photo_id)
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


def _output_args(session: state.PhotoSession, layer: str, size: tuple[int, int]) -> tuple:
    """(name, width, height, options) of a layer's output image: `size` is (H, W) of the upright
    image (the decomposition's); Blender's image is the photo as its file stores it, turned by the
    session's orientation (pixel_buffers.stored_size)."""
    height, width = pixel_buffers.stored_size(size, session.orientation)
    colorspace = bl_images.NON_COLOR if layer == "alpha" else bl_images.LINEAR
    return (output_names.output_name(session.source, layer), width, height,
            dict(colorspace=colorspace, owner=session.photo_id, layer=layer))


def make_output(session: state.PhotoSession, layer: str, size: tuple[int, int]) -> bool:
    """Make the layer's output image when it is not there at its size: True when Blender allocated
    one (then a timer writes its pixels at its next call, so neither step is a long stretch)."""
    name, width, height, options = _output_args(session, layer, size)
    return bl_images.output_image(name, width, height, **options)[1]


def write_output(session: state.PhotoSession, layer: str, rgba: np.ndarray, size: tuple[int, int]):
    """Hand a prepared buffer to Blender; the buffer goes back to the pool (nobody reads it after).
    `size`: (H, W) of the upright image (the decomposition's)."""
    name, width, height, options = _output_args(session, layer, size)
    try:
        image = bl_images.write_rgba(name, rgba, width, height, **options)
    finally:
        pixel_buffers.BUFFERS.give(rgba)
    if layer == "matte" and image.alpha_mode != "STRAIGHT":
        image.alpha_mode = "STRAIGHT"  # shown as a cut-out over Blender's checkerboard
    return image


def updates_immediately() -> bool:
    # without a UI (tests, scripts) timers never fire: relight at once
    return bpy.app.background or jobs.env_flag(SYNC_ENV)


def release_job(job, slot: str = "job") -> None:
    """Forget the running job, if it is still this one."""
    if job is not None and state.RUNNING.get(slot) is job:
        del state.RUNNING[slot]


class WorkerOperator:
    """What Relight and Relight Sequence share: a job on a worker thread (its BackgroundJob,
    plan and start time), run on the calling thread when asked or with no UI to poll from,
    else polled on a timer from the operator's modal handler."""

    synchronous: BoolProperty(name="Synchronous", default=False, options={"SKIP_SAVE", "HIDDEN"},
                              description="Run on the calling thread (tests, scripts)")

    _job = None
    _timer = None
    _plan = None
    _started = 0.0
    _world_seconds = 0.0  # of the press, spent reading the World's light (bl_session.press_clock)

    def runs_here(self, context) -> bool:
        """Run on the calling thread: asked to (the property, RELIGHT_PHOTO_SYNC), or no window
        whose timer could poll the job (background mode, scripts)."""
        return self.synchronous or updates_immediately() or context.window is None

    def start_polling(self, context) -> set:
        """The job is started: poll it every POLL_SECONDS from the modal handler."""
        wm = context.window_manager
        self._timer = wm.event_timer_add(POLL_SECONDS, window=context.window)
        wm.modal_handler_add(self)
        status_of(context).running = True
        return {"RUNNING_MODAL"}

    def stop_polling(self, context, slot: str = "job") -> None:
        """The job is over: no more timer, the panel's status at rest, the job's slot free."""
        if self._timer is not None:
            context.window_manager.event_timer_remove(self._timer)
            self._timer = None
        status = status_of(context)
        status.running, status.stage, status.progress = False, "", 0.0
        release_job(self._job, slot)


# ------------------------------------------------------------------ how long a press took

PRESS_GAP = 0.25  # s: a scene update that ended this shortly before an operator started was part of its press
_UPDATE = {"began": 0.0, "ended": 0.0, "worlds": set(), "world_seconds": 0.0}


@bpy.app.handlers.persistent
def on_update_pre(*_args) -> None:
    if bl_world.baking():  # the updates of our own bake's scene are inside the update that bakes
        return
    _UPDATE["began"], _UPDATE["worlds"] = time.monotonic(), set(state.WORLDS)


@bpy.app.handlers.persistent
def on_update_post(*_args) -> None:
    """Registered after bl_dials.on_depsgraph_update: a World edit's light, read (a procedural
    World baked with Cycles, seconds) by that handler, is inside this update."""
    if bl_world.baking():
        return
    now = time.monotonic()
    read_world = bool(set(state.WORLDS) - _UPDATE["worlds"])
    _UPDATE["ended"], _UPDATE["world_seconds"] = now, (now - _UPDATE["began"]) if read_world else 0.0


def press_clock() -> tuple[float, float]:
    """(when the press began, seconds of it spent reading the World's light) at an operator's start.

    Blender brings the scene up to date before it runs an operator; when the World changed, the
    add-on's depsgraph handler reads its light there (a Sky World: a Cycles bake of 0.6-2 s), before
    the operator's own code. That update is part of the press the artist waits for."""
    now = time.monotonic()
    if _UPDATE["world_seconds"] and now - _UPDATE["ended"] < PRESS_GAP:
        began, seconds = _UPDATE["began"], _UPDATE["world_seconds"]
        _UPDATE["world_seconds"] = 0.0  # counted once
        return began, seconds
    return now, 0.0


def timed_light(read, *args):
    """(read(*args), seconds it took when it read a World's light (not from the cache), else 0)."""
    before, start = set(state.WORLDS), time.monotonic()
    value = read(*args)
    return value, (time.monotonic() - start) if set(state.WORLDS) - before else 0.0


def seconds_note(world: float, network: float | None = None) -> str:
    """' (reading the World's light 1.2 s, network 0.4 s)', the parts of a press worth naming."""
    parts = [f"reading the World's light {world:.1f} s"] if world >= 0.05 else []
    if network is not None:
        parts.append(f"network {network:.1f} s")
    return f" ({', '.join(parts)})" if parts else ""
