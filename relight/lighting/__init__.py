"""Light as spherical harmonics: the SH basis and its checks, equirect maps projected to SH, rotations,
the order a light needs; any light source (a map file, a preset, Blender's lamps, World pixels,
another photo) resolved to SH coefficients, and an SH light turned back into what Blender shows (an
equirect map, a key light and a smooth World).
"""
