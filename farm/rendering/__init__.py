"""A drawn scene to pixels: the per-vertex SH transport bake and the body pass (ray casting, numpy +
embreex), and Blender's side (bpy): Cycles materials, the scene with its AOV routing, and the render
calls.
"""
