"""What the add-on's tests share: a person photo, image pixels, a World with nodes on every
Blender, the N-panel drawn into a layout that checks it, the add-on in an empty scene, and a
relit photo's session and World map. The tiny model is tests/support/tiny_model.py (no bpy)."""

from __future__ import annotations

import contextlib
import types
from pathlib import Path

import numpy as np

import bpy

import blender_addon

H, W = 72, 48


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


def cube(location, size: float):
    """A cube mesh object of edge `size` (m) centred at `location`, linked to the scene."""
    mesh = bpy.data.meshes.new("cube")
    h = size / 2
    corners = [(x, y, z) for x in (-h, h) for y in (-h, h) for z in (-h, h)]
    faces = [(0, 1, 3, 2), (4, 6, 7, 5), (0, 4, 5, 1), (2, 3, 7, 6), (0, 2, 6, 4), (1, 5, 7, 3)]
    mesh.from_pydata(corners, [], faces)
    obj = bpy.data.objects.new("cube", mesh)
    obj.location = location
    bpy.context.scene.collection.objects.link(obj)
    return obj


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


def draft_photo(model: Path, folder: Path) -> str:
    """The person photo (`folder`/person.png) loaded, the panel at Draft with `model`, the network's
    matte, the studio preset and neutral dials; its image name."""
    photo = bpy.data.images.load(str(folder / "person.png"))
    s = bpy.context.scene.relight_photo
    s.model_path, s.quality, s.mask_mode = str(model), "DRAFT", "NETWORK"
    s.light_kind, s.preset = "PRESET", "studio"
    s.rotation, s.exposure, s.strength = 0.0, 0.0, 1.0
    return photo.name


def relit_photo(model: Path, folder: Path) -> str:
    """draft_photo relit (synchronously); its image name."""
    name = draft_photo(model, folder)
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    return name


def photo_session(name: str):
    """The add-on's session (blender_addon.worker.state.PhotoSession) of the photo image `name`."""
    from blender_addon.blender import bl_images
    from blender_addon.worker import state

    return state.SESSIONS[bpy.data.images[name][bl_images.PHOTO_ID]]


def world_map_pixels(world) -> np.ndarray:
    """The RGB pixels of the Environment Texture of `world` (Photo Light -> World's map)."""
    texture = next(n for n in world.node_tree.nodes if n.type == "TEX_ENVIRONMENT")
    return pixels(texture.image.name)[..., :3]
