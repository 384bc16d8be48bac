"""Worker processes of the local farm pool: start, pin, talk to, retire and kill one.

A worker is `python -m farm.worker` (or the Blender binary with -P under real
Blender) in its own session and temp folder, pinned to its share of the cores,
killed with the parent (PR_SET_PDEATHSIG). It imports bpy once and answers
JSON lines (farm/worker.py has the protocol); a reader thread turns them into
events on the executor's queue, and EOF into a None event.
"""

from __future__ import annotations

import ctypes
import datetime
import functools
import json
import os
import queue
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

from farm.execution.run_config import RunConfig

REPO_ROOT = Path(__file__).resolve().parent.parent.parent

_PR_SET_PDEATHSIG = 1


def _die_with_parent() -> None:
    """In the child before exec: get SIGKILL when the farm process dies (Linux)."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_PDEATHSIG, signal.SIGKILL)
    except (OSError, AttributeError):
        pass


def worker_cpus(slot: int, workers: int, available: set[int]) -> set[int] | None:
    """The cores worker `slot` is pinned to: an equal, disjoint share when there are at
    least as many cores as workers, else None (no pinning).

    Pinned, each worker's idle library threads (TBB, OpenMP, OpenBLAS) stay on its
    own cores instead of spinning on another worker's: 20% less CPU per scene
    measured (docs/benchmarks/farm_render.md).
    """
    cores = sorted(available)
    if workers < 1 or workers > len(cores):
        return None
    share = len(cores) // workers
    return set(cores[slot * share : (slot + 1) * share])


def _start_child(cpus: set[int] | None) -> None:
    """In the child before exec: die with the parent, then pin to `cpus`."""
    _die_with_parent()
    if cpus:
        os.sched_setaffinity(0, cpus)


def worker_command(config: RunConfig) -> list[str]:
    """Command starting one worker: the running Blender binary under Blender, else this Python."""
    args = ["--job-module", config.job_module, "--out", str(config.out),
            "--options", json.dumps(config.scene.to_json())]
    bpy = sys.modules.get("bpy")
    blender = getattr(getattr(bpy, "app", None), "binary_path", "") if bpy else ""
    if blender:  # real Blender: its bundled Python cannot import the bpy wheel
        return [blender, "-b", "--factory-startup", "-noaudio", "-P",
                str(REPO_ROOT / "farm" / "worker.py"), "--", *args]
    return [sys.executable, "-m", "farm.worker", *args]


class _Worker:
    """One worker process and the thread that turns its stdout lines into queue events."""

    def __init__(self, slot: int, command: list[str], log_path: Path, events: queue.Queue, threads: int,
                 cpus: set[int] | None = None):
        self.slot = slot
        self.ready = False
        self.task: int | None = None
        self.deadline = 0.0
        self.assigned = 0
        self.started = time.monotonic()
        self.log_path = log_path
        env = dict(os.environ)
        env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO_ROOT), env.get("PYTHONPATH")) if p)
        # A private temp folder: whatever scratch a killed worker leaves (Cycles' EXRs)
        # is removed with it.
        self.tmp = Path(tempfile.mkdtemp(prefix=f"farm_worker{slot}_"))
        env["TMPDIR"] = str(self.tmp)
        env.setdefault("PYTHONUNBUFFERED", "1")
        # W workers share the machine's cores: Cycles threads per worker (farm.rendering.passes reads it).
        env.setdefault("RELIGHT_CYCLES_THREADS", str(threads))
        for name in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
            env.setdefault(name, str(threads))
        with open(log_path, "ab") as log:
            log.write(f"--- worker start {datetime.datetime.now().isoformat()}\n".encode())
            log.flush()
            self.proc = subprocess.Popen(
                command, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=log,
                env=env, cwd=str(REPO_ROOT), start_new_session=True,
                preexec_fn=functools.partial(_start_child, cpus),
            )
        self.pid = self.proc.pid
        threading.Thread(target=self._read, args=(events,), daemon=True).start()

    def _read(self, events: queue.Queue) -> None:
        for line in self.proc.stdout:
            try:
                message = json.loads(line)
            except ValueError:
                continue  # e.g. Blender's start-up banner, printed before the worker script runs
            if isinstance(message, dict) and "event" in message:
                events.put((self, message))
        events.put((self, None))

    def send(self, index: int, seed: int) -> bool:
        try:
            self.proc.stdin.write((json.dumps({"index": index, "seed": seed}) + "\n").encode())
            self.proc.stdin.flush()
            return True
        except (BrokenPipeError, OSError):
            return False

    def retire(self) -> None:
        """Close stdin: the worker finishes and exits (reaped later)."""
        try:
            self.proc.stdin.close()
        except OSError:
            pass

    def kill(self) -> None:
        """SIGKILL the worker's process group and wait until it is gone, so that
        nothing it was writing can still land after the caller looks at the files."""
        try:
            os.killpg(self.proc.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.retire()
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            return  # unkillable (D state); reaped at shutdown
        self.remove_tmp()

    def remove_tmp(self) -> None:
        """Delete the worker's temp folder (only once the process is gone)."""
        shutil.rmtree(self.tmp, ignore_errors=True)

    def release(self) -> None:
        """Once the process is gone: delete its temp folder and close its pipes."""
        self.remove_tmp()
        for stream in (self.proc.stdin, self.proc.stdout):
            try:
                stream.close()
            except OSError:
                pass

    def exit_description(self) -> str:
        try:
            code = self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            return "worker closed its pipe but did not exit"
        if code < 0:
            return f"worker {self.pid} killed by {signal.Signals(-code).name}"
        return f"worker {self.pid} exited with code {code}"

    def last_log_line(self) -> str:
        try:
            lines = [ln.strip() for ln in self.log_path.read_text(errors="replace").splitlines() if ln.strip()]
        except OSError:
            return ""
        return lines[-1][:300] if lines else ""

