"""A training campaign that outlives an interruption (issue 45):

    python -m model.campaign --name NAME --scenes N --seed S --steps K [farm options] [-- model.train options]

Everything it makes lives in the campaign's folder in the cache, outside the work tree (as the body
model's cache does): CACHE/campaigns/NAME, CACHE = $RELIGHT_CACHE or ~/.cache/relight.

  campaign.json  the settings: the farm's, the pack's and model.train's; a rerun that changes them is
                 refused (only --steps, --device, --threads, --workers and --quiet may change)
  farm/          the farm's scenes: python -m farm --resume, so the scenes already written are
                 skipped (each index drawn from the seed: the same scene whenever it is rendered)
  pack.npz       the training pack (model.samples.training_pack), made again when the scenes change
  run/           python -m model.train --from-pack pack.npz --out run: checkpoints/last.ckpt every
                 --ckpt-every steps (written atomically), resumed from with its optimizer and step

So the same command, rerun after a kill at any point, continues where it stopped; with the cache
gone it starts again from the farm's seeds. `--pack PACK.npz` trains from a pack made elsewhere (no
farm, no Blender: a GPU machine carries only the pack); `--pack-only` stops once the pack is made.
A damaged checkpoint stops the campaign with one line naming it (model.train.check_checkpoint).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

from relight.files.fileio import atomic_write_json

# model.train options that may change between the runs of one campaign (how, not what, it trains)
RUNTIME_OPTIONS = ("steps", "device", "threads", "workers", "quiet")
NAME = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]{0,63}$")


def _die_with_parent() -> None:
    """In the farm's process before exec: SIGKILL when the campaign dies (Linux), so that a killed
    campaign leaves no farm writing into the folder the next run resumes (the farm does the same
    for its workers: farm/execution/pool.py)."""
    import ctypes
    import signal

    try:
        ctypes.CDLL(None, use_errno=True).prctl(1, signal.SIGKILL)  # PR_SET_PDEATHSIG
    except (OSError, AttributeError):
        pass


def cache_root() -> Path:
    return Path(os.environ.get("RELIGHT_CACHE") or Path.home() / ".cache" / "relight")


def parse_args(argv=None):
    argv = list(sys.argv[1:] if argv is None else argv)
    train_args = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    p = argparse.ArgumentParser(prog="python -m model.campaign", description=__doc__.splitlines()[0],
                                epilog="Options after -- go to python -m model.train (e.g. -- --preset geo-small "
                                       "--batch 8 --lr 1e-3 --device cuda).")
    p.add_argument("--name", required=True, help="the campaign's name (its folder in the cache)")
    p.add_argument("--cache", type=Path, default=None, help="cache folder (default $RELIGHT_CACHE or ~/.cache/relight)")
    p.add_argument("--steps", type=int, required=True, help="training steps in all (a rerun may raise it)")
    p.add_argument("--pack", type=Path, default=None, metavar="PACK.npz",
                   help="train from this training pack; no farm (its settings are the pack's)")
    p.add_argument("--pack-only", action="store_true", help="stop once the pack is made; print its path")
    p.add_argument("--out", type=Path, default=None, help="also copy the final model.safetensors/.json here")
    f = p.add_argument_group("farm (python -m farm)")
    f.add_argument("--scenes", type=int, default=None)
    f.add_argument("--seed", type=int, default=None)
    f.add_argument("--res", type=int, default=128)
    f.add_argument("--lights", type=int, default=2)
    f.add_argument("--samples", type=int, default=16)
    f.add_argument("--framing", default="full-body")
    f.add_argument("--hard-lights", type=float, default=0.0)
    f.add_argument("--light-pool", default="train")
    f.add_argument("--farm-workers", type=int, default=1)
    f.add_argument("--farm-job-module", default=None, help=argparse.SUPPRESS)  # tests: the farm's --job-module
    k = p.add_argument_group("pack")
    k.add_argument("--size", type=int, default=128, help="training crop size")
    k.add_argument("--order", type=int, default=4)
    args = p.parse_args(argv)
    if not NAME.match(args.name):
        p.error(f"--name {args.name!r}: letters, digits, '.', '_' and '-' only (it names a folder)")
    if args.pack is None and (args.scenes is None or args.seed is None):
        p.error("--scenes and --seed are needed to render the scenes (or give --pack)")
    if args.steps < 1:
        p.error("--steps must be >= 1")
    args.train_args = train_args
    return args


def farm_settings(args) -> dict:
    return {"scenes": args.scenes, "seed": args.seed, "res": args.res, "lights": args.lights,
            "samples": args.samples, "framing": args.framing, "hard_lights": args.hard_lights,
            "light_pool": args.light_pool, "order": max(args.order, 4)}


def farm_argv(settings: dict, out: Path, workers: int, job_module: str | None = None) -> list[str]:
    """The farm's command line for the campaign's scenes (--resume: finished ones are kept)."""
    s = settings
    return [sys.executable, "-m", "farm", "--out", str(out), "--scenes", str(s["scenes"]), "--seed", str(s["seed"]),
            "--res", str(s["res"]), "--lights", str(s["lights"]), "--samples", str(s["samples"]),
            "--order", str(s["order"]), "--framing", s["framing"], "--hard-lights", str(s["hard_lights"]),
            "--light-pool", s["light_pool"], "--workers", str(workers), "--resume", "--no-progress",
            *([] if job_module is None else ["--job-module", job_module])]


def train_settings(train_args: list[str], steps: int) -> dict:
    """model.train's parsed options that make the run what it is (RUNTIME_OPTIONS and the campaign's
    own paths left out)."""
    from model.train import parse_args as train_parse

    parsed = vars(train_parse(["--from-pack", "unused.npz", "--out", "unused", "--steps", str(steps)]
                              + train_args, check_pack=False))
    return {k: v for k, v in parsed.items() if k not in RUNTIME_OPTIONS + ("from_pack", "out", "resume", "data")}


def settle_settings(folder: Path, settings: dict) -> None:
    """Record the campaign's settings, or check them against those it was started with."""
    path = folder / "campaign.json"
    if path.is_file():
        try:
            before = json.loads(path.read_text())
        except (OSError, ValueError) as exc:
            raise ValueError(f"{path}: unreadable ({exc}); remove it to start the campaign again") from None
        changed = []
        for key in sorted(set(before) | set(settings)):
            old, new = before.get(key), settings.get(key)
            if isinstance(old, dict) and isinstance(new, dict):
                changed += [f"{key}.{k} {old.get(k)!r} -> {new.get(k)!r}" for k in sorted(set(old) | set(new))
                            if old.get(k) != new.get(k)]
            elif old != new:
                changed.append(f"{key} {str(old)[:40]} -> {str(new)[:40]}")
        if changed:
            raise ValueError(f"campaign {folder.name} was started with other settings ({'; '.join(changed)}; "
                             f"{path}); use another --name, or remove {folder} to start again")
        return
    folder.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, settings, indent=1, sort_keys=True)


