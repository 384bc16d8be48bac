"""Relight Photo: relight a person in a photo from Blender's Image Editor.

The Blender-facing modules (bl_*, in blender/) are thin; everything else is plain Python that imports
without bpy: logic/ (the add-on's decisions: photo checks and pixels, masks, light sources, quality,
output names, the photo's light, the person proxy's mesh), worker/ (the work off Blender's main thread:
engine, jobs, state, work, people, save_layers, sequence) and, beside this file, build and manifest, so
`python -m blender_addon.build` runs outside Blender.
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
