"""What one farm run is (RunConfig) and how it fails (UsageError, FarmError).

Plain data shared by the command line (farm.cli) and the executors (local
pool, Ray), so neither imports the other.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path

from farm.synthesis.scene_options import SceneOptions

DEFAULT_JOB_MODULE = "farm.scene"


class UsageError(ValueError):
    """A command-line option is missing, malformed or out of range."""


class FarmError(RuntimeError):
    """The run cannot go on (output not writable, disk full, workers cannot start)."""


@dataclass(frozen=True)
class RunConfig:
    """Everything one farm run needs; built by parse_args."""

    out: Path
    scenes: int
    seed: int
    first: int = 0
    scene: SceneOptions = field(default_factory=SceneOptions)
    workers: int = 1
    recycle: int = 100  # a worker start (bpy, anny) costs ~5 s; RSS stays ~1.1 GB over 60 scenes
    timeout: float = 1800.0
    retries: int = 3
    resume: bool = False
    ray: str | None = None
    job_module: str = DEFAULT_JOB_MODULE
    progress: bool = True
    pin: bool = True  # local workers pinned to disjoint cores (farm.execution.pool.worker_cpus)

    @property
    def indices(self) -> range:
        return range(self.first, self.first + self.scenes)
