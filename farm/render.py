"""Render-farm entry point for real Blender and for plain Python.

    blender -b -P farm/render.py -- --out DIR --scenes N --seed S [options]
    python farm/render.py -- --out DIR --scenes N --seed S [options]

Arguments after "--" are the farm's (see `python -m farm --help`).
"""

import os
import sys
from pathlib import Path

# Blender's bundled Python sees neither the venv nor this repository, and the
# script's own folder (farm/) must not shadow top-level modules: put the
# repository root first instead.
_FARM_DIR = Path(__file__).resolve().parent
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _FARM_DIR]
sys.path.insert(0, str(_FARM_DIR.parent))

from farm.cli import main  # noqa: E402


def _farm_argv(argv):
    """The farm's arguments: those after '--' (Blender passes its own before it)."""
    return argv[argv.index("--") + 1:] if "--" in argv else argv[1:]


if __name__ == "__main__":
    code = main(_farm_argv(sys.argv))
    sys.stdout.flush()
    sys.stderr.flush()
    # Under Blender, sys.exit inside -P is reported but Blender would go on to
    # its own event handling; leave at once with the farm's exit code.
    os._exit(code)
