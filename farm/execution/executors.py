"""The local executor of the render farm: the scheduling loop over a pool of worker processes.

`run_local` renders the run's scenes with W workers (farm.execution.pool) on this machine.
The loop sends one scene at a time to each ready worker, enforces the per-scene
timeout by SIGKILLing that worker's process group, retries a failed scene (up to
--retries) in a fresh worker, retires a worker after `recycle` scenes or after
any failure, checks free disk space before each scene and validates every scene
it is told about (farm.execution.outputs); the run book (farm.execution.runbook) records it all.

Why not concurrent.futures.ProcessPoolExecutor (max_tasks_per_child would give
the recycling): it cannot stop one hung task. future.result(timeout) only stops
waiting, the pool does not say which process runs which task, and killing that
process breaks the whole pool. benchmarks/studies/process_pool_timeout.py shows it
(Python 3.11, 2 workers, one task hung and SIGKILLed, the other 2.5 s from
done): the hung future, the healthy one and the next submit all raise
BrokenProcessPool, so one timeout would lose every in-flight scene and need a
new pool whose workers all import bpy again. Here a timeout costs the hung
scene's worker only. What the library would save is small: this loop's own cost
is 7 to 17 ms of worker time per scene, validation included (`bench_farm.py
--runner-only 200 --workers 1`, 2-core machine idle to loaded), against seconds
to minutes of rendering per scene.
"""

from __future__ import annotations

import collections
import os
import queue
import signal
import subprocess
import sys
import threading
import time

from farm.execution.outputs import WORKER_LOG_DIR, check_scene, disk_room, plan_run, remove_partial_files
from farm.execution.pool import _Worker, worker_command, worker_cpus
from farm.execution.run_config import FarmError, RunConfig
from relight.models.session import cores_available
from farm.execution.runbook import RunBook, Summary

MAX_START_FAILURES = 3


