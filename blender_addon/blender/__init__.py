"""The add-on's Blender layer, the only modules that import bpy (each named bl_*, kept thin): settings
and panel, operators, handlers and timers, the context's photo and session, image datablocks and
layers, the World and its dials, Photo Light -> World, Compositing Setup, save and reopen, Relight
Sequence.
"""
