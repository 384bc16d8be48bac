"""relight: torch-free, bpy-free core of single-image full-body human relighting.

Submodules are imported on demand (relight.lighting.sh, relight.network.prt, relight.files.exr, ...);
nothing here imports torch or bpy. `from relight import Relighter` (and
Decomposition, SHLight, sh_light) works, and loads its module (numpy, onnxruntime)
only then: `import relight` stays light.
"""

__version__ = "0.1.0"

_LAZY = ("Relighter", "Decomposition", "SHLight", "sh_light")


def __getattr__(name: str):
    if name in ("Relighter", "Decomposition"):
        from relight.network import runtime

        return getattr(runtime, name)
    if name in ("SHLight", "sh_light"):
        from relight.lighting import light

        return getattr(light, name)
    raise AttributeError(f"module 'relight' has no attribute {name!r}")


def __dir__():
    return sorted([*globals(), *_LAZY])
