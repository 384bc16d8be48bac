"""The run book of a farm run: one record per scene, the totals, and the atomic JSON run log.

Each executor reports events (attempt, done, failed attempt, settled elsewhere,
stop) here; the book decides whether a failed scene is retried (within
--retries), drives the progress bar (farm.execution.progress) and rewrites
`farm_runlog.json` in the output folder, keeping the runs before this one so
that a resumed folder shows its whole history.
"""

from __future__ import annotations

import collections
import datetime
import json
import sys
import time
from dataclasses import dataclass, field

from farm.execution.outputs import SceneCheck
from farm.execution.progress import progress_bar
from farm.execution.run_config import RunConfig
from relight.files.fileio import atomic_write_json

RUN_LOG_NAME = "farm_runlog.json"
RUN_LOG_FORMAT = "relight-farm-runlog/1"
LOG_WRITE_INTERVAL = 5.0


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
            self._bar = progress_bar(len(todo))

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
            atomic_write_json(self.log_path, {"format": RUN_LOG_FORMAT, "runs": self._previous_runs + [run]},
                              indent=1)
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

