"""Local executor of the render farm, plus the bookkeeping every executor shares.

The local pool keeps W worker processes (`python -m farm.worker`, or the
Blender binary with -P under real Blender). Each imports bpy once, renders
scenes sent one at a time, and is retired after `recycle` scenes or after
any failure, so a retry always runs in a fresh process. The parent enforces
the per-scene timeout (SIGKILL), notices killed workers (EOF on their pipe),
validates every scene it is told about, checks free disk space before each
scene, and keeps an atomic JSON run log in the output folder.
"""

from __future__ import annotations

import collections
import ctypes
import functools
import datetime
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from farm.run_config import FarmError, RunConfig

REPO_ROOT = Path(__file__).resolve().parent.parent
RUN_LOG_NAME = "farm_runlog.json"
RUN_LOG_FORMAT = "relight-farm-runlog/1"
WORKER_LOG_DIR = "farm_logs"
# Any file of scene NNNNNN: finals (scene_NNNNNN.exr/.json) and the temps of
# atomic writes (.scene_NNNNNN.exr.XXXX.tmp.exr).
SCENE_FILE = re.compile(r"^\.?scene_(\d{6})(?=[._])")
# Zip-compressed float32 EXRs are at most about their raw size; the JSON
# sidecar (SH of K lights at order 8, body and pose) stays well under 1 MiB.
SIDECAR_ALLOWANCE = 1 << 20
LOG_WRITE_INTERVAL = 5.0
MAX_START_FAILURES = 3


def json_path(out: Path, index: int) -> Path:
    return Path(out) / f"scene_{index:06d}.json"


def exr_path(out: Path, index: int) -> Path:
    return Path(out) / f"scene_{index:06d}.exr"


@dataclass
class SceneCheck:
    """What the runner learns from a finished, valid scene."""

    index: int
    bytes: int
    path_traced: int
    skipped_passes: list[str]
    timings: dict


def _skipped_passes(meta: dict) -> list[str]:
    """Passes the scene code recorded as skipped (sidecar "passes"), plus a skipped
    specular bake (sidecar "bake")."""
    passes = meta.get("passes") or {}
    skipped = passes.get("skipped", []) if isinstance(passes, dict) else []
    names = {str(k) for k in skipped}
    bake = meta.get("bake")
    if isinstance(bake, dict) and str(bake.get("specular", "")).startswith("skipped"):
        names.add("specular")
    return sorted(names)


def check_scene(out: Path, index: int) -> SceneCheck:
    """Validate scene `index` in `out` with relight.dataset: sidecar present, EXR hash
    matches, channels as the sidecar lists them, and every pixel finite.

    Raises ValueError naming the problem.
    """
    from relight.dataset import read_scene

    scene = read_scene(json_path(out, index))
    if scene.index != index:
        raise ValueError(f"scene {index}: sidecar says index {scene.index}")
    arrays = {"alpha": scene.alpha, "albedo": scene.albedo, "normal": scene.normal,
              "material": scene.material, "depth": scene.depth, "transport": scene.transport}
    for kind in ("images", "shading", "prt"):
        for k, plane in enumerate(getattr(scene, kind) or []):
            arrays[f"{kind}.L{k}"] = plane
    for name, pixels in arrays.items():
        if pixels is not None and not np.isfinite(pixels).all():
            raise ValueError(f"scene {index}: {name} has NaN or Inf pixels")
    return SceneCheck(
        index=index,
        bytes=scene.exr_path.stat().st_size + scene.json_path.stat().st_size,
        path_traced=len(scene.images or []),
        skipped_passes=_skipped_passes(scene.meta),
        timings=scene.meta.get("timings") or {},
    )


def finished_indices(out: Path, indices) -> set[int]:
    """Indices of this range whose scene is finished (sidecar and EXR present; not hashed)."""
    from relight.dataset import list_finished_scenes

    wanted = set(indices)
    found = {int(p.stem.split("_")[1]) for p in list_finished_scenes(out)}
    return found & wanted


def _remove(path: Path) -> None:
    if path.is_dir() and not path.is_symlink():
        shutil.rmtree(path, ignore_errors=True)
    else:
        path.unlink(missing_ok=True)


