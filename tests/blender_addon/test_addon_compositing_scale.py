"""Relight Photo add-on: Compositing Setup renders the whole photo at any Resolution % (issue 40).

With the render resolution at 25 %, F12 gave the middle of the unscaled photo (a quarter of
each side) behind the render: the compositor centres an image at its own size. The photo
behind the render must scale with the render. Rendered as F12 does (render.render, Cycles,
the composite written), under each Blender.
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest

import bpy

from relight.files import exr
from relight.imaging.resample import resize_linear
from addon_support import H, W


def _render(folder, percentage: int) -> np.ndarray:
    """F12 at `percentage`: the composite's RGB, top row first."""
    scene = bpy.context.scene
    scene.render.resolution_percentage = percentage
    scene.cycles.samples = 4
    scene.cycles.use_denoising = False
    scene.cycles.device = "CPU"
    scene.render.image_settings.file_format = "OPEN_EXR"
    scene.render.image_settings.color_depth = "32"
    out = folder / f"composite_{percentage}.exr"
    scene.render.filepath = str(out)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        bpy.ops.render.render(write_still=True)
    planes = exr.read_exr(out)
    return np.stack([planes[c] for c in "RGB"], -1)


@pytest.mark.parametrize("percentage", [25, 50])
def test_the_whole_photo_is_behind_the_render_at_any_resolution_percentage(addon, percentage):
    from blender_addon.blender import bl_images
    from blender_addon.worker import state

    photo = bpy.data.images.load(str(addon / "person.png"))
    assert bpy.ops.relight_photo.relight(image_name=photo.name, synchronous=True) == {"FINISHED"}
    assert bpy.ops.relight_photo.compositing_setup(image_name=photo.name) == {"FINISHED"}
    for what in ("person", "person_shadow"):  # the random network's person is the whole photo, its relief
        bpy.data.objects[f"{photo.name}.{what}"].hide_render = True  # metres deep (tests/blender_addon/test_addon_proxy.py)
    linear = state.SESSIONS[photo[bl_images.PHOTO_ID]].photo  # as the add-on decoded it
    composite = _render(addon, percentage)
    h, w = H * percentage // 100, W * percentage // 100
    assert composite.shape == (h, w, 3)
    whole = resize_linear(linear, h, w)  # the whole photo at the render's size
    top, left = (H - h) // 2, (W - w) // 2
    middle = linear[top:top + h, left:left + w]  # what the composite showed: the unscaled photo's middle
    off_whole = np.abs(composite - whole).mean()
    off_middle = np.abs(composite - middle).mean()
    print(f"{percentage} %: |composite - whole photo scaled| {off_whole:.4f}, - its middle {off_middle:.4f}")
    # a filter's difference only (bilinear against area at a 2-4x reduction, on a textured background)
    assert off_whole < 0.05 and off_whole < 0.25 * off_middle
    # the background's blue at the corners, where the middle crop had only the person's skin
    assert composite[0, 0, 2] > composite[0, 0, 0] and composite[-1, -1, 2] > composite[-1, -1, 0]
    # at 100 % the photo is the render's size: unscaled, as before
    full = _render(addon, 100)
    np.testing.assert_allclose(full, linear, atol=2e-3)
