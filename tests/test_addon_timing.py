"""Relight Photo add-on: the seconds a report gives are the seconds the press took (issue 40).

A World edit (here a Sky Texture's sun) changes the World's light; Blender brings the scene up
to date before it runs the next operator, and there the add-on's depsgraph handler reads the
new light: a Cycles bake of the sky (0.6-1.2 s on the issue's machine). Relight then said
"Relit ... in 0.1 s" for a press that took seconds. Pressed as a script's click does
(bpy.ops, which updates the scene first), the report's seconds are compared with the wall time
of the whole call, measured outside it.
"""

from __future__ import annotations

import re
import time

import pytest

import bpy

import blender_addon
from addon_support import new_node_world, write_person_png


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


def _reported_seconds(message: str) -> float:
    return float(re.match(r"Relit .* in (\d+\.\d) s", message).group(1))


def test_the_relight_report_counts_the_world_bake_of_the_press(sky_scene):
    name, sky = sky_scene
    status = bpy.context.window_manager.relight_photo_status
    start = time.monotonic()
    assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
    first = time.monotonic() - start
    assert _reported_seconds(status.message) >= first - 0.15  # baked inside the operator: counted already
    for elevation in (0.2, 0.9):
        sky.sun_elevation = elevation  # the World edit: its light is baked again at the next press
        start = time.monotonic()
        assert bpy.ops.relight_photo.relight(image_name=name, synchronous=True) == {"FINISHED"}
        wall = time.monotonic() - start
        reported = _reported_seconds(status.message)
        assert wall > 0.3, "the sky was not baked again: the test no longer shows the case"
        # the report rounds to 0.1 s and misses only Blender's own steps around the operator
        assert wall - 0.15 <= reported <= wall + 0.05, (status.message, wall)
        baked = float(re.search(r"reading the World's light (\d+\.\d) s", status.message).group(1))
        assert baked >= 0.5 * wall, status.message
