"""Cluster executor of the render farm on Ray (`--ray auto|ADDRESS`, extra 'distributed').

Each scene is one Ray task. Tasks run in Ray worker processes that import the
scene module (and bpy) once and are replaced after `recycle` scenes
(`max_calls`). A watchdog thread SIGKILLs the task's own process at the
per-scene timeout; Ray sees a dead worker and retries the task on a fresh one
(`max_retries`), as it does for a crash or an exception. Every attempt appends
one line to farm_logs/attempts/scene_NNNNNN.log in the output folder, which is
how the driver counts retries. The output folder must be a filesystem every
node sees at the same path (NFS or similar); Ray is imported only here.
"""

from __future__ import annotations

import atexit
import logging
import os
import shutil
import signal
import socket
import tempfile
import threading
import time
from pathlib import Path

from farm.execution.outputs import (
    WORKER_LOG_DIR, check_scene, disk_room, expected_scene_bytes, plan_run, remove_partial_files,
)
from farm.execution.pool import REPO_ROOT
from farm.execution.run_config import FarmError, RunConfig
from farm.execution.runbook import RunBook, Summary
from farm.execution.scene_job import is_disk_full

ATTEMPT_DIR = "attempts"


class SceneError(RuntimeError):
    """A scene failed inside a Ray task (retried by Ray)."""


class DiskFullError(RuntimeError):
    """The output disk is full (never retried: the run stops)."""


class JobSetupError(RuntimeError):
    """The scene module or its options cannot load on a node (never retried: the run stops)."""


_JOB_CACHE: dict = {}
# Each Ray worker process keeps the scene code's scratch in its own temp folder,
# so the scratch of a process killed mid-scene can be found and removed later.
RAY_TMP_PREFIX = "farm_ray_"
_SYSTEM_TMP = Path(tempfile.gettempdir())
_PRIVATE_TMP: Path | None = None


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


def remove_dead_workers_tmp(base: Path = _SYSTEM_TMP) -> list[str]:
    """Delete the private temp folders of Ray worker processes (on this node) that are gone."""
    removed = []
    for path in base.glob(RAY_TMP_PREFIX + "*"):
        pid = path.name[len(RAY_TMP_PREFIX):]
        if pid.isdigit() and not _pid_alive(int(pid)):
            shutil.rmtree(path, ignore_errors=True)
            removed.append(path.name)
    return removed


def _use_private_tmp() -> None:
    global _PRIVATE_TMP
    if _PRIVATE_TMP is None:
        remove_dead_workers_tmp()
        _PRIVATE_TMP = _SYSTEM_TMP / f"{RAY_TMP_PREFIX}{os.getpid()}"
        _PRIVATE_TMP.mkdir(exist_ok=True)
        atexit.register(shutil.rmtree, _PRIVATE_TMP, True)  # a normal exit (max_calls) tidies up
        tempfile.tempdir = str(_PRIVATE_TMP)
        os.environ["TMPDIR"] = str(_PRIVATE_TMP)


def _attempt_log(out: Path, index: int) -> Path:
    return Path(out) / WORKER_LOG_DIR / ATTEMPT_DIR / f"scene_{index:06d}.log"


def _note(out: Path, index: int, text: str) -> None:
    with open(_attempt_log(out, index), "a") as f:
        one_line = " ".join(str(text).split())[:500]
        f.write(f"{time.time():.3f} {socket.gethostname()} {os.getpid()} {one_line}\n")
        f.flush()
        os.fsync(f.fileno())


def read_attempts(out: Path, index: int) -> tuple[int, list[str]]:
    """(attempts started, error texts) from the scene's attempt log."""
    try:
        lines = _attempt_log(out, index).read_text().splitlines()
    except OSError:
        return 0, []
    attempts = sum(1 for ln in lines if ln.split(" ", 3)[3:] == ["start"])
    errors = [ln.split(" ", 3)[3] for ln in lines if len(ln.split(" ", 3)) == 4 and ln.split(" ", 3)[3] != "start"]
    return attempts, errors


def _kill_self(out: Path, index: int, timeout: float) -> None:
    try:
        _note(out, index, f"timeout after {timeout:g} s")
    finally:
        os.kill(os.getpid(), signal.SIGKILL)


def render_task(job_module: str, settings: dict, index: int, seed: int, out: str,
                timeout: float, need_bytes: int) -> dict:
    """One scene inside a Ray worker process (bpy imported once per process)."""
    from farm.execution.scene_job import load_job, render_one

    out_dir = Path(out)
    # Each task holds one CPU of the cluster: one Cycles thread (farm.rendering.passes reads it).
    os.environ.setdefault("RELIGHT_CYCLES_THREADS", "1")
    _use_private_tmp()
    _note(out_dir, index, "start")
    free = shutil.disk_usage(out_dir).free
    if free < need_bytes:
        _note(out_dir, index, "disk full")
        raise DiskFullError(f"output disk full on {socket.gethostname()}: {free / 2**20:.1f} MiB free, "
                            f"{need_bytes / 2**20:.1f} MiB needed")
    key = (job_module, repr(sorted(settings.items())))
    if key not in _JOB_CACHE:
        try:
            options_class, render_scene = load_job(job_module)
            options = options_class.from_json(settings)
        except Exception as exc:
            _note(out_dir, index, f"setup failed: {type(exc).__name__}: {exc}")
            raise JobSetupError(f"{type(exc).__name__}: {exc} (on {socket.gethostname()})") from None
        _JOB_CACHE.clear()
        _JOB_CACHE[key] = (render_scene, options)
    render_scene, options = _JOB_CACHE[key]
    watchdog = threading.Timer(timeout, _kill_self, args=(out_dir, index, timeout))
    watchdog.daemon = True
    watchdog.start()
    try:
        message = render_one(render_scene, options, index, seed, out_dir)
    finally:
        watchdog.cancel()
    message["pid"] = os.getpid()
    if message["event"] == "failed":
        _note(out_dir, index, message["error"])
        remove_partial_files(out_dir, index, keep_finished=False)
        if message["disk_full"]:
            raise DiskFullError(message["error"])
        raise SceneError(message["error"])
    return message


