"""Farm worker: imports the scene module (and so bpy) once, then renders the scenes it is sent.

Protocol: one JSON object per line. The parent writes tasks {"index": i, "seed": s}
to stdin and closes stdin to retire the worker; the worker answers on its
original stdout with {"event": "ready"}, {"event": "done", ...} or
{"event": "failed", ...}. Everything else the worker or Blender prints goes to
stderr, so Cycles' chatter can never corrupt the protocol.

Run as `python -m farm.worker ...` or `blender -b -P farm/worker.py -- ...`.
"""

from __future__ import annotations

import sys
from pathlib import Path

if __name__ == "__main__" and __package__ in (None, ""):
    # Started as a script (Blender -P): Blender's Python does not see the venv or
    # the repository, and the script folder must not shadow top-level modules.
    _farm_dir = Path(__file__).resolve().parent
    sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != _farm_dir]
    sys.path.insert(0, str(_farm_dir.parent))

import argparse
import faulthandler
import json
import os
import traceback

from farm.execution.scene_job import load_job, render_one


def serve(job_module: str, settings: dict, out_dir: Path, reply) -> int:
    """Worker loop: answer 'ready', then one reply per task line until stdin closes."""

    def send(message: dict) -> None:
        reply.write((json.dumps(message) + "\n").encode())
        reply.flush()

    options_class, render_scene = load_job(job_module)
    options = options_class.from_json(settings)
    send({"event": "ready", "pid": os.getpid()})
    for line in sys.stdin.buffer:
        if not line.strip():
            continue
        task = json.loads(line)
        message = render_one(render_scene, options, int(task["index"]), int(task["seed"]), out_dir)
        message["pid"] = os.getpid()
        send(message)
    return 0


def _script_argv(argv: list[str]) -> list[str]:
    """Arguments after '--' when run under Blender, else all of them."""
    return argv[argv.index("--") + 1:] if "--" in argv else argv


def main(argv: list[str] | None = None) -> int:
    argv = _script_argv(sys.argv[1:] if argv is None else argv)
    parser = argparse.ArgumentParser(prog="farm.worker")
    parser.add_argument("--job-module", required=True)
    parser.add_argument("--out", type=Path, required=True)
    parser.add_argument("--options", required=True, help="scene settings as JSON")
    args = parser.parse_args(argv)
    # Keep the protocol on a private copy of stdout; point fd 1 (C and Python
    # prints, Cycles' progress lines) at stderr.
    sys.stdout.flush()
    reply = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    # A crash inside bpy/Cycles (SIGSEGV, SIGABRT) leaves the Python stack in the worker log.
    faulthandler.enable(file=sys.stderr, all_threads=True)
    try:
        return serve(args.job_module, json.loads(args.options), args.out, reply)
    except Exception:
        traceback.print_exc(file=sys.stderr)  # the parent shows the log's last line
        return 1


if __name__ == "__main__":
    code = main()
    sys.stdout.flush()
    sys.stderr.flush()
    # os._exit: skip bpy's atexit teardown, slow and sometimes noisy after many renders.
    os._exit(code)
