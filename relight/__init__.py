"""relight: torch-free, bpy-free core of single-image full-body human relighting.

Submodules are imported on demand (relight.sh, relight.prt, relight.exr, ...);
nothing here imports torch or bpy.
"""

__version__ = "0.1.0"