def scene_list(folder: Path) -> list[list[str]]:
    from relight.files.dataset import list_finished_scenes, read_sidecar

    return [[p.stem, read_sidecar(p)["exr_sha256"]] for p in list_finished_scenes(folder)]


def make_pack(folder: Path, settings: dict, pack: Path) -> None:
    """The farm's scenes packed; an existing pack is kept when it holds exactly those scenes."""
    from relight.files.dataset import list_finished_scenes

    from model.samples.training_pack import read_manifest, write_training_pack

    scenes = scene_list(folder / "farm")
    if pack.is_file():
        try:
            manifest = read_manifest(pack)
            if [[s["name"], s["exr_sha256"]] for s in manifest["scenes"]] == scenes and \
                    manifest["source"] == settings["farm"]:
                return
        except ValueError as exc:
            print(f"model.campaign: {exc}; packing again", file=sys.stderr)
    checkpoint = folder / "run" / "checkpoints" / "last.ckpt"
    if checkpoint.exists():
        raise ValueError(f"{checkpoint} was trained on other scenes than {folder / 'farm'} now holds; "
                         f"remove {folder / 'run'} to train again from step 0")
    write_training_pack(list_finished_scenes(folder / "farm"), pack, settings["pack"]["size"],
                        settings["pack"]["order"], source=settings["farm"])


def run(args) -> Path:
    """Run (or continue) the campaign; returns the final weights' path (the pack's with --pack-only)."""
    folder = (args.cache or cache_root()) / "campaigns" / args.name
    settings = {"pack": {"size": args.size, "order": args.order}}
    if args.pack is not None:
        from model.samples.training_pack import read_manifest

        manifest = read_manifest(args.pack)
        settings.update(farm=manifest["source"], pack_file=str(args.pack.resolve()),
                        scenes=[[s["name"], s["exr_sha256"]] for s in manifest["scenes"]],
                        pack={"size": manifest["size"], "order": manifest["order"]})
        pack = args.pack
    else:
        settings["farm"] = farm_settings(args)
        pack = folder / "pack.npz"
    # the pack's size and order, unless model.train's options after -- say otherwise (then refused there)
    args.train_args = ["--size", str(settings["pack"]["size"]), "--order", str(settings["pack"]["order"]),
                       *args.train_args]
    settings["train"] = train_settings(args.train_args, args.steps)
    settle_settings(folder, settings)
    if args.pack is None:
        cmd = farm_argv(settings["farm"], folder / "farm", args.farm_workers, args.farm_job_module)
        print(f"model.campaign: farm: {' '.join(cmd[2:])}", file=sys.stderr)
        done = subprocess.run(cmd, check=False, preexec_fn=_die_with_parent if sys.platform == "linux" else None)
        if done.returncode != 0:
            raise ValueError(f"the farm stopped (exit {done.returncode}); rerun the campaign to continue")
        make_pack(folder, settings, pack)
    if args.pack_only:
        return pack
    from model.train import parse_args as train_parse, train

    run_dir = folder / "run"
    train_argv = ["--from-pack", str(pack), "--out", str(run_dir), "--steps", str(args.steps)] + args.train_args
    if (run_dir / "checkpoints" / "last.ckpt").exists():
        train_argv.append("--resume")
    weights = train(train_parse(train_argv))
    if args.out is not None:
        args.out.mkdir(parents=True, exist_ok=True)
        for path in (weights, weights.with_suffix(".json")):
            shutil.copyfile(path, args.out / path.name)
        weights = args.out / weights.name
    return weights


def main(argv=None) -> int:
    args = parse_args(argv)
    try:
        path = run(args)
    except (ValueError, FloatingPointError) as exc:
        print(f"model.campaign: error: {exc}", file=sys.stderr)
        return 2
    print(f"wrote {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
