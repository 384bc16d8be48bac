"""Operators: Relight (network off the UI thread, Esc cancels) and Save Layers, and the
add-on's registration (operators, handlers, timers of bl_dials and bl_saved).

The main thread only gathers inputs (settings, the light) and hands finished
buffers to Blender (one foreach_set per image); reading and decoding the
photo, the network, relighting and packing pixels run on a worker thread.
"""

import math
import os
import time

import bpy
from bpy.props import BoolProperty, StringProperty

from . import bl_dials, bl_images, bl_layers, bl_proxy, bl_saved, bl_session
from ..worker import engine, jobs, people, save_layers, state, work
from ..logic import mask_choice, output_names, photo_pixels, quality
from .bl_dials import schedule_refresh
from .bl_layers import poll_layers, start_layers, write_layers_now
from .bl_light import current_dials, light_image_key, target_light
from .bl_session import (WorkerOperator, addon_settings, current_session, editor_image, make_output, press_clock,
                         release_job, seconds_note, session_of, set_status, source_image, status_of, tell,
                         timed_light, write_output)


def mask_inputs(settings, image) -> dict:
    """What the worker needs to make the mask; errors a user can fix are raised here, at once."""
    width, height = image.size
    inputs = dict(mode=settings.mask_mode, rgb=None, alpha=None, name="", use_photo_alpha=False,
                  person=int(settings.person) if settings.person.isdigit() else 1)
    if settings.mask_mode == "IMAGE":
        mask_image = settings.mask_image
        if mask_image is not None:
            # stored values (code values of 8/16-bit files), not decoded colour: a mask is data
            inputs["rgb"], inputs["alpha"] = mask_choice.mask_channels(bl_images.rgba_pixels(mask_image))
            inputs["name"] = mask_image.name
        mask_choice.choose_mask("IMAGE", (height, width), None, inputs["rgb"], inputs["alpha"], inputs["name"])
    elif settings.mask_mode == "IMAGE_ALPHA":
        if not bl_images.has_alpha(image):
            raise ValueError("The photo has no alpha channel to use as the mask.")
        inputs["use_photo_alpha"] = True
    return inputs


# ------------------------------------------------------------------ operators

