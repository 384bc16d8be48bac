"""A function run on a worker thread, polled from Blender's main thread.

Plain Python (no bpy). onnxruntime releases the GIL during inference, so the
UI keeps drawing while the network runs. Cancelling marks the job so the
caller can return at once and any late result is dropped; with a cancel token
(engine.CancelToken) it also stops the work itself, a running inference
included. The worker reports its stage through a Progress object. env_flag (run on the
calling thread?) serves the jobs' callers.
"""

from __future__ import annotations

import enum
import os
import threading
import time
from typing import Any, Callable


class JobState(enum.Enum):
    RUNNING = "running"
    DONE = "done"
    FAILED = "failed"
    CANCELLED = "cancelled"


class Progress:
    """The worker's current stage (artist words) and the fraction of the whole job done.

    Written by the worker, read by the main thread: two plain attributes,
    each replaced whole, so no lock is needed.
    """

    def __init__(self):
        self.stage = "Starting"
        self.fraction = 0.0
        self.stage_started = time.monotonic()
        self.history: list[tuple[str, float]] = []  # (stage, when it started): for timings

    def enter(self, stage: str, fraction: float) -> None:
        now = time.monotonic()
        self.history.append((stage, now))
        self.stage, self.fraction, self.stage_started = stage, float(fraction), now

    def durations(self, end: float | None = None) -> list[tuple[str, float]]:
        """(stage, seconds) of every stage entered, the last one up to `end` (default now)."""
        marks = self.history + [("", time.monotonic() if end is None else end)]
        return [(stage, later - t) for (stage, t), (_, later) in zip(marks, marks[1:])]


NETWORK_STAGE = "Running the network"


def shown_fraction(progress: Progress, expected_seconds: float | None, network_share: float,
                   now: float | None = None) -> float:
    """The fraction the progress bar shows: the job's own, plus, inside the network
    stage, `network_share` interpolated by the time the last run took (below 1)."""
    fraction = progress.fraction
    if progress.stage.startswith(NETWORK_STAGE) and expected_seconds:
        now = time.monotonic() if now is None else now
        fraction += min(1.0, (now - progress.stage_started) / expected_seconds) * network_share
    return min(fraction, 0.99)


def finished_job(running: dict, slot: str, interval: float):
    """(job, None) once the job in running[slot] is no longer running; else (None, what a
    polling timer returns): `interval` while it runs, None when there is no job."""
    job = running.get(slot)
    if job is None:
        return None, None
    if job.poll() is JobState.RUNNING:
        return None, interval
    return job, None


class BackgroundJob:
    """Runs `fn()` once on a daemon thread; `poll()` reports its state without blocking."""

    def __init__(self, fn: Callable[[], Any], label: str = "job", cancel_token=None,
                 progress: Progress | None = None):
        self.label = label
        self.progress = progress or Progress()
        self.cancel_token = cancel_token
        self._fn = fn
        self._result: Any = None
        self._error: BaseException | None = None
        self._cancelled = threading.Event()
        self._finished = threading.Event()
        self._started_at = time.monotonic()
        self.finished_at: float | None = None
        self._thread = threading.Thread(target=self._run, name=f"relight-{label}", daemon=True)
        self._thread.start()

    def _run(self) -> None:
        try:
            self._result = self._fn()
        except BaseException as exc:  # reported to the main thread, never raised here
            self._error = exc
        finally:
            self._fn = None  # its closure's inputs (a photo, a session) are not kept by the job
            self.finished_at = time.monotonic()
            self._finished.set()

    def cancel(self) -> None:
        """Drop the result; with a cancel token the work stops too, else the thread finishes unseen."""
        self._cancelled.set()
        if self.cancel_token is not None:
            self.cancel_token.cancel()

    @property
    def finished(self) -> bool:
        """True once the thread has returned (also after a cancel)."""
        return self._finished.is_set()

    @property
    def elapsed(self) -> float:
        return time.monotonic() - self._started_at

    def poll(self) -> JobState:
        if self._cancelled.is_set():
            return JobState.CANCELLED
        if not self._finished.is_set():
            return JobState.RUNNING
        return JobState.FAILED if self._error is not None else JobState.DONE

    def wait(self, timeout: float | None = None) -> JobState:
        """Block until finished or cancelled (used by the synchronous test mode)."""
        self._finished.wait(timeout)
        return self.poll()

    @property
    def result(self) -> Any:
        if self.poll() is not JobState.DONE:
            raise RuntimeError(f"{self.label} has no result (state {self.poll().value})")
        return self._result

    def take_result(self) -> Any:
        """The result, no longer kept by the job: an operator instance that holds its job may
        outlive the run (Blender keeps the last operators for its redo panel), and a 24 MP
        result is hundreds of MB."""
        result = self.result
        self._result = None
        return result

    @property
    def error(self) -> BaseException | None:
        return self._error


def env_flag(name: str) -> bool:
    """True when environment variable `name` is set to 1/true/yes/on."""
    return os.environ.get(name, "").strip().lower() in {"1", "true", "yes", "on"}