def remove_partial_files(out: Path, index: int, keep_finished: bool) -> list[str]:
    """Delete the temps (and, unless keep_finished, the finals) of one scene; returns names."""
    finals = {json_path(out, index).name, exr_path(out, index).name}
    removed = []
    for path in Path(out).glob(f"*scene_{index:06d}*"):
        m = SCENE_FILE.match(path.name)
        if not m or int(m.group(1)) != index:
            continue
        if keep_finished and path.name in finals:
            continue
        _remove(path)
        removed.append(path.name)
    return removed


def clean_unfinished(out: Path, indices, finished: set[int]) -> list[str]:
    """Remove stray files of this run's scenes (temps; EXRs without sidecar); never finished ones.

    Only this run's index range is touched: other machines may be writing
    other ranges into the same folder.
    """
    wanted = set(indices)
    touched = set()
    for path in Path(out).iterdir():
        m = SCENE_FILE.match(path.name)
        if m and int(m.group(1)) in wanted:
            touched.add(int(m.group(1)))
    removed = []
    for index in sorted(touched):
        removed += remove_partial_files(out, index, keep_finished=index in finished)
    return removed


def atomic_write_json(path: Path, data) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    try:
        with open(tmp, "w") as f:
            json.dump(data, f, indent=1)
            f.flush()
            os.fsync(f.fileno())
        os.replace(tmp, path)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


def expected_scene_bytes(config: RunConfig) -> int:
    s = config.scene
    return s.expected_channels() * s.resolution * s.resolution * 4 + SIDECAR_ALLOWANCE


def prepare_output(config: RunConfig) -> None:
    """Create the output folder and prove it is writable; FarmError otherwise."""
    out = config.out
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / f".farm_write_probe.{os.getpid()}"
        probe.write_bytes(b"ok")
        probe.unlink()
    except OSError as exc:
        raise FarmError(f"output folder {out} is not writable: {exc.strerror or exc}") from None


@dataclass
class SceneRecord:
    index: int
    status: str = "pending"  # pending | done | failed | skipped | not_started
    attempts: int = 0
    errors: list = field(default_factory=list)
    seconds: float | None = None
    worker: int | None = None  # pid of the process that rendered it
    path_traced: int = 0
    skipped_passes: list = field(default_factory=list)
    timings: dict = field(default_factory=dict)


@dataclass
class Summary:
    """Totals of one run (printed at the end, stored in the run log)."""

    done: int
    failed: int
    retried: int
    skipped: int
    not_started: int
    skipped_passes: dict
    wall_seconds: float
    scenes_per_hour: float
    images_per_hour: float
    abort: str | None

    @property
    def ok(self) -> bool:
        return self.failed == 0 and self.not_started == 0 and self.abort is None

    def table(self) -> str:
        passes = ", ".join(f"{k} x{v}" for k, v in sorted(self.skipped_passes.items())) or "none"
        rows = [
            ("done", self.done),
            ("failed", self.failed),
            ("retried", self.retried),
            ("skipped (resumed)", self.skipped),
            ("not started", self.not_started),
            ("skipped passes", passes),
            ("wall time", f"{self.wall_seconds:.1f} s"),
            ("scenes/hour", f"{self.scenes_per_hour:.1f}"),
            ("path-traced images/hour", f"{self.images_per_hour:.1f}"),
        ]
        width = max(len(k) for k, _ in rows)
        lines = [f"{k:<{width}}  {v}" for k, v in rows]
        if self.abort:
            lines.append(f"{'stopped':<{width}}  {self.abort}")
        return "\n".join(lines)


class _PlainProgress:
    """Stand-in for tqdm when it is not installed: one line per finished scene, with ETA."""

    def __init__(self, total: int, file, **_):
        self.total, self.n, self.file, self.t0, self.postfix = total, 0, file, time.monotonic(), {}

    def update(self, n: int = 1) -> None:
        self.n += n
        elapsed = time.monotonic() - self.t0
        eta = elapsed / self.n * (self.total - self.n)
        extra = " ".join(f"{k}={v}" for k, v in self.postfix.items())
        print(f"farm: {self.n}/{self.total} scenes, {elapsed:.0f} s, ETA {eta:.0f} s {extra}".rstrip(),
              file=self.file, flush=True)

    def set_postfix(self, refresh: bool = False, **values) -> None:
        self.postfix = values

    def close(self) -> None:
        pass


