"""What the add-on's tests share: a tiny exported model, a person photo, image pixels, a
World with nodes on every Blender, and the N-panel drawn into a layout that checks it."""

from __future__ import annotations

import contextlib
import os
import subprocess
import sys
import textwrap
import types
from pathlib import Path

import numpy as np

import bpy

import blender_addon

REPO = Path(__file__).resolve().parents[1]
ORDER = 4
H, W = 72, 48


def make_tiny_model(tmp_path_factory) -> Path:
    """A seeded random-weight RelightNet exported by the project's export code, in a
    child process so torch never loads into the bpy process; made once per session."""
    out = tmp_path_factory.getbasetemp() / "addon_tiny_model" / "tiny.onnx"
    if out.is_file():
        return out
    out.parent.mkdir(exist_ok=True)
    code = textwrap.dedent(f"""
        from export.random_model import export_random_model
        export_random_model({str(out)!r}, seed=3, sh_order={ORDER}, width=4, depth=2)
    """)
    # Blender 5.1+ bundles Python 3.13, for which no CPU torch is at hand: the make test
    # run under bpy 5.2 names the 3.11 interpreter that has torch (RELIGHT_TORCH_PYTHON)
    python = os.environ.get("RELIGHT_TORCH_PYTHON", sys.executable)
    subprocess.run([python, "-c", code], cwd=REPO, check=True, capture_output=True, timeout=300)
    return out


def write_person_png(path: Path, with_alpha: bool = False) -> None:
    """A bright figure (ellipse) on a darker textured background, sRGB PNG."""
    from PIL import Image

    y, x = np.mgrid[0:H, 0:W]
    inside = ((x - W / 2) / (W / 4)) ** 2 + ((y - H / 2) / (H / 2.6)) ** 2 <= 1
    rgb = np.empty((H, W, 3), np.uint8)
    rgb[..., 0] = 40 + (x * 3) % 50
    rgb[..., 1] = 60 + (y * 2) % 40
    rgb[..., 2] = 90
    rgb[inside] = (220, 170, 140)
    if with_alpha:
        rgba = np.dstack([rgb, np.where(inside, 255, 0).astype(np.uint8)])
        Image.fromarray(rgba, "RGBA").save(path)
    else:
        Image.fromarray(rgb, "RGB").save(path)


def new_node_world(name: str):
    """A World with a node tree on every Blender: 5.0+ always has one, 4.2 - 4.5 only with use_nodes."""
    world = bpy.data.worlds.new(name)
    if bpy.app.version < (5, 0, 0):
        world.use_nodes = True
    return world


def pixels(name: str) -> np.ndarray:
    """Float RGBA [H, W, 4] of an image datablock, top row first."""
    image = bpy.data.images[name]
    w, h = image.size
    flat = np.empty(w * h * 4, np.float32)
    image.pixels.foreach_get(flat)
    return flat.reshape(h, w, 4)[::-1]


class CheckingLayout:
    """Stands in for bpy's UILayout: records what the panel shows and fails on
    a property name the settings do not have."""

    def __init__(self, log):
        self.log = log
        self.enabled = True
        self.scale_y = 1.0

    def _child(self, *args, **kw):
        return CheckingLayout(self.log)

    column = row = box = _child

    def prop(self, data, name, **kw):
        assert hasattr(data, name), name
        self.log.append(("prop", name))

    def template_ID(self, data, name, **kw):
        assert hasattr(data, name), name
        self.log.append(("template_ID", name))

    def label(self, text="", icon="NONE"):
        self.log.append(("label", text))

    def operator(self, idname, **kw):
        module, name = idname.split(".")
        assert hasattr(getattr(bpy.ops, module), name), idname
        self.log.append(("operator", idname))


def draw_panel(photo_name: str) -> list:
    """Draw the N-panel for the image `photo_name` into a CheckingLayout; returns its log."""
    log = []
    panel = types.SimpleNamespace(layout=CheckingLayout(log))
    space = types.SimpleNamespace(image=bpy.data.images[photo_name])
    context = types.SimpleNamespace(scene=bpy.context.scene, window_manager=bpy.context.window_manager,
                                    space_data=space)
    bpy.types.RELIGHT_PHOTO_PT_panel.draw(panel, context)
    return log


@contextlib.contextmanager
def addon_in_empty_scene(folder: Path, model: Path | None = None, **settings):
    """The add-on registered in an empty scene, with the person photo written to `folder`/person.png;
    given `model`, the panel set to it at Draft with the network's matte and the studio preset,
    then to `settings`. Yields the panel's settings; afterwards the default scene (with its World)
    for the tests that follow, and the add-on unregistered."""
    write_person_png(folder / "person.png")
    blender_addon.register()
    bpy.ops.wm.read_homefile(use_empty=True)
    s = bpy.context.scene.relight_photo
    if model is not None:
        s.model_path, s.quality, s.mask_mode = str(model), "DRAFT", "NETWORK"
        s.light_kind, s.preset = "PRESET", "studio"
    for name, value in settings.items():
        setattr(s, name, value)
    yield s
    bpy.ops.wm.read_homefile()
    blender_addon.unregister()
