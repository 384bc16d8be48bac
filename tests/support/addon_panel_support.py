"""The add-on registered once per test module, with the photo and a cut-out loaded, and the panel's
settings reset before each test: shared by tests/blender_addon/test_addon_blender.py and the modules
split from it (World lights, errors, interaction)."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import bpy
import pytest

import blender_addon
from blender_addon.blender import bl_images, bl_ops
from blender_addon.worker import state

from addon_support import write_person_png

# float32 arithmetic on values <= ~4 through a few dozen operations (SH dot
# products of 25 terms, bilinear taps, blend): far below 1e-5
TIGHT = 1e-5


@pytest.fixture(scope="module")
def addon(model, tmp_path_factory):
    folder = tmp_path_factory.mktemp("addon_photos")
    write_person_png(folder / "person.png")
    write_person_png(folder / "cutout.png", with_alpha=True)
    blender_addon.register()
    # the World tests here read the World alone: the startup scene's lamp would join its light
    # (lamps in, issue 38: tests/blender_addon/test_addon_lamps.py)
    for lamp in [obj for obj in bpy.data.objects if obj.type == "LIGHT"]:
        bpy.data.objects.remove(lamp)
    photo = bpy.data.images.load(str(folder / "person.png"))
    cutout = bpy.data.images.load(str(folder / "cutout.png"))
    yield {"model": model, "photo": photo.name, "cutout": cutout.name, "folder": folder}
    for image in list(bpy.data.images):
        if image.name.startswith(("person.png", "cutout.png", "mask", "lightsrc")):
            bpy.data.images.remove(image)
    blender_addon.unregister()


@pytest.fixture
def settings(addon):
    s = bpy.context.scene.relight_photo
    s.model_path = str(addon["model"])
    s.quality = "DRAFT"
    s.mask_mode = "NETWORK"  # the synthetic figure is no person to the person matte
    s.light_kind = "PRESET"
    s.preset = "studio"
    s.rotation = 0.0
    s.exposure = 0.0
    s.strength = 1.0
    s.hdr_path = ""
    s.light_image = None
    s.mask_image = None
    yield s
    s.light_kind = "PRESET"


def session(image_name: str) -> state.PhotoSession:
    """The add-on's session of a photo, found by the photo's stable id."""
    return state.SESSIONS[bpy.data.images[image_name][bl_images.PHOTO_ID]]


def relight(image_name: str, **kw):
    return bpy.ops.relight_photo.relight(image_name=image_name, synchronous=True, **kw)



def expect_error(message_start: str, **kw):
    with pytest.raises(RuntimeError) as info:
        relight(**kw) if "image_name" in kw else bpy.ops.relight_photo.relight(synchronous=True)
    text = str(info.value)
    assert message_start in text, text
    # one sentence, no traceback
    assert "Traceback" not in text and text.strip().count("\n") == 0
    return text


class FakeWindowManager:
    def __init__(self):
        self.progress = []
        self.relight_photo_status = bpy.context.window_manager.relight_photo_status

    def progress_update(self, value):
        self.progress.append(value)

    def progress_end(self):
        self.progress.append("end")

    def event_timer_remove(self, _timer):
        pass


class FakeWorkspace:
    def __init__(self):
        self.status = []

    def status_text_set(self, text):
        self.status.append(text)


def modal_operator(image_name):
    import types

    cls = bl_ops.RELIGHT_PHOTO_OT_relight
    op = types.SimpleNamespace(image_name=image_name, synchronous=False, _job=None, _timer=None,
                               _plan=None, _pending=None, _result=None, _started=0.0, reports=[],
                               _dial_values=cls._dial_values)
    op.report = lambda kind, text: op.reports.append((set(kind), text))
    for name in ("_make_plan", "_start", "_install", "_write_next", "_done", "_error", "_cleanup",
                 "stop_polling", "_show_progress", "modal"):
        setattr(op, name, getattr(cls, name).__get__(op))
    context = types.SimpleNamespace(scene=bpy.context.scene, window_manager=FakeWindowManager(),
                                    workspace=FakeWorkspace(), space_data=None, window=None)
    return op, context


def png_image(path: Path, rgb: np.ndarray) -> str:
    from PIL import Image

    Image.fromarray(rgb, "RGB").save(path)
    return bpy.data.images.load(str(path)).name
