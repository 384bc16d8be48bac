"""Operators: Relight (network off the UI thread, Esc cancels) and Save Layers."""

import math

import bpy
import numpy as np
from bpy.props import BoolProperty, StringProperty

from . import bl_images, bl_world, engine, jobs, pipeline, quality, state

SYNC_ENV = "RELIGHT_PHOTO_SYNC"   # 1: every Relight runs synchronously (tests, scripts)
POLL_SECONDS = 0.1


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
    name = pipeline.source_of(image.name, set(bpy.data.images.keys()))
    return bpy.data.images[name]


def _mask_for(settings, image, photo_alpha, shape):
    mask_rgb = mask_alpha = None
    mask_name = ""
    if settings.mask_mode == "IMAGE" and settings.mask_image is not None:
        mask_name = settings.mask_image.name
        # stored values (code values of 8/16-bit files), not decoded colour: a mask is data
        stored = bl_images.rgba_pixels(settings.mask_image)
        mask_rgb = stored[..., :3] if stored.shape[2] >= 3 else np.repeat(stored[..., :1], 3, axis=2)
        mask_alpha = stored[..., 3] if stored.shape[2] == 4 else None
    if settings.mask_mode == "IMAGE_ALPHA" and not _has_alpha(image):
        photo_alpha = None
    mask = pipeline.choose_mask(settings.mask_mode, shape, photo_alpha, mask_rgb, mask_alpha, mask_name)
    return mask, (settings.mask_mode, mask_name)


def _has_alpha(image) -> bool:
    # depth: bits per pixel; 32/64/128 are RGBA at 8/16/32 bits per channel
    return image.alpha_mode != "NONE" and image.depth in (16, 32, 64, 128)


def _light_image_key(settings, model_path: str) -> tuple | None:
    if settings.light_kind != "IMAGE" or settings.light_image is None:
        return None
    return (settings.light_image.name, model_path, settings.quality)


