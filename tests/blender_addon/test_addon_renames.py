"""Relight Photo add-on: a renamed photo's outputs take its new name at once, on every Blender (issue 48).

Blender 5 sends a depsgraph update for a rename, which the add-on's handler takes; Blender 4.2
sends none, and the outputs kept the old name until the next dial. Every Blender publishes the
name on its message bus, which its main loop delivers (headless bpy has no main loop: the test
delivers it as that loop would, to the subscriptions the add-on made through bpy.msgbus).
"""

from __future__ import annotations

import pytest

import bpy

from addon_support import addon_in_empty_scene, relit_photo

LAYERS = ("albedo", "alpha", "relit", "residual", "shading")


@pytest.fixture
def subscriptions(monkeypatch):
    """Every live bpy.msgbus.subscribe_rna call (key, notify, owner), as Blender keeps them."""
    live = []
    subscribe, clear = bpy.msgbus.subscribe_rna, bpy.msgbus.clear_by_owner

    def recording_subscribe(**kw):
        live.append(kw)
        return subscribe(**kw)

    def recording_clear(owner):
        live[:] = [s for s in live if s["owner"] is not owner]
        return clear(owner)

    monkeypatch.setattr(bpy.msgbus, "subscribe_rna", recording_subscribe)
    monkeypatch.setattr(bpy.msgbus, "clear_by_owner", recording_clear)
    return live


def _deliver_rename(live, image) -> int:
    """What Blender's main loop does after `image.name = ...`: call the subscriptions to an image's
    name (its type's or that image's). Returns how many were called."""
    called = 0
    for s in list(live):
        target, prop = s["key"]
        if prop == "name" and (target in (bpy.types.Image, bpy.types.ID) or target == image):
            s["notify"](*s.get("args", ()))
            called += 1
    return called


def _outputs_named(prefix: str) -> set:
    return {i.name for i in bpy.data.images if i.name.startswith(prefix + ".")}


def test_a_renamed_photo_renames_its_outputs_at_once(subscriptions, model, tmp_path):
    with addon_in_empty_scene(tmp_path, model):
        name = relit_photo(model, tmp_path)
        photo = bpy.data.images[name]
        relit = bpy.data.images[f"{name}.relit"].as_pointer()
        photo.name = "renamed.png"
        bpy.context.view_layer.update()  # the depsgraph update a rename brings (Blender 5; none on 4.2)
        assert _deliver_rename(subscriptions, photo) >= 1  # the add-on listens on the message bus
        assert _outputs_named("renamed.png") >= {f"renamed.png.{layer}" for layer in LAYERS}
        assert not _outputs_named(name)
        assert bpy.data.images["renamed.png.relit"].as_pointer() == relit  # the same datablock, renamed
        # a file load clears Blender's subscriptions: the add-on subscribes again
        blend = tmp_path / "shot.blend"
        assert bpy.ops.wm.save_as_mainfile(filepath=str(blend)) == {"FINISHED"}
        subscriptions.clear()  # what the load clears in Blender
        bpy.ops.wm.open_mainfile(filepath=str(blend))
        photo = bpy.data.images["renamed.png"]
        photo.name = "again.png"
        assert _deliver_rename(subscriptions, photo) >= 1
        assert _outputs_named("again.png") >= {f"again.png.{layer}" for layer in LAYERS}
        assert not _outputs_named("renamed.png")
