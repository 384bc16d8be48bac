"""The add-on's work off Blender's main thread, without bpy: the engine (the only caller of the core's
runtime and matte), what the worker threads do, a worker thread polled from the main thread, the
sequence's frame loop, and what the add-on remembers between runs.
"""
