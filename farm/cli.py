"""Command line of the render farm: one parser for `blender -b -P farm/render.py -- ...` and `python -m farm ...`.

Exit codes: 0 every scene finished; 1 the run could not finish (failed scenes,
unwritable or full output disk, workers that cannot start); 2 bad options;
130 interrupted.
"""

from __future__ import annotations

import argparse
import os
import sys
from pathlib import Path

from farm.synthesis.camera import FRAMINGS, parse_framings
from farm.synthesis.scene_options import DENOISE_PREFILTERS, LIGHT_POOLS, LOOK_POOLS, SPECULAR_MODES, SceneOptions
from farm.execution.run_config import DEFAULT_JOB_MODULE, FarmError, RunConfig, UsageError
from relight.files import scene_passes
from relight.files.argument_types import bounded_int, finite_float

# Limits the runner enforces before any worker starts. Scene indices are
# written with six digits (scene_NNNNNN), so first + scenes <= 1,000,000.
MAX_SCENE_INDEX = 999_999


class _OneLineParser(argparse.ArgumentParser):
    """argparse that reports a bad command line as one line on stderr and exit code 2."""

    def error(self, message: str):  # argparse's hook
        raise UsageError(message)


def _passes(text: str) -> frozenset:
    names = [p.strip() for p in text.split(",") if p.strip()]
    unknown = sorted(set(names) - set(scene_passes.CHOICES))
    if unknown or not names:
        raise argparse.ArgumentTypeError(
            f"--passes must be a comma list of {','.join(sorted(scene_passes.CHOICES))}, got {text!r}"
        )
    return frozenset(names)


def _framing(text: str) -> str:
    try:
        return ",".join(parse_framings(text))
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _people(text: str) -> str:
    from farm.synthesis.people import parse_people

    try:
        lo, hi = parse_people(text)
    except ValueError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None
    return str(lo) if lo == hi else f"{lo}-{hi}"


def build_parser() -> argparse.ArgumentParser:
    p = _OneLineParser(
        prog="farm",
        description="Render synthetic relighting scenes (EXR + JSON sidecar per scene).",
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
        epilog="Under Blender: blender -b -P farm/render.py -- --out DIR --scenes N --seed S",
    )
    p.add_argument("--out", type=Path, required=True, help="output folder (created)")
    p.add_argument("--scenes", type=bounded_int(1, MAX_SCENE_INDEX + 1), required=True,
                   help="number of scenes to render")
    p.add_argument("--seed", type=bounded_int(0, 2**32 - 1), required=True,
                   help="dataset seed; scene i draws from rng([seed, i])")
    p.add_argument("--first", type=bounded_int(0, MAX_SCENE_INDEX), default=0,
                   help="index of the first scene (split a dataset across machines)")
    s = p.add_argument_group("scene")
    s.add_argument("--res", type=bounded_int(16, 4096), default=256, help="image side in pixels")
    s.add_argument("--lights", type=bounded_int(1, 64), default=4, help="lights K per scene")
    s.add_argument("--samples", type=bounded_int(1, 65536), default=64,
                   help="path-tracing samples per pixel")
    s.add_argument("--denoise", action=argparse.BooleanOptionalAction, default=True,
                   help="OIDN-denoise the path-traced images")
    s.add_argument("--denoise-prefilter", choices=DENOISE_PREFILTERS, default="fast",
                   help="OIDN guide prefilter: fast (guides as rendered) or accurate (denoised too; slower)")
    s.add_argument("--order", type=bounded_int(1, 8), default=4, help="SH order N")
    s.add_argument("--directions", type=bounded_int(16, 65536), default=256,
                   help="transport bake directions per vertex")
    s.add_argument("--passes", type=_passes, default=",".join(sorted(scene_passes.DEFAULT)),
                   help="comma list of " + "; ".join(f"{p.name}: {p.what}" for p in scene_passes.PASSES
                                                    if not p.always))
    s.add_argument("--specular", choices=SPECULAR_MODES, default="auto",
                   help="view-dependent specular bake")
    s.add_argument("--light-pool", choices=LIGHT_POOLS, default="train",
                   help="train maps, or only the held-out maps")
    s.add_argument("--look-pool", choices=LOOK_POOLS, default="train",
                   help="the looks training sees, or only the held-out garments, prints, hair, skin and "
                        "accessories (farm/synthesis/looks.py)")
    s.add_argument("--framing", type=_framing, default="full-body",
                   help="framings a scene draws from, uniformly: 'all' or a comma list of "
                        + ",".join(FRAMINGS) + " (farm/synthesis/camera.py)")
    s.add_argument("--hard-lights", type=finite_float(0, 1, what="share"), default=0.0, metavar="SHARE",
                   help="share of the lights that are a hard light (sun, studio key and fill, lamp; "
                        "farm/synthesis/hard_lights.py) instead of a map")
    s.add_argument("--people", type=_people, default="1", metavar="N|LO-HI",
                   help="people per scene: a count, or a range drawn uniformly per scene (2-5: groups, "
                        "farm/synthesis/people.py)")
    s.add_argument("--clip-frames", type=bounded_int(2, 1000), default=None, metavar="F",
                   help="render clips instead of stills: scene i is frame i mod F of clip i // F (farm/clips.py)")
    s.add_argument("--motion", choices=("turn", "sway"), default="turn",
                   help="with --clip-frames: the person turns in place or shifts weight")
    r = p.add_argument_group("runner")
    r.add_argument("--workers", type=bounded_int(1, 256), default=1,
                   help="worker processes (local executor)")
    r.add_argument("--recycle", type=bounded_int(1, 100000), default=100,
                   help="restart a worker after this many scenes")
    # a week is far beyond any single scene
    r.add_argument("--timeout", type=finite_float(0, 7 * 24 * 3600, low_open=True, what="number of seconds"),
                   default=1800.0, help="seconds per scene before kill")
    r.add_argument("--retries", type=bounded_int(0, 100), default=3,
                   help="retries per scene after a failure")
    r.add_argument("--resume", action="store_true", help="skip finished scenes in --out")
    r.add_argument("--ray", metavar="auto|ADDRESS", default=None,
                   help="run on a Ray cluster (extra 'distributed')")
    r.add_argument("--pin", action=argparse.BooleanOptionalAction, default=True,
                   help="pin each local worker to its own share of the cores (when workers <= cores)")
    r.add_argument("--no-progress", dest="progress", action="store_false", help="no progress bar")
    # Module with SceneOptions and render_scene; tests swap in a fault-injecting one.
    r.add_argument("--job-module", default=DEFAULT_JOB_MODULE, help=argparse.SUPPRESS)
    return p