class RunBook:
    """Per-scene bookkeeping, progress bar, summary and the atomic JSON run log."""

    def __init__(self, config: RunConfig, executor: str, todo: list[int], skipped: list[int]):
        self.config = config
        self.executor = executor
        self.started = time.time()
        self.t0 = time.monotonic()
        self.t_end: float | None = None
        self.records = {i: SceneRecord(i) for i in todo}
        for i in skipped:
            self.records[i] = SceneRecord(i, status="skipped")
        self.retried = 0
        self.workers_started = 0
        self.worker_notes: list[str] = []
        self.abort: str | None = None
        self.log_path = config.out / RUN_LOG_NAME
        self._previous_runs = self._load_previous_runs()
        self._last_write = 0.0
        self._bar = None
        if config.progress and todo:
            try:
                from tqdm import tqdm
            except ImportError:  # e.g. real Blender's bundled Python without tqdm
                tqdm = _PlainProgress
            self._bar = tqdm(total=len(todo), unit="scene", file=sys.stderr, dynamic_ncols=True,
                             desc="farm", smoothing=0.1)

    def _load_previous_runs(self) -> list:
        try:
            data = json.loads(self.log_path.read_text())
            runs = data.get("runs", []) if isinstance(data, dict) else []
            return runs if isinstance(runs, list) else []
        except (OSError, ValueError):
            return []  # no log yet, or a damaged one: start a new list

    # -- events ---------------------------------------------------------
    def attempt(self, index: int) -> int:
        record = self.records[index]
        record.attempts += 1
        return record.attempts

    def done(self, index: int, seconds: float | None, check: SceneCheck, worker: int | None = None) -> None:
        r = self.records[index]
        r.status, r.seconds, r.worker = "done", seconds, worker
        r.path_traced, r.skipped_passes, r.timings = check.path_traced, check.skipped_passes, check.timings
        self._advance()

    def failed_attempt(self, index: int, reason: str) -> bool:
        """Record a failed attempt; True when the scene should be retried."""
        r = self.records[index]
        r.errors.append(reason)
        if r.attempts <= self.config.retries and self.abort is None:
            self.retried += 1
            self._postfix()
            self.write_log()
            return True
        r.status = "failed"
        self._advance()
        return False

    def settle(self, index: int, attempts: int, errors: list, check: SceneCheck | None,
               seconds: float | None = None, worker: int | None = None) -> None:
        """Record a scene whose attempts ran elsewhere (Ray retries inside the cluster)."""
        r = self.records[index]
        r.attempts, r.errors = attempts, list(errors)
        self.retried += max(0, attempts - 1)
        if check is not None:
            self.done(index, seconds, check, worker)
        else:
            r.status = "failed"
            self._advance()

    def note(self, text: str) -> None:
        """Something the run log should show that is no scene's outcome."""
        self.worker_notes.append(f"{time.monotonic() - self.t0:.1f} s: {text}")

    def stop(self, reason: str) -> None:
        if self.abort is None:
            self.abort = reason

    def _advance(self) -> None:
        if self._bar is not None:
            self._bar.update(1)
            self._postfix()
        self.write_log()

    def _postfix(self) -> None:
        if self._bar is not None:
            failed = sum(r.status == "failed" for r in self.records.values())
            self._bar.set_postfix(failed=failed, retried=self.retried, refresh=False)

    # -- results --------------------------------------------------------
    def summary(self) -> Summary:
        end = self.t_end if self.t_end is not None else time.monotonic()
        wall = max(end - self.t0, 1e-9)
        done = [r for r in self.records.values() if r.status == "done"]
        skipped_passes = collections.Counter(p for r in done for p in r.skipped_passes)
        return Summary(
            done=len(done),
            failed=sum(r.status == "failed" for r in self.records.values()),
            retried=self.retried,
            skipped=sum(r.status == "skipped" for r in self.records.values()),
            not_started=sum(r.status == "pending" for r in self.records.values()),
            skipped_passes=dict(skipped_passes),
            wall_seconds=wall,
            scenes_per_hour=len(done) * 3600.0 / wall,
            images_per_hour=sum(r.path_traced for r in done) * 3600.0 / wall,
            abort=self.abort,
        )

    def write_log(self, final: bool = False) -> None:
        """Rewrite the run log atomically (at most every few seconds unless final)."""
        now = time.monotonic()
        if not final and now - self._last_write < LOG_WRITE_INTERVAL:
            return
        self._last_write = now
        c = self.config
        run = {
            "started": datetime.datetime.fromtimestamp(self.started, datetime.timezone.utc).isoformat(),
            "finished": final,
            "executor": self.executor,
            "argv": sys.argv,
            "config": {
                "scenes": c.scenes, "first": c.first, "seed": c.seed, "workers": c.workers,
                "recycle": c.recycle, "timeout": c.timeout, "retries": c.retries,
                "resume": c.resume, "ray": c.ray, "job_module": c.job_module,
                "scene": c.scene.to_json(),
            },
            "summary": self.summary().__dict__,
            "workers_started": self.workers_started,
            "worker_notes": self.worker_notes,
            "scenes": [r.__dict__ for _, r in sorted(self.records.items())],
        }
        try:
            atomic_write_json(self.log_path, {"format": RUN_LOG_FORMAT, "runs": self._previous_runs + [run]})
        except OSError as exc:
            # Scenes are the product; a log that cannot be written stops the run cleanly.
            self.stop(f"cannot write run log {self.log_path}: {exc.strerror or exc}")

    def close(self) -> Summary:
        if self._bar is not None:
            self._bar.close()
        # One end time: the run log and the printed table must show the same rates.
        self.t_end = time.monotonic()
        self.write_log(final=True)
        summary = self.summary()
        print(summary.table(), flush=True)
        return summary


