"""tools/trace_hops.py (issue 39): the hops a photo takes through relight/ while `relight image` relights it."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
sys.path.insert(0, str(ROOT / "tools"))

import trace_hops  # noqa: E402


def test_counts_are_stable_and_name_modules_by_file():
    # each run in a fresh process, as the counts are defined: a second run in one process
    # skips what the first one cached (sessions, tables) and takes fewer hops
    counts = []
    for _ in range(2):
        res = subprocess.run([sys.executable, str(ROOT / "tools" / "trace_hops.py"), "--quality", "draft",
                              "--by-caller", "--calls", "sh.py:validate_coeffs"],
                             capture_output=True, text=True, timeout=300)
        assert res.returncode == 0, res.stderr
        lines = res.stdout.splitlines()
        counts.append([line for line in lines if line.startswith(("function hops", "returns to a module"))])
        # the hop list starts at the command's entry point and reads the photo on its own thread
        assert lines[0].startswith("wrote ") and lines[1].startswith("cli.main -> cli.build_parser")
        assert "photo.read_photo" in res.stdout and "[relight-read_0]" in res.stdout
        assert "calls of relight/lighting/sh.py:validate_coeffs" in res.stdout
    assert counts[0] == counts[1] and len(counts[0]) == 2 and int(counts[0][0].split()[-1]) > 50


def test_a_module_moved_into_a_subpackage_keeps_its_file_name():
    tracer = trace_hops.Tracer()
    assert tracer.module(str(trace_hops.PACKAGE / "io" / "photo.py")) == "relight/io/photo.py"
    assert tracer.module(str(ROOT / "tools" / "trace_hops.py")) is None
    hops = [("MainThread", "relight/a.py:f", "relight/b.py:g", None), ("MainThread", "relight/b.py:g", "relight/a.py:h", "relight/a.py")]
    assert trace_hops.by_caller(hops) == "a.f -> b.g\nb.g -> a.h*"
