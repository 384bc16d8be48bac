"""The tests' tiny exported model (no bpy, no torch in this process): a seeded random-weight
RelightNet exported by the project's export code in a child process, made once per session."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
ORDER = 4  # its SH order


def make_tiny_model(tmp_path_factory) -> Path:
    """The model's path under the session's base temporary folder, exported there on the first call.
    In a child process so that torch never loads into a bpy process."""
    out = tmp_path_factory.getbasetemp() / "addon_tiny_model" / "tiny.onnx"
    if out.is_file():
        return out
    out.parent.mkdir(exist_ok=True)
    code = textwrap.dedent(f"""
        from export.random_model import export_random_model
        export_random_model({str(out)!r}, seed=3, sh_order={ORDER}, width=4, depth=2)
    """)
    # Blender 5.1+ bundles Python 3.13, for which no CPU torch is at hand: the make test
    # run under bpy 5.2 names the 3.11 interpreter that has torch (RELIGHT_TORCH_PYTHON)
    python = os.environ.get("RELIGHT_TORCH_PYTHON", sys.executable)
    subprocess.run([python, "-c", code], cwd=REPO, check=True, capture_output=True, timeout=300)
    return out
