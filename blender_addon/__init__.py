"""Relight Photo: relight a person in a photo from Blender's Image Editor.

The Blender-facing modules (bl_*, in blender/) are thin; the logic lives in plain-Python
modules (worker/, logic/ and beside this file: output_names, photo_pixels, photo_checks, pixel_buffers, mask_choice,
light_sources, work, quality, jobs, state, engine, sequence, photo_light, build,
manifest) that import
without bpy, so `python -m blender_addon.build` runs outside Blender.
"""

_REGISTERED = []


def register():
    from .blender import bl_compositing, bl_ops, bl_photo_world, bl_props, bl_sequence, bl_ui

    for module in (bl_props, bl_ops, bl_photo_world, bl_compositing, bl_sequence, bl_ui):
        module.register()
        _REGISTERED.append(module)


def unregister():
    from .worker import state

    while _REGISTERED:
        _REGISTERED.pop().unregister()
    state.clear()
