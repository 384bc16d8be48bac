"""Relight Photo add-on: the seconds a report gives are the seconds the press took (issue 40).

A World edit (here a Sky Texture's sun) changes the World's light; Blender brings the scene up
to date before it runs the next operator, and there the add-on's depsgraph handler reads the
new light: a Cycles bake of the sky (0.6-1.2 s on the issue's machine). Relight then said
"Relit ... in 0.1 s" for a press that took seconds. Pressed as a script's click does
(bpy.ops, which updates the scene first). The add-on's clock is a stand-in that moves only
when a bake runs (BAKE_SECONDS each): the report must count every bake of the press, once,
whatever the machine's load (issue 48: a wall-time bound failed under load).
"""

from __future__ import annotations

import re
import types

import pytest

import bpy

import blender_addon
from blender_addon.blender import bl_ops, bl_session, bl_world
from addon_support import new_node_world, write_person_png

BAKE_SECONDS = 2.0  # what the stand-in clock moves by during one bake of the World


@pytest.fixture
def sky_scene(model, tmp_path):
    write_person_png(tmp_path / "person.png")
    blender_addon.register()
    bpy.ops.wm.read_homefile(use_empty=True)
    s = bpy.context.scene.relight_photo
    s.model_path, s.quality, s.mask_mode = str(model), "DRAFT", "NETWORK"
    world = new_node_world("sky")
    tree = world.node_tree
    background = next(n for n in tree.nodes if n.type == "BACKGROUND")
    sky = tree.nodes.new("ShaderNodeTexSky")
    tree.links.new(sky.outputs["Color"], background.inputs["Color"])
    bpy.context.scene.world = world
    s.light_kind = "WORLD"
    yield bpy.data.images.load(str(tmp_path / "person.png")).name, sky
    bpy.ops.wm.read_homefile()
    blender_addon.unregister()


class _BakeClock:
    """time.monotonic for the add-on's bl_session and bl_ops: still, except that each bake of the
    World moves it by BAKE_SECONDS (half before the render, half after). Records the bakes."""

    def __init__(self, monkeypatch):
        self.now, self.bakes = 1000.0, 0
        bake = bl_world.bake_world

        def timed_bake(*args, **kw):  # the clock moves before and after the depsgraph updates the bake makes
            self.bakes += 1
            self.now += BAKE_SECONDS / 2
            try:
                return bake(*args, **kw)
            finally:
                self.now += BAKE_SECONDS / 2

        monkeypatch.setattr(bl_world, "bake_world", timed_bake)
        clock = types.SimpleNamespace(monotonic=lambda: self.now)
        monkeypatch.setattr(bl_session, "time", clock)
        monkeypatch.setattr(bl_ops, "time", clock)


def _report(message: str) -> tuple[float, float]:
    """(the press's seconds, of which reading the World's light) as the report gives them."""
    wall = float(re.match(r"Relit .* in (\d+\.\d) s", message).group(1))
    world = re.search(r"reading the World's light (\d+\.\d) s", message)
    return wall, float(world.group(1)) if world else 0.0


def test_the_relight_report_counts_the_world_bake_of_the_press(sky_scene, monkeypatch):
    name, sky = sky_scene
    clock = _BakeClock(monkeypatch)
    status = bpy.context.window_manager.relight_photo_status
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    assert clock.bakes == 1  # read inside the operator, before the network
    assert _report(status.message) == (BAKE_SECONDS, BAKE_SECONDS), status.message
    for presses, elevation in enumerate((0.2, 0.9), start=2):
        sky.sun_elevation = elevation  # the World edit: its light is baked again at the next press
        assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
        # baked once, in the scene update Blender runs before the operator (the operator reads the cache)
        assert clock.bakes == presses, "the sky was not baked again: the test no longer shows the case"
        assert _report(status.message) == (BAKE_SECONDS, BAKE_SECONDS), status.message
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    assert clock.bakes == 3 and _report(status.message) == (0.0, 0.0), status.message  # no edit: no bake