def target_light(context, order: int, model_path: str):
    """(light for relight.runtime, extra rotation in degrees) for the current settings.

    The light is a preset name, an HDR path, SH coefficients (the World) or
    the Decomposition of another photo; ValueError says what is missing.
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
        decomposition = state.LIGHT_SOURCES.get(_light_image_key(settings, model_path))
        if decomposition is None:
            raise ValueError(f"Press Relight to estimate the light of '{settings.light_image.name}'.")
        return decomposition, 0.0
    raise ValueError(f"Unknown light kind {kind!r}.")


def _world_light(world, order: int):
    """(SH light, rotation) of the world, read (or baked) and projected again only
    when its nodes changed."""
    key = bl_world.fingerprint(world)
    cached = state.WORLDS.get(world.name)
    if cached is None or cached[0] != key:
        cached = state.WORLDS[world.name] = (key, bl_world.read_world(world), {})
    _, light, projected = cached
    if order not in projected:
        projected[order] = pipeline.equirect_light(light.equirect, order)
    return projected[order], light.rotation_deg


def _dials(context, session: state.PhotoSession):
    settings = _settings(context)
    light, extra_rotation = target_light(context, session.decomposition.sh_order, session.model_path)
    return light, math.degrees(settings.rotation) + extra_rotation, settings.exposure


def compute_relit(context, session: state.PhotoSession, dials=None):
    """Linear RGB [H, W, 3] of the cached decomposition relit with the current dials."""
    light, rotation, exposure = dials or _dials(context, session)
    relit = engine.relight(session.decomposition, light, rotation, exposure)
    return pipeline.blend(relit, session.photo, _settings(context).strength)


def render_relit(context, session: state.PhotoSession, dials=None) -> bpy.types.Image:
    """Relight the cached decomposition with the current dials and write '<photo>.relit'."""
    rgb = compute_relit(context, session, dials)
    return bl_images.write_image(pipeline.output_name(session.source, "relit"), rgb)


def refresh_relit(context) -> None:
    """Property-update hook: redo the relit image from the cache (no network run)."""
    settings = _settings(context)
    session = state.SESSIONS.get(settings.last_source)
    if session is None or bpy.data.images.get(session.source) is None:
        return
    try:
        render_relit(context, session)
        _set_status(context, "")
    except ValueError as exc:
        _set_status(context, str(exc), is_error=True)


def _updates_immediately() -> bool:
    # without a UI (tests, scripts) timers never fire: relight at once
    return bpy.app.background or pipeline.env_flag(SYNC_ENV)


def _deferred_refresh():
    refresh_relit(bpy.context)
    return None  # run once


def schedule_refresh(context) -> None:
    """A dial moved: relight now without a UI, else once the UI is idle.

    Dragging a slider sends an update per mouse move; deferring to a timer
    coalesces them, so a drag stays smooth even when one relight takes
    a noticeable fraction of a second on a large photo.
    """
    if _updates_immediately():
        refresh_relit(context)
    elif not bpy.app.timers.is_registered(_deferred_refresh):
        bpy.app.timers.register(_deferred_refresh, first_interval=0.0)


def _write_layers(context, session: state.PhotoSession, dials=None) -> None:
    """'<photo>.albedo/.shading/.residual/.alpha' under the current light."""
    light, rotation, exposure = dials or _dials(context, session)
    for layer, pixels in engine.layers(session.decomposition, light, rotation, exposure).items():
        colorspace = bl_images.NON_COLOR if layer == "alpha" else bl_images.LINEAR
        bl_images.write_image(pipeline.output_name(session.source, layer), pixels, colorspace=colorspace)


_in_handler = False


@bpy.app.handlers.persistent
def on_depsgraph_update(scene, depsgraph) -> None:
    """A World edit that changes its light (mapping, sky, image) relights live."""
    global _in_handler
    if _in_handler or not depsgraph.id_type_updated("WORLD"):
        return
    settings = getattr(scene, "relight_photo", None)
    if settings is None or settings.light_kind != "WORLD" or settings.last_source not in state.SESSIONS:
        return
    cached = state.WORLDS.get(scene.world.name) if scene.world is not None else None
    if cached is not None and cached[0] == bl_world.fingerprint(scene.world):
        return  # an update that does not change the light (or our own bake)
    _in_handler = True
    try:
        refresh_relit(bpy.context)
    finally:
        _in_handler = False


@bpy.app.handlers.persistent
def on_load(_dummy) -> None:
    """A new .blend: the cached photos belong to the old file."""
    state.clear()


def _run_network(plan: dict):
    """The worker thread's whole job: plain data in, decompositions out (no bpy)."""
    relighter, long_side = plan["relighter"], plan["long_side"]
    decomposition = engine.decompose(relighter, plan["photo"], plan["mask"], long_side)
    light_decomposition = None
    if plan["light_photo"] is not None:
        light_decomposition = engine.decompose(relighter, plan["light_photo"], None, long_side)
    return decomposition, light_decomposition


