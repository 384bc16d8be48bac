"""Why the farm's local pool is not concurrent.futures.ProcessPoolExecutor (farm/execution/executors.py).

    .venv/bin/python benchmarks/studies/process_pool_timeout.py

Two workers: one task hangs, the other is 2.5 s from done. The per-scene
timeout would SIGKILL the hung task's process; this prints what becomes of
the hung future, the healthy one, and the next submit. On Python 3.11 all
three raise BrokenProcessPool: one timeout loses every in-flight task and the
whole pool (whose workers would each import bpy again).
"""

from __future__ import annotations

import concurrent.futures as cf
import multiprocessing as mp
import os
import signal
import sys
import tempfile
import time
from pathlib import Path


def _task(seconds: float, pid_file: str) -> float:
    Path(pid_file).write_text(str(os.getpid()))
    time.sleep(seconds)
    return seconds


def _outcome(future: cf.Future) -> str:
    try:
        return f"result {future.result(timeout=10)!r}"
    except Exception as exc:  # any type: what it raises is the finding
        return type(exc).__name__


def main() -> None:
    with tempfile.TemporaryDirectory() as tmp:
        hung_pid = Path(tmp) / "hung.pid"
        pool = cf.ProcessPoolExecutor(2, mp_context=mp.get_context("forkserver"), max_tasks_per_child=5)
        hung = pool.submit(_task, 60.0, str(hung_pid))
        healthy = pool.submit(_task, 3.0, str(Path(tmp) / "healthy.pid"))
        deadline = time.monotonic() + 10
        while not hung_pid.exists() or not hung_pid.read_text():
            if time.monotonic() > deadline:
                raise SystemExit("the hung task never started")
            time.sleep(0.05)
        time.sleep(0.5)
        os.kill(int(hung_pid.read_text()), signal.SIGKILL)  # what the per-scene timeout does
        print(f"python {sys.version.split()[0]}")
        print(f"hung task:            {_outcome(hung)}")
        print(f"healthy task (3 s):   {_outcome(healthy)}")
        try:
            nxt = _outcome(pool.submit(_task, 0.0, str(Path(tmp) / "next.pid")))
        except cf.process.BrokenProcessPool as exc:  # submit itself refuses
            nxt = type(exc).__name__
        print(f"next submit:          {nxt}")
        pool.shutdown(wait=True, cancel_futures=True)


if __name__ == "__main__":
    main()
