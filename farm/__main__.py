"""`python -m farm ...`: the render farm with the bpy module (same parser as farm/render.py)."""

import sys

from farm.cli import main

if __name__ == "__main__":
    sys.exit(main())