class RELIGHT_PHOTO_OT_relight(bpy.types.Operator, WorkerOperator):
    """Split the photo into albedo, light transport and light, then relight it with the chosen light"""

    bl_idname = "relight_photo.relight"
    bl_label = "Relight"
    bl_options = {"REGISTER", "UNDO"}  # undoing a run removes its output images

    image_name: StringProperty(name="Image", default="", options={"SKIP_SAVE"},
                               description="Photo to relight (default: the Image Editor's image)")

    _pending = None     # output layers still to hand to Blender, one per timer tick
    _result = None

    # the plan gathers every input on the main thread before the worker starts
    def _make_plan(self, context) -> dict:
        settings = addon_settings(context)
        bl_images.sync_output_names()
        image = source_image(context, self.image_name)
        previous = state.SESSIONS.get(bl_images.photo_id(image))
        if previous is not None and previous.provisional:  # a reopened file's preview: not the full photo
            previous = None
        reuse = None if previous is None else photo_pixels.PhotoPixels(previous.photo, None, previous.digest,
                                                                      previous.orientation)
        # checks the photo has pixels and a usable size (from its file's header when Blender has not read it)
        read_photo = bl_images.photo_reader(image, reuse, settings.max_megapixels)
        mask = mask_inputs(settings, image)
        model_path = str(quality.model_path_for(settings.quality, bpy.path.abspath(settings.model_path)))
        order = engine.known_sh_order(model_path)
        # a shipped model opens on the worker; a custom one here, to learn its SH order
        relighter = engine.open_relighter(model_path) if order is None else None
        order = relighter.sh_order if relighter is not None else order
        long_side = quality.preset(settings.quality).working_size
        light = light_cached = light_reader = None
        light_key = light_image_key(settings, model_path)
        rotation = math.degrees(settings.rotation)
        if settings.light_kind == "IMAGE":
            if settings.light_image is None:
                raise ValueError("Choose the photo to take the light from.")
            light_cached = state.LIGHT_SOURCES.get(light_key)
            if light_cached is None:
                light_reader = bl_images.photo_reader(settings.light_image, max_megapixels=settings.max_megapixels)
        elif settings.light_kind in ("PRESET", "HDR"):
            # a name or a path: checked (and projected) by the worker, before the network runs
            light = ("PRESET", settings.preset) if settings.light_kind == "PRESET" else \
                ("HDR", bpy.path.abspath(settings.hdr_path) if settings.hdr_path else "")
            if light[0] == "PRESET" and light[1] == "NONE":
                raise ValueError("No light preset is installed.")
        else:
            # the World needs bpy: read here, before any time goes into the network
            (light, extra), seconds = timed_light(target_light, context, order, model_path)
            self._world_seconds += seconds
            rotation += extra
        return dict(photo_id=bl_images.photo_id(image, create=True), source=image.name, read_photo=read_photo,
                    mask=mask, model_path=model_path, relighter=relighter, long_side=long_side,
                    quality=settings.quality, light=light, light_cached=light_cached, light_reader=light_reader,
                    light_key=light_key, rotation=rotation, exposure=settings.exposure,
                    strength=settings.strength, dials_at_start=self._dial_values(settings), previous=previous)

    @staticmethod
    def _dial_values(settings) -> tuple:
        return (settings.light_kind, settings.preset, settings.hdr_path, settings.rotation, settings.exposure,
                settings.strength, settings.light_image.name if settings.light_image else "")

    def _start(self, context, layers_later: bool = False, press: tuple | None = None):
        # the press: from the scene update Blender ran just before (a World's light read there) on
        self._started, self._world_seconds = press or press_clock()
        if "job" in state.RUNNING:
            raise ValueError("A relight is already running; press Esc to cancel it first.")
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
        session.extras["stamp"] = bl_images.photo_stamp(photo)  # Photo Light -> World checks it (bl_photo_world)
        state.SESSIONS[session.photo_id] = session
        state.NOTICES.pop(session.photo_id, None)  # relit: what a restore said of it no longer holds
        settings = addon_settings(context)
        settings.last_photo_id = session.photo_id
        if session.people:
            settings.people_found = session.people
        settings.people_relit = len(people.people_of(session.decomposition)) if session.people else 0
        self._result = result
        self._pending = output_names.layers_in_order(result["buffers"])

    def _write_next(self, context, apart: bool = False) -> None:
        """Write the next output; `apart` (a timer tick): an image Blender must allocate first is
        made at this tick and written at the next."""
        session = self._result["session"]
        layer = self._pending[0]
        if apart and make_output(session, layer, session.photo.shape[:2]):
            return
        self._pending.pop(0)
        image = write_output(session, layer, self._result["buffers"].pop(layer), session.photo.shape[:2])
        if layer == "relit":
            space = getattr(context, "space_data", None)
            if space is not None and getattr(space, "type", "") == "IMAGE_EDITOR":
                space.image = image

    def _done(self, context) -> set:
        session = self._result["session"]
        wall = time.monotonic() - self._started
        bl_proxy.refresh(session)  # its proxy in the 3D scene, if Compositing Setup made one, follows
        note = people.people_note(session.people, len(people.people_of(session.decomposition))) \
            if session.mask_key == ("AUTO", str(work.EVERYONE)) else ""
        message = (f"Relit '{session.source}'{note} in {wall:.1f} s"
                   f"{seconds_note(self._world_seconds, self._result['network_seconds'])}.")
        if self._plan.get("layers_later"):
            start_layers(session, self._result["dials"])
            message = message[:-1] + "; the other layers follow."
        set_status(context, message)
        self.report({"INFO"}, message)
        if self._dial_values(addon_settings(context)) != self._plan["dials_at_start"]:
            schedule_refresh(context)  # a dial moved while the network ran
        self._result = self._plan = None  # Blender may keep this operator instance (redo): not the photo
        return {"FINISHED"}

    def _error(self, context, exc: BaseException) -> set:
        self._result = self._plan = None
        if isinstance(exc, engine.Cancelled):
            self.report({"WARNING"}, "Relighting cancelled.")
            set_status(context, "Relighting cancelled.")
            return {"CANCELLED"}
        return tell(self, context, str(exc) if isinstance(exc, ValueError) else str(engine.user_error(exc)))

    def execute(self, context):
        # synchronous path: tests, scripts and background mode
        press = press_clock()
        try:
            self._start(context, press=press)
            job_state = self._job.wait()
            if job_state is jobs.JobState.FAILED:
                raise engine.user_error(self._job.error) \
                    if not isinstance(self._job.error, engine.Cancelled) else self._job.error
            self._install(context, self._job.take_result())
            while self._pending:
                self._write_next(context)
            write_layers_now(self._result["session"], self._result["dials"])
        except (ValueError, engine.Cancelled) as exc:
            return self._error(context, exc)
        finally:
            release_job(self._job)
        return self._done(context)

    def invoke(self, context, event):
        if self.runs_here(context):
            return self.execute(context)
        press = press_clock()
        try:
            self._start(context, layers_later=True, press=press)
        except ValueError as exc:
            return self._error(context, exc)
        context.window_manager.progress_begin(0, 100)
        return self.start_polling(context)

    def _cleanup(self, context) -> None:
        context.window_manager.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        self.stop_polling(context)

    def _show_progress(self, context) -> None:
        progress = self._job.progress
        elapsed = time.monotonic() - self._started
        plan = self._plan
        in_network = plan is not None and progress.stage.startswith(jobs.NETWORK_STAGE)
        expected = engine.expected_seconds(plan["model_path"], plan["long_side"],
                                           **quality.network_options(plan["quality"])) if in_network else None
        network_share = 0.45 if plan is None or plan["light_reader"] is None else 0.30
        status = status_of(context)
        status.stage, status.progress, status.elapsed = \
            progress.stage, jobs.shown_fraction(progress, expected, network_share), elapsed
        context.window_manager.progress_update(int(100 * status.progress))
        if context.workspace is not None:
            context.workspace.status_text_set(
                f"Relight Photo: {progress.stage.lower()} ({elapsed:.1f} s), Esc to cancel")

    def modal(self, context, event):
        if event.type == "ESC":
            self._job.cancel()
            self._cleanup(context)
            if self._result is not None:  # an image made for the relit photo, not written: not left black
                bl_images.remove_unwritten(self._result["session"].photo_id)
            return self._error(context, engine.Cancelled())
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._result is not None:
            try:
                self._write_next(context, apart=True)  # one step per tick: the UI stays responsive
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
            self._install(context, self._job.take_result())
        except ValueError as exc:
            self._cleanup(context)
            return self._error(context, exc)
        status_of(context).stage = "Writing the images"
        return {"PASS_THROUGH"}


