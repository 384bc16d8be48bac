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


# issue 49: relight image's path with --quality best at 1b569f7 (before the request values, the SH
# order checked once and the merged relight / layers): 258 hops, 78 returns, 68 of them within
# run_image; after: 253, 68 and 58; at adeaf18 251, 66 and 56. The path's second pass (the EXR
# map's layout read once, the group's mattes and the working-size crop made once and passed on,
# one-call helpers folded): 227, 57 and 47. The ceilings leave a hop or two for the core's other rooms.
CEILINGS = {"function hops (distinct edges)": 229, "returns to a module already left": 59,
            "within run_image: returns": 49}


def test_relight_images_path_stays_under_its_ceilings():
    res = subprocess.run([sys.executable, str(ROOT / "tools" / "trace_hops.py"), "--quality", "best",
                          "--from", "run_image"], capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr
    figures = {line.rsplit(None, 1)[0]: int(line.split()[-1]) for line in res.stdout.splitlines()
               if line.rsplit(None, 1)[0] in CEILINGS}
    assert figures.keys() == CEILINGS.keys(), res.stdout
    assert all(figures[k] <= CEILINGS[k] for k in CEILINGS), figures


def test_from_counts_the_returns_within_one_call_from_its_module_on():
    # the calls below the scope's call a.f: its module a first; b entered, a entered again (a return),
    # b again (one more)
    tracer = trace_hops.Tracer("f")
    calls = [("relight/b.py", "relight/a.py", "relight/a.py:f", "relight/b.py:g"),
             ("relight/a.py", "relight/b.py", "relight/b.py:g", "relight/a.py:h"),
             ("relight/b.py", "relight/a.py", "relight/a.py:h", "relight/b.py:k")]
    for module, caller_module, caller, callee in calls:
        tracer.scoped.record("MainThread", module, caller_module, caller, callee)
    hops, returns = trace_hops.count(tracer.scoped, "relight/a.py:f")
    assert len(hops) == 3 and returns == {"relight/a.py": 1, "relight/b.py": 1}
    # without the scope's module as the start, entering a from x is no return
    assert trace_hops.count(tracer.scoped)[1] == {"relight/b.py": 1}