def plan_run(config: RunConfig) -> tuple[list[int], list[int], list[str]]:
    """(todo, skipped, removed stray files) after checking the output folder."""
    prepare_output(config)
    finished = finished_indices(config.out, config.indices)
    if finished and not config.resume:
        raise FarmError(
            f"{config.out} already holds {len(finished)} finished scenes of this range; "
            "pass --resume to keep them and render the rest"
        )
    removed = clean_unfinished(config.out, config.indices, finished)
    todo = [i for i in config.indices if i not in finished]
    return todo, sorted(finished), removed


def disk_room(config: RunConfig, scenes_in_flight: int, largest_seen: int) -> str | None:
    """None when the output disk has room for one more scene, else the reason."""
    need = max(expected_scene_bytes(config), largest_seen) * (scenes_in_flight + 1)
    try:
        free = shutil.disk_usage(config.out).free
    except OSError as exc:
        return f"cannot read free space of {config.out}: {exc.strerror or exc}"
    if free < need:
        return (f"output disk full: {free / 2**20:.1f} MiB free in {config.out}, "
                f"{need / 2**20:.1f} MiB needed for the next scene")
    return None


# -- local executor ------------------------------------------------------

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
        # W workers share the machine's cores: Cycles threads per worker (farm.passes reads it).
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
        self.threads = max(1, len(os.sched_getaffinity(0)) // config.workers)
        self.log_dir = config.out / WORKER_LOG_DIR
        self.log_dir.mkdir(exist_ok=True)
        self.start_failures = 0
        self.ever_ready = False
        self.largest_scene = 0

    # -- worker lifecycle ------------------------------------------------
    def _spawn(self, slot: int) -> None:
        self.book.workers_started += 1
        log = self.log_dir / f"worker{slot}.log"
        cpus = worker_cpus(slot, self.config.workers, os.sched_getaffinity(0)) if self.config.pin else None
        self.slots[slot] = _Worker(slot, self.command, log, self.events, self.threads, cpus)

    def _drop(self, worker: _Worker, kill: bool) -> None:
        if self.slots[worker.slot] is worker:
            self.slots[worker.slot] = None
        worker.kill() if kill else worker.retire()
        self.retiring.append(worker)

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
            return  # already retired or killed on purpose
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
            worker.remove_tmp()
            for stream in (worker.proc.stdin, worker.proc.stdout):
                try:
                    stream.close()
                except OSError:
                    pass


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