class RELIGHT_PHOTO_OT_save_layers(bpy.types.Operator, WorkerOperator):
    """Save the relit photo and its layers (albedo, shading, residual, alpha) as one multi-layer EXR"""

    bl_idname = "relight_photo.save_layers"
    bl_label = "Save Layers"
    bl_options = {"REGISTER"}

    filepath: StringProperty(subtype="FILE_PATH", options={"SKIP_SAVE"})
    filter_glob: StringProperty(default="*.exr", options={"HIDDEN"})
    check_existing: BoolProperty(default=True, options={"HIDDEN"})  # the file browser warns on overwrite
    image_name: StringProperty(name="Image", default="", options={"SKIP_SAVE"})

    SLOT = "save_layers"  # its place in state.RUNNING: one save at a time, beside a Relight

    def _session(self, context):
        if self.image_name or editor_image(context) is not None:
            session = session_of(source_image(context, self.image_name))
        else:
            session = current_session(context)
        if session is None:
            raise ValueError("Relight the photo first: there are no layers to save yet.")
        if session.photo_missing:
            raise ValueError(f"{session.photo_missing} Saving layers needs the photo at full size: "
                             f"{session.advice}")
        if session.provisional:
            raise ValueError("The photo is still being read after opening the file: save the layers in a moment.")
        return session

    def invoke(self, context, event):
        try:
            session = self._session(context)
        except ValueError as exc:
            return tell(self, context, str(exc))
        if not self.filepath:
            self.filepath = bpy.path.ensure_ext(bpy.path.clean_name(session.source) + "_layers", ".exr")
        context.window_manager.fileselect_add(self)
        return {"RUNNING_MODAL"}

    def _start(self, context) -> None:
        """The checks and the light here (the World needs bpy); relighting, the layers and the EXR
        (seconds at 24 MP) on a worker, into a temporary file beside the target."""
        from relight.files.fileio import temp_path_beside

        self._started = time.monotonic()
        if self.SLOT in state.RUNNING:
            raise ValueError("The layers are already being saved; press Esc to cancel that first.")
        session = self._session(context)
        if not self.filepath:
            raise ValueError("Choose a file to save the layers to.")
        path = bpy.path.abspath(bpy.path.ensure_ext(self.filepath, ".exr"))
        save_layers.check_layers_target(path, *session.photo.shape[:2],  # before seconds of work
                                        len(people.people_of(session.decomposition)))
        dials = current_dials(context, session)
        import threading
        from pathlib import Path

        tmp = str(temp_path_beside(Path(path), ".exr"))
        self._plan = plan = dict(session=session, dials=dials, path=path, tmp=tmp, handover=threading.Lock(),
                                 source=session.source)
        token, progress = engine.CancelToken(), jobs.Progress()
        self._job = jobs.BackgroundJob(lambda: save_layers.save_layers_work(plan, progress, token), label="save-layers",
                                       cancel_token=token, progress=progress)
        state.RUNNING[self.SLOT] = self._job

    def _finish(self, context) -> set:
        """The worker is done: its file takes the chosen name (or its error is said)."""
        job, plan = self._job, self._plan
        self._plan = None  # not the session: Blender may keep this operator for its redo panel
        if job.poll() is jobs.JobState.FAILED:
            return self._failed(context, job.error)
        os.replace(job.take_result(), plan["path"])
        wall = time.monotonic() - self._started
        return tell(self, context, f"Saved the layers of '{plan['source']}' to {plan['path']} in {wall:.1f} s.",
                    is_error=False)

    def _failed(self, context, exc) -> set:
        if isinstance(exc, engine.Cancelled):
            self.report({"WARNING"}, "Saving the layers cancelled: nothing was written.")
            set_status(context, "Saving the layers cancelled: nothing was written.")
            return {"CANCELLED"}
        if isinstance(exc, OSError):
            return tell(self, context, f"Cannot write '{self.filepath}': {exc.strerror or exc}.")
        return tell(self, context, str(exc) if isinstance(exc, ValueError) else str(engine.user_error(exc)))

    def execute(self, context):
        try:
            self._start(context)
        except ValueError as exc:
            return tell(self, context, str(exc))
        except OSError as exc:  # the temporary file beside the target
            return tell(self, context, f"Cannot write '{self.filepath}': {exc.strerror or exc}.")
        if not self.runs_here(context):  # after the file browser, with a UI: poll the worker
            context.window_manager.progress_begin(0, 100)
            return self.start_polling(context)
        try:
            self._job.wait()
            return self._finish(context)
        finally:
            release_job(self._job, self.SLOT)

    def _cleanup(self, context) -> None:
        context.window_manager.progress_end()
        if context.workspace is not None:
            context.workspace.status_text_set(None)
        self.stop_polling(context, self.SLOT)

    def modal(self, context, event):
        if event.type == "ESC":
            plan = self._plan
            with plan["handover"]:  # the worker hands its file over under this lock, or leaves none
                self._job.cancel()
                if plan.get("written"):
                    os.unlink(plan["tmp"])
            self._cleanup(context)
            self._plan = None
            return self._failed(context, engine.Cancelled())
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        if self._job.poll() is jobs.JobState.RUNNING:
            progress, elapsed = self._job.progress, time.monotonic() - self._started
            status = status_of(context)
            status.stage, status.progress, status.elapsed = progress.stage, min(progress.fraction, 0.99), elapsed
            context.window_manager.progress_update(int(100 * status.progress))
            if context.workspace is not None:
                context.workspace.status_text_set(
                    f"Relight Photo: {progress.stage.lower()} ({elapsed:.1f} s), Esc to cancel")
            return {"PASS_THROUGH"}
        self._cleanup(context)
        try:
            return self._finish(context)
        except OSError as exc:  # putting the file in place
            return self._failed(context, exc)