def _connect(ray, address: str) -> bool:
    """Connect (or start a local cluster for 'auto' when none runs); True when we started it."""
    if ray.is_initialized():
        return False
    try:
        ray.init(
            address=None if address == "auto" else address,
            include_dashboard=False,
            logging_level=logging.WARNING,
            log_to_driver=False,  # Cycles' progress lines stay in the workers' logs
            runtime_env={"env_vars": {"PYTHONPATH": str(REPO_ROOT)}},
        )
    except (ConnectionError, RuntimeError, ValueError) as exc:
        raise FarmError(f"cannot connect to Ray at {address!r}: {exc}".splitlines()[0]) from None
    return True


def _failure_text(exc: BaseException) -> str:
    cause = getattr(exc, "cause", None)
    if cause is not None:
        return f"{type(cause).__name__}: {cause}".splitlines()[0][:300]
    return f"{type(exc).__name__}: {exc}".splitlines()[0][:300]


def run_on_ray(config: RunConfig) -> Summary:
    """Render config.indices as Ray tasks; prints and returns the summary."""
    try:
        import ray
    except ImportError:
        raise FarmError("--ray needs Ray: pip install 'fullbody-relight[distributed]' (or pip install ray)") from None
    todo, skipped, _removed = plan_run(config)
    (config.out / WORKER_LOG_DIR / ATTEMPT_DIR).mkdir(parents=True, exist_ok=True)
    for index in todo:
        _attempt_log(config.out, index).unlink(missing_ok=True)
    book = RunBook(config, "ray", todo, skipped)
    started_here = _connect(ray, config.ray) if todo else False
    try:
        if todo:
            _run(ray, config, book, todo)
    except KeyboardInterrupt:
        book.stop("interrupted")
        book.close()
        raise
    finally:
        if started_here:
            ray.shutdown()
        remove_dead_workers_tmp()  # this node's; other nodes clean up as their next task starts
    summary = book.close()
    if summary.abort:
        raise FarmError(summary.abort)
    return summary


def _run(ray, config: RunConfig, book: RunBook, todo: list[int]) -> None:
    task = ray.remote(
        num_cpus=1,
        max_calls=config.recycle,  # a fresh worker process (and bpy) every `recycle` scenes
        max_retries=config.retries,
        retry_exceptions=[SceneError],
    )(render_task)
    settings = config.scene.to_json()
    window = max(1, int(ray.cluster_resources().get("CPU", 1)))
    pending = list(reversed(todo))
    in_flight: dict = {}
    largest = 0
    while pending or in_flight:
        while pending and len(in_flight) < window and book.abort is None:
            reason = disk_room(config, len(in_flight), largest)
            if reason:
                book.stop(reason)
                break
            index = pending.pop()
            need = max(expected_scene_bytes(config), largest)
            ref = task.remote(config.job_module, settings, index, config.seed, str(config.out),
                              config.timeout, need)
            in_flight[ref] = index
        if not in_flight:
            break
        ready, _ = ray.wait(list(in_flight), num_returns=1, timeout=1.0)
        for ref in ready:
            index = in_flight.pop(ref)
            try:
                message = ray.get(ref)
            except ray.exceptions.RayError as exc:
                attempts, errors = read_attempts(config.out, index)
                cause = getattr(exc, "cause", None)
                if isinstance(cause, DiskFullError) or (isinstance(cause, BaseException) and is_disk_full(cause)):
                    book.stop(f"output disk full (ENOSPC) while writing scene {index}: {cause}")
                elif isinstance(cause, JobSetupError):
                    book.stop(f"scene module {config.job_module} cannot load on the cluster: {cause}")
                if not errors or errors[-1] != _failure_text(exc):
                    errors.append(_failure_text(exc))
                try:
                    check = check_scene(config.out, index)  # written before a late kill?
                except (ValueError, OSError):
                    check = None
                    remove_partial_files(config.out, index, keep_finished=False)
                book.settle(index, max(attempts, 1), errors, check)
                continue
            attempts, errors = read_attempts(config.out, index)
            try:
                check = check_scene(config.out, index)
            except (ValueError, OSError) as exc:
                remove_partial_files(config.out, index, keep_finished=False)
                with open(_attempt_log(config.out, index), "a") as f:
                    f.write(f"{time.time():.3f} driver 0 invalid output: {exc}\n")
                if attempts < 1 + config.retries and book.abort is None:
                    pending.append(index)  # Ray saw success; the driver retries
                    continue
                book.settle(index, attempts, errors + [f"invalid output: {exc}"], None)
                continue
            largest = max(largest, check.bytes)
            book.settle(index, attempts, errors, check, message.get("seconds"), message.get("pid"))
        book.write_log()