def parse_args(argv: list[str]) -> RunConfig:
    """Parse and range-check a farm command line; raises UsageError with one-line text."""
    a = build_parser().parse_args(argv)
    if a.first + a.scenes - 1 > MAX_SCENE_INDEX:
        raise UsageError(f"--first + --scenes - 1 must be <= {MAX_SCENE_INDEX} (six-digit scene names)")
    if a.ray is not None and not a.ray.strip():
        raise UsageError("--ray needs 'auto' or a cluster address")
    if (a.order + 1) ** 2 > a.directions:
        raise UsageError(
            f"--directions ({a.directions}) must be >= (order+1)^2 = {(a.order + 1) ** 2} "
            "to determine the transport coefficients"
        )
    settings = dict(
        resolution=a.res, lights=a.lights, samples=a.samples, denoise=a.denoise,
        denoise_prefilter=a.denoise_prefilter,
        sh_order=a.order, bake_directions=a.directions, passes=a.passes,
        specular=a.specular, light_pool=a.light_pool, framing=a.framing, hard_lights=float(a.hard_lights),
        people=a.people, look_pool=a.look_pool,
    )
    job_module = a.job_module
    if a.clip_frames is not None and a.people != "1":
        raise UsageError("--clip-frames renders one person: --people must be 1 with it")
    if a.clip_frames is not None:
        from farm import clips

        scene = clips.SceneOptions(**settings, clip_frames=a.clip_frames, motion=a.motion)
        job_module = clips.__name__ if job_module == DEFAULT_JOB_MODULE else job_module
    else:
        scene = SceneOptions(**settings)
    return RunConfig(
        # Absolute: workers run in the repository root, Ray tasks on other nodes.
        out=Path(os.path.abspath(a.out)), scenes=a.scenes, seed=a.seed, first=a.first, scene=scene,
        workers=a.workers, recycle=a.recycle, timeout=a.timeout, retries=a.retries,
        resume=a.resume, ray=a.ray, job_module=job_module, progress=a.progress, pin=a.pin,
    )


def main(argv: list[str] | None = None) -> int:
    """Run the farm; returns the process exit code."""
    argv = sys.argv[1:] if argv is None else argv
    if argv[:1] == ["--summary"]:  # python -m farm --summary DIR: dataset feature fractions (farm/execution/summary.py)
        from farm.execution.summary import main as summary_main
        return summary_main(argv[1:])
    try:
        config = parse_args(argv)
    except UsageError as err:
        print(f"farm: error: {err}", file=sys.stderr)
        return 2
    except SystemExit as exit_:  # --help: a code, not an exception, for Blender's -P
        return int(exit_.code or 0)
    try:
        if config.ray is not None:
            from farm.execution.ray_executor import run_on_ray

            summary = run_on_ray(config)
        else:
            from farm.execution.executors import run_local

            summary = run_local(config)
    except FarmError as err:
        print(f"farm: error: {err}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print("farm: interrupted; finished scenes are kept, rerun with --resume", file=sys.stderr)
        return 130
    if not summary.ok:
        print(f"farm: error: {summary.failed} scenes failed, {summary.not_started} not started; "
              f"see {config.out / 'farm_runlog.json'}", file=sys.stderr)
        return 1
    return 0