def _release(job) -> None:
    """Forget the running job, if it is still this one."""
    if job is not None and state.RUNNING.get("job") is job:
        del state.RUNNING["job"]


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

    # the plan gathers every input on the main thread before the worker starts
    def _make_plan(self, context) -> dict:
        settings = _settings(context)
        image = source_image(context, self.image_name)
        photo, photo_alpha = bl_images.linear_rgb_and_alpha(image)
        mask, mask_key = _mask_for(settings, image, photo_alpha, photo.shape[:2])
        model_path = str(pipeline.model_path_for(settings.quality, bpy.path.abspath(settings.model_path)))
        relighter = engine.open_relighter(model_path)
        long_side = quality.preset(settings.quality).working_long_side
        light_photo = None
        light_key = _light_image_key(settings, model_path)
        if settings.light_kind == "IMAGE":
            if settings.light_image is None:
                raise ValueError("Choose the photo to take the light from.")
            if light_key not in state.LIGHT_SOURCES:
                light_photo, _ = bl_images.linear_rgb_and_alpha(settings.light_image)
        if settings.light_kind != "IMAGE":
            # check the target light before spending time on the network
            target_light(context, relighter.sh_order, model_path)
        return dict(source=image.name, photo=photo, mask=mask, mask_key=mask_key, model_path=model_path,
                    relighter=relighter, long_side=long_side, quality=settings.quality,
                    light_photo=light_photo, light_key=light_key)

    def _finish(self, context, result, seconds: float) -> set:
        plan = self._plan
        decomposition, light_decomposition = result
        if light_decomposition is not None:
            state.LIGHT_SOURCES[plan["light_key"]] = light_decomposition
        session = state.PhotoSession(
            source=plan["source"], photo=plan["photo"],
            decomposition=decomposition, model_path=plan["model_path"], quality=plan["quality"],
            mask_key=plan["mask_key"])
        state.SESSIONS[session.source] = session
        _settings(context).last_source = session.source
        try:
            dials = _dials(context, session)
            relit = render_relit(context, session, dials)
            _write_layers(context, session, dials)
        except ValueError as exc:
            self.report({"ERROR"}, str(exc))
            _set_status(context, str(exc), is_error=True)
            return {"CANCELLED"}
        space = getattr(context, "space_data", None)
        if space is not None and space.type == "IMAGE_EDITOR":
            space.image = relit
        message = f"Relit '{session.source}' in {seconds:.1f} s."
        _set_status(context, message)
        self.report({"INFO"}, message)
        return {"FINISHED"}

    def _start(self, context):
        if "job" in state.RUNNING:
            raise ValueError("A relight is already running; press Esc to cancel it first.")
        self._plan = self._make_plan(context)
        plan = self._plan
        # the thread gets plain data only: never the operator, which Blender may free
        self._job = jobs.BackgroundJob(lambda: _run_network(plan), label="decompose")
        state.RUNNING["job"] = self._job

    def _error(self, context, exc: Exception) -> set:
        message = str(exc) if isinstance(exc, ValueError) else f"Relighting failed: {exc}"
        self.report({"ERROR"}, message)
        _set_status(context, message, is_error=True)
        return {"CANCELLED"}

    def execute(self, context):
        # synchronous path: tests, scripts and background mode
        try:
            self._start(context)
            state_ = self._job.wait()
        except ValueError as exc:
            return self._error(context, exc)
        finally:
            _release(self._job)
        if state_ is jobs.JobState.FAILED:
            return self._error(context, engine.user_error(self._job.error))
        return self._finish(context, self._job.result, self._job.elapsed)

    def invoke(self, context, event):
        if self.synchronous or pipeline.env_flag(SYNC_ENV) or bpy.app.background or context.window is None:
            return self.execute(context)
        try:
            self._start(context)
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
        _status(context).running = False
        _release(self._job)

    def modal(self, context, event):
        if event.type == "ESC":
            self._job.cancel()
            self._cleanup(context)
            self.report({"WARNING"}, "Relighting cancelled.")
            _set_status(context, "Relighting cancelled.")
            return {"CANCELLED"}
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        job_state = self._job.poll()
        if job_state is jobs.JobState.RUNNING:
            expected = engine.expected_seconds(self._plan["model_path"], self._plan["long_side"])
            fraction = min(0.99, self._job.elapsed / expected) if expected else 0.0
            context.window_manager.progress_update(int(100 * fraction))
            if context.workspace is not None:
                context.workspace.status_text_set(
                    f"Relight Photo: running the network on '{self._plan['source']}' "
                    f"({self._job.elapsed:.1f} s), Esc to cancel")
            return {"PASS_THROUGH"}
        self._cleanup(context)
        if job_state is jobs.JobState.FAILED:
            return self._error(context, engine.user_error(self._job.error))
        return self._finish(context, self._job.result, self._job.elapsed)


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
        name = self.image_name or _settings(context).last_source
        if self.image_name == "" and _editor_image(context) is not None:
            name = source_image(context).name
        session = state.SESSIONS.get(name)
        if session is None:
            raise ValueError("Relight the photo first: there are no layers to save yet.")
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
            engine.save_layers(path, relit, engine.layers(session.decomposition, *dials))
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
             (bpy.app.handlers.load_post, on_load))


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for handlers, fn in _HANDLERS:
        if fn not in handlers:
            handlers.append(fn)


def unregister() -> None:
    if bpy.app.timers.is_registered(_deferred_refresh):
        bpy.app.timers.unregister(_deferred_refresh)
    for handlers, fn in _HANDLERS:
        while fn in handlers:
            handlers.remove(fn)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