class LocalExecutor:
    """A pool of recycled worker processes on this machine."""

    def __init__(self, config: RunConfig, book: RunBook, todo: list[int]):
        self.config = config
        self.book = book
        self.pending = collections.deque(todo)
        self.events: queue.Queue = queue.Queue()
        self.slots: list[_Worker | None] = [None] * config.workers
        self.retiring: list[_Worker] = []
        self.command = worker_command(config)
        # the cores this run may use; pinning needs the affinity API (Linux)
        self.cores = os.sched_getaffinity(0) if hasattr(os, "sched_getaffinity") else None
        self.threads = max(1, cores_available() // config.workers)
        self.log_dir = config.out / WORKER_LOG_DIR
        self.log_dir.mkdir(exist_ok=True)
        self.start_failures = 0
        self.ever_ready = False
        self.largest_scene = 0

    # -- worker lifecycle ------------------------------------------------
    def _spawn(self, slot: int) -> None:
        self.book.workers_started += 1
        log = self.log_dir / f"worker{slot}.log"
        cpus = worker_cpus(slot, self.config.workers, self.cores) if self.config.pin and self.cores else None
        self.slots[slot] = _Worker(slot, self.command, log, self.events, self.threads, cpus)

    def _drop(self, worker: _Worker, kill: bool) -> None:
        if self.slots[worker.slot] is worker:
            self.slots[worker.slot] = None
        worker.kill() if kill else worker.retire()
        self.retiring.append(worker)

    def _reap(self, worker: _Worker) -> None:
        """A dropped worker that closed its output: wait for it, delete its temp folder and close
        its pipes now, so a long run keeps no exited processes, pipes or scratch of past workers
        (one per `recycle` scenes) until it ends. One still running stays for the shutdown."""
        try:
            worker.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            return
        worker.release()
        if worker in self.retiring:
            self.retiring.remove(worker)

    def _busy(self) -> int:
        return sum(1 for w in self.slots if w is not None and w.task is not None)

    # -- scene outcomes --------------------------------------------------
    def _finished_anyway(self, index: int) -> bool:
        """After a crash or timeout: did the scene get written before the worker died?"""
        try:
            check = check_scene(self.config.out, index)
        except (ValueError, OSError):
            return False
        self.book.done(index, None, check)
        return True

    def _failed(self, index: int, reason: str) -> None:
        if self._finished_anyway(index):
            return
        remove_partial_files(self.config.out, index, keep_finished=False)
        if self.book.failed_attempt(index, reason):
            self.pending.append(index)

    def _on_done(self, worker: _Worker, message: dict) -> None:
        index = worker.task
        worker.task = None
        worker.assigned += 1
        try:
            check = check_scene(self.config.out, index)
        except (ValueError, OSError) as exc:
            self._drop(worker, kill=False)
            self._failed(index, f"invalid output: {exc}")
            return
        self.largest_scene = max(self.largest_scene, check.bytes)
        self.book.done(index, message.get("seconds"), check, message.get("pid"))
        if worker.assigned >= self.config.recycle:
            self._drop(worker, kill=False)

    def _on_failed(self, worker: _Worker, message: dict) -> None:
        index = worker.task
        worker.task = None
        self._drop(worker, kill=False)  # bpy state after an exception is suspect: fresh worker
        if message.get("disk_full"):
            remove_partial_files(self.config.out, index, keep_finished=False)
            self.book.stop(f"output disk full (ENOSPC) while writing scene {index} in {self.config.out}")
            self.book.failed_attempt(index, message.get("error", "ENOSPC"))
            return
        self._failed(index, message.get("error", "unknown error"))

    def _on_exit(self, worker: _Worker) -> None:
        if self.slots[worker.slot] is not worker:
            self._reap(worker)  # retired or killed on purpose: its exit was expected
            return
        self.slots[worker.slot] = None
        self.retiring.append(worker)
        how = worker.exit_description()
        worker.remove_tmp()
        if worker.task is not None:
            index, worker.task = worker.task, None
            self._failed(index, f"{how} while rendering")
        elif not worker.ready:
            self._start_failed(worker, how)
        else:
            self.book.note(f"{how} while idle")  # no scene lost, but worth knowing

    def _start_failed(self, worker: _Worker, how: str) -> None:
        self.start_failures += 1
        last = worker.last_log_line()
        if not self.ever_ready or self.start_failures >= MAX_START_FAILURES:
            self.book.stop(f"worker could not start ({how}): {last or 'no output'}; log {worker.log_path}")

    # -- main loop -------------------------------------------------------
    def _dispatch(self) -> None:
        for slot, worker in enumerate(self.slots):
            if self.book.abort is not None or not self.pending:
                return
            if worker is None:
                self._spawn(slot)
                continue
            if not worker.ready or worker.task is not None:
                continue
            reason = disk_room(self.config, self._busy(), self.largest_scene)
            if reason:
                self.book.stop(reason)
                return
            index = self.pending.popleft()
            self.book.attempt(index)
            worker.task = index
            worker.deadline = time.monotonic() + self.config.timeout
            if not worker.send(index, self.config.seed):
                pass  # the worker died; its EOF event retries the scene

    def _check_deadlines(self) -> None:
        now = time.monotonic()
        for worker in list(self.slots):
            if worker is None:
                continue
            if worker.task is not None and now > worker.deadline:
                index, worker.task = worker.task, None
                self._drop(worker, kill=True)
                self._failed(index, f"timeout after {self.config.timeout:g} s (worker {worker.pid} killed)")
            elif not worker.ready and now - worker.started > self.config.timeout:
                self._drop(worker, kill=True)
                self._start_failed(worker, f"not ready after {self.config.timeout:g} s")

    def _next_wakeup(self) -> float:
        now = time.monotonic()
        times = [w.deadline for w in self.slots if w is not None and w.task is not None]
        times += [w.started + self.config.timeout for w in self.slots if w is not None and not w.ready]
        return max(0.01, min([now + 0.25] + times) - now)

    def _idle(self) -> bool:
        return all(w is None or w.task is None for w in self.slots)

    def run(self) -> None:
        try:
            while True:
                if STOP.requested:  # checked here, where no scene is half-bookkept
                    raise KeyboardInterrupt
                self._dispatch()
                if (not self.pending or self.book.abort is not None) and self._idle():
                    break
                try:
                    worker, message = self.events.get(timeout=self._next_wakeup())
                except queue.Empty:
                    pass
                else:
                    self._handle(worker, message)
                self._check_deadlines()
                self.book.write_log()
        except KeyboardInterrupt:
            self._shutdown(interrupted=True)
            raise
        self._shutdown(interrupted=False)

    def _handle(self, worker: _Worker, message: dict | None) -> None:
        if message is None:
            self._on_exit(worker)
            return
        if self.slots[worker.slot] is not worker:
            return  # a late message from a worker already dropped
        event = message.get("event")
        if event == "ready":
            worker.ready = True
            self.ever_ready = True
            self.start_failures = 0
        elif event == "done" and worker.task == message.get("index"):
            self._on_done(worker, message)
        elif event == "failed" and worker.task == message.get("index"):
            self._on_failed(worker, message)

    def _shutdown(self, interrupted: bool) -> None:
        for worker in list(self.slots):
            if worker is None:
                continue
            index, worker.task = worker.task, None
            self._drop(worker, kill=interrupted or index is not None)
            # Interrupted mid-scene: a scene written but not yet reported still counts;
            # otherwise its partial files go.
            if index is not None and not self._finished_anyway(index):
                remove_partial_files(self.config.out, index, keep_finished=False)
        for worker in self.retiring:
            try:
                worker.proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                worker.kill()
                worker.proc.wait()
            worker.release()


class _StopRequest:
    """SIGINT/SIGTERM set a flag the main loop polls (within 0.25 s), so an interrupt
    never lands between writing a scene and recording it; a second signal interrupts at once."""

    def __init__(self):
        self.requested = False

    def __call__(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def install(self) -> dict:
        self.requested = False
        if threading.current_thread() is not threading.main_thread():
            return {}
        return {sig: signal.signal(sig, self) for sig in (signal.SIGINT, signal.SIGTERM)}

    @staticmethod
    def restore(previous: dict) -> None:
        for sig, handler in previous.items():
            signal.signal(sig, handler)


STOP = _StopRequest()


def run_local(config: RunConfig) -> Summary:
    """Render config.indices with the local pool; prints and returns the summary."""
    todo, skipped, removed = plan_run(config)
    book = RunBook(config, "local", todo, skipped)
    if removed:
        print(f"farm: removed {len(removed)} stray files of unfinished scenes", file=sys.stderr)
    previous = STOP.install()
    try:
        if todo:
            LocalExecutor(config, book, todo).run()
    except KeyboardInterrupt:
        book.stop("interrupted")
        book.close()
        raise
    finally:
        STOP.restore(previous)
    summary = book.close()
    if summary.abort:
        raise FarmError(summary.abort)
    return summary
