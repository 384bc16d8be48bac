"""The add-on's decisions, without bpy: a photo's pixels and the photos refused before the network,
buffers in Blender's layout, which mask the network gets, the panel's light sources as SH, output
names, the quality presets as an enum, and what Photo Light -> World builds.
"""
