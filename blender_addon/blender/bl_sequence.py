"""Relight Sequence: the movie or image sequence in the Image Editor relit frame by frame
into a new image sequence beside the .blend (blender_addon/worker/sequence.py does the work on
a worker thread; progress in the panel, Esc stops and keeps the frames done)."""

import math
import time

import bpy
from bpy.props import BoolProperty, StringProperty

from relight.command.clip import DEFAULT_STABILITY

from ..worker import engine, jobs, sequence
from ..logic import quality
from .bl_light import target_light
from .bl_session import (WorkerOperator, addon_settings, editor_image, press_clock, release_job, seconds_note,
                         set_status, status_of, tell, timed_light)

SLOT = "sequence"  # its place in state.RUNNING (a sequence and a photo can be relit at once)
SOURCES = {"SEQUENCE", "MOVIE"}


def sequence_image(context, image_name: str = ""):
    """`image_name`, else the editor's image, when it is a movie or an image sequence; else None."""
    image = bpy.data.images.get(image_name) if image_name else editor_image(context)
    return image if image is not None and image.source in SOURCES else None


class RELIGHT_PHOTO_OT_relight_sequence(bpy.types.Operator, WorkerOperator):
    """Relight every frame of the movie or image sequence into a new image sequence beside the .blend
(steady from frame to frame; Esc stops and keeps the frames done)"""

    bl_idname = "relight_photo.relight_sequence"
    bl_label = "Relight Sequence"
    bl_options = {"REGISTER"}

    image_name: StringProperty(name="Image", default="", options={"SKIP_SAVE"},
                               description="Movie or image sequence to relight (default: the Image Editor's image)")
    overwrite: BoolProperty(name="Overwrite", default=False, options={"SKIP_SAVE"},
                            description="Replace the frames an earlier run left in the output folder "
                                        "(the panel's Overwrite Frames does the same for one run)")

    def _make_plan(self, context) -> dict:
        from ..worker import state

        if SLOT in state.RUNNING:
            raise ValueError("A sequence is already being relit; press Esc to stop it first.")
        image = sequence_image(context, self.image_name)
        if image is None:
            raise ValueError("Open a movie or an image sequence in the Image Editor first.")
        settings = addon_settings(context)
        if settings.light_kind == "IMAGE":
            raise ValueError("Relight Sequence takes a preset, an HDR file or the World as its light.")
        model_path = str(quality.model_path_for(settings.quality, bpy.path.abspath(settings.model_path)))
        order = engine.known_sh_order(model_path)
        relighter = engine.open_relighter(model_path) if order is None else None
        order = relighter.sh_order if relighter is not None else order
        folder = sequence.output_folder(bpy.data.filepath, image.name)
        earlier = sequence.frames_in(folder)
        overwrite = self.overwrite or settings.overwrite_frames
        if earlier and not overwrite:
            raise ValueError(f"'{folder.name}' beside the .blend holds {len(earlier)} frames of an earlier Relight "
                             "Sequence: tick Overwrite next to Relight Sequence to replace them, or move or rename "
                             "that folder to keep them.")
        # the World needs bpy: read here
        (light, extra_rotation), self._world_seconds = timed_light(target_light, context, order, model_path)
        if overwrite:
            settings.overwrite_frames = False  # one run's permission: the next run asks again
        return dict(path=bpy.path.abspath(image.filepath), source=image.source, name=image.name,
                    folder=str(folder), replace=earlier if overwrite else [], model_path=model_path,
                    relighter=relighter, long_side=quality.preset(settings.quality).working_size,
                    matte_method=quality.preset(settings.quality).matte_method,
                    augment=quality.preset(settings.quality).augment, light=light,
                    rotation=math.degrees(settings.rotation) + extra_rotation, exposure=settings.exposure,
                    stability=DEFAULT_STABILITY,
                    person=int(settings.person) or None if settings.person.isdigit() else None)  # 0: everyone

    def _start(self, context, press: tuple | None = None) -> None:
        from ..worker import state

        self._started, before = press or press_clock()
        self._plan = plan = self._make_plan(context)
        self._world_seconds += before
        token, progress = engine.CancelToken(), sequence.SequenceProgress()
        self._job = jobs.BackgroundJob(lambda: sequence.relight_sequence(plan, progress, token),
                                       label="sequence", cancel_token=token, progress=progress)
        state.RUNNING[SLOT] = self._job

    def _finish(self, context, result: dict) -> set:
        image = bpy.data.images.load(str(result["first"]), check_existing=True)
        image.reload()  # a run before may have left other frames under the same name
        image.source = "SEQUENCE"
        space = getattr(context, "space_data", None)
        if space is not None and getattr(space, "type", "") == "IMAGE_EDITOR":
            space.image = image
            space.image_user.frame_duration = result["written"]
        wall = time.monotonic() - self._started
        replace = self._plan["replace"]
        replaced = f", replacing the {len(replace)} frames there before" if replace else ""
        message = (f"Relit {result['written']} frames of '{self._plan['name']}' into {result['folder']} in "
                   f"{wall:.1f} s{seconds_note(self._world_seconds)}{replaced}{sequence.nobody_note(result['nobody'])}.")
        set_status(context, message)
        self.report({"INFO"}, message)
        return {"FINISHED"}

    def _stopped(self, context, error: BaseException) -> set:
        if isinstance(error, engine.Cancelled):
            written = self._job.progress.written if self._job is not None else 0
            message = f"Stopped: the {written} frames done are in {self._plan['folder']}."
            self.report({"WARNING"}, message)
            set_status(context, message)
            return {"CANCELLED"}
        return tell(self, context, str(error) if isinstance(error, ValueError) else str(engine.user_error(error)))

    def execute(self, context):
        # synchronous path: tests, scripts and background mode
        press = press_clock()
        try:
            self._start(context, press)
            if self._job.wait() is jobs.JobState.FAILED:
                raise self._job.error
            return self._finish(context, self._job.result)
        except (ValueError, OSError, engine.Cancelled) as exc:
            return self._stopped(context, exc)
        finally:
            release_job(self._job, SLOT)

    def invoke(self, context, event):
        if self.runs_here(context):
            return self.execute(context)
        try:
            self._start(context, press_clock())
        except ValueError as exc:
            return self._stopped(context, exc)
        return self.start_polling(context)

    def modal(self, context, event):
        if event.type == "ESC":
            # stop after the frame in progress: every frame written stays whole
            self._job.cancel_token.cancel()
            self._job.wait(timeout=30)
            self.stop_polling(context, SLOT)
            return self._stopped(context, engine.Cancelled())
        if event.type != "TIMER":
            return {"PASS_THROUGH"}
        job_state = self._job.poll()
        if job_state is jobs.JobState.RUNNING:
            progress = self._job.progress
            status = status_of(context)
            status.stage, status.elapsed = progress.stage, time.monotonic() - self._started
            status.progress = min(0.99, progress.written / progress.total) if progress.total else 0.0
            return {"PASS_THROUGH"}
        self.stop_polling(context, SLOT)
        if job_state is jobs.JobState.FAILED:
            return self._stopped(context, self._job.error)
        try:
            return self._finish(context, self._job.result)
        except (ValueError, RuntimeError) as exc:
            return self._stopped(context, exc)


CLASSES = (RELIGHT_PHOTO_OT_relight_sequence,)

register, unregister = bpy.utils.register_classes_factory(CLASSES)