CLASSES = (RELIGHT_PHOTO_OT_relight, RELIGHT_PHOTO_OT_save_layers)


# in this order: bl_session.on_update_post times the update bl_dials' handler is part of
_HANDLERS = ((bpy.app.handlers.depsgraph_update_pre, bl_session.on_update_pre),
             (bpy.app.handlers.depsgraph_update_post, bl_dials.on_depsgraph_update),
             (bpy.app.handlers.depsgraph_update_post, bl_session.on_update_post),
             (bpy.app.handlers.load_post, bl_saved.on_load),
             (bpy.app.handlers.load_post, bl_dials.on_load_follow_renames),
             (bpy.app.handlers.save_post, bl_saved.on_save_post),
             (bpy.app.handlers.undo_post, bl_layers.on_undo_redo),
             (bpy.app.handlers.redo_post, bl_layers.on_undo_redo))
_TIMERS = (bl_dials.deferred_refresh, bl_dials.full_when_resting, bl_dials.poll_full_size,
           bl_saved.poll_restore, bl_saved.poll_saves, poll_layers)


def register() -> None:
    for cls in CLASSES:
        bpy.utils.register_class(cls)
    for handlers, fn in _HANDLERS:
        if fn not in handlers:
            handlers.append(fn)
    bl_dials.follow_renames()


def unregister() -> None:
    bl_saved.wait_for_saves()
    bl_dials.stop_following_renames()
    for timer in _TIMERS:
        if bpy.app.timers.is_registered(timer):
            bpy.app.timers.unregister(timer)
    for handlers, fn in _HANDLERS:
        while fn in handlers:
            handlers.remove(fn)
    for cls in reversed(CLASSES):
        bpy.utils.unregister_class(cls)
