"""The drawn scene, without Blender: the person's body and pose, the camera framings, the light (HDR
maps, skies and hard lights as SH), and what the person wears and looks like (outfit, garments,
hair, faces, mesh helpers, material parameters, prints), as numpy meshes and parameter dicts.
"""
