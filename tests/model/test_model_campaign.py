"""A training campaign that outlives an interruption (model.campaign): killed, it continues at its
last checkpoint on the same loss trajectory; a damaged checkpoint stops it naming the file; the
farm's finished scenes are kept and its settings cannot change under it."""

import csv
import json
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from model import campaign
from model.samples.synthetic import write_analytic_dataset
from model.samples.training_pack import read_training_pack, write_training_pack

pytestmark = pytest.mark.usefixtures("one_thread")  # tests/conftest.py
ROOT = Path(__file__).resolve().parents[2]
STEPS, CKPT_EVERY = 40, 6
# a tiny network on 16 px crops: a step is milliseconds, so a run is short and a kill lands mid-run
TRAIN = ["--", "--width", "4", "--depth", "2", "--batch", "2", "--lr", "1e-3", "--lr-schedule", "cosine",
         "--padding", "1", "--val-every", "1000", "--ckpt-every", str(CKPT_EVERY), "--log-every", "1", "--quiet",
         "--threads", "1", "--light-tint", "0.1"]


@pytest.fixture(scope="module")
def pack(tmp_path_factory):
    folder = tmp_path_factory.mktemp("analytic")
    scenes = write_analytic_dataset(folder / "data", n_scenes=7, size=32, order=2, lights=("studio", "city", "venice"))
    return write_training_pack(scenes, folder / "pack.npz", 16, 2, padding=1, source={"analytic": 7})


def losses(run: Path) -> dict[int, float]:
    """Step -> training loss over every logged version of a run (a resumed run logs a new version)."""
    out = {}
    for path in sorted((run / "logs").glob("version_*/metrics.csv")):
        with open(path, newline="") as f:
            for row in csv.DictReader(f):
                if row.get("train/total"):
                    out[int(row["step"])] = float(row["train/total"])
    return out


def test_a_killed_campaign_resumes_at_its_checkpoint_on_the_same_loss_trajectory(pack, tmp_path):
    """One campaign runs through; another is SIGKILLed once its first checkpoint exists, then the same
    command continues it. The continued run starts at a checkpoint's step k (k < STEPS: it was cut
    short) and from there logs the uninterrupted run's losses, step for step (same batches, same
    augmentation, optimizer and schedule restored). CPU float32 in one process kind: the tolerance is
    float32's rounding, not a loosened bound."""
    cache = tmp_path / "cache"
    env = {**os.environ, "RELIGHT_CACHE": str(cache), "PYTHONPATH": str(ROOT)}
    args = ["--pack", str(pack), "--steps", str(STEPS)]
    assert campaign.main(["--name", "whole", "--cache", str(cache), *args, *TRAIN]) == 0
    whole = losses(cache / "campaigns" / "whole" / "run")
    assert sorted(whole) == list(range(STEPS))

    run = cache / "campaigns" / "cut" / "run"
    proc = subprocess.Popen([sys.executable, "-m", "model.campaign", "--name", "cut", *args, *TRAIN], cwd=ROOT,
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 300
        while not (run / "checkpoints" / "last.ckpt").exists() and proc.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.005)
        proc.send_signal(signal.SIGKILL)
    finally:
        _, err = proc.communicate(timeout=60)
    assert proc.returncode == -signal.SIGKILL, f"the campaign ended before it was killed:\n{err.decode()[-2000:]}"
    assert not (run / "model.safetensors").exists()

    assert campaign.main(["--name", "cut", "--cache", str(cache), *args, *TRAIN]) == 0
    resumed = losses(run)
    versions = sorted((run / "logs").glob("version_*/metrics.csv"))
    with open(versions[-1], newline="") as f:
        first = min(int(r["step"]) for r in csv.DictReader(f) if r.get("train/total"))
    assert first % CKPT_EVERY == 0 and 0 < first < STEPS
    for step in range(first, STEPS):
        assert resumed[step] == pytest.approx(whole[step], rel=1e-5, abs=1e-6), step
    record = json.loads((run / "model.json").read_text())["training"]
    assert record["steps"] == STEPS and record["pack_source"] == {"analytic": 7}


def test_a_damaged_checkpoint_stops_the_campaign_naming_it(pack, tmp_path, capsys):
    cache = tmp_path / "cache"
    args = ["--name", "c", "--cache", str(cache), "--pack", str(pack)]
    assert campaign.main([*args, "--steps", "4", *TRAIN]) == 0
    last = cache / "campaigns" / "c" / "run" / "checkpoints" / "last.ckpt"
    whole = last.read_bytes()
    for damaged in (whole[: len(whole) // 3], b"\0" * 4096, whole[:100] + b"x" * (len(whole) - 100)):
        last.write_bytes(damaged)
        capsys.readouterr()
        assert campaign.main([*args, "--steps", "8", *TRAIN]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and str(last) in err[0] and "damaged or truncated" in err[0], err
        assert last.read_bytes() == damaged  # left for the user to see, not trained over
    record = json.loads((cache / "campaigns" / "c" / "run" / "model.json").read_text())
    assert record["training"]["steps"] == 4  # nothing trained on from the damaged file


def test_a_campaign_refuses_other_settings_under_its_name(pack, tmp_path, capsys):
    cache = tmp_path / "cache"
    args = ["--name", "c", "--cache", str(cache), "--pack", str(pack), "--steps", "2"]
    assert campaign.main([*args, *TRAIN]) == 0
    capsys.readouterr()
    assert campaign.main([*args, *TRAIN, "--lr", "5e-4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "other settings (train.lr 0.001 -> 0.0005;" in err[0] and "campaign.json" in err[0]
    # how it trains may change: more steps, other threads; --out gets a copy of the final weights
    assert campaign.main([*args[:-1], "4", "--out", str(tmp_path / "final"), *TRAIN, "--threads", "2"]) == 0
    run = cache / "campaigns" / "c" / "run"
    for name in ("model.safetensors", "model.json"):
        assert (tmp_path / "final" / name).read_bytes() == (run / name).read_bytes()
    assert json.loads((run / "model.json").read_text())["training"]["steps"] == 4


def test_the_farms_finished_scenes_are_kept_and_packed_once(tmp_path, monkeypatch, capsys):
    """The campaign's farm runs with --resume into the cache ($RELIGHT_CACHE): scenes already there
    are skipped by index, not rendered again; the pack is made from them once and kept while they
    are the same scenes."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("RELIGHT_CACHE", str(cache))
    farm = cache / "campaigns" / "f" / "farm"
    write_analytic_dataset(farm, n_scenes=3, size=32, order=4, lights=("studio", "city", "venice"))
    args = ["--name", "f", "--scenes", "3", "--seed", "0", "--steps", "2", "--size", "16", "--order", "2", *TRAIN]
    before = {p.name: p.stat().st_mtime_ns for p in farm.glob("scene_*")}
    assert campaign.main(args) == 0
    assert {p.name: p.stat().st_mtime_ns for p in farm.glob("scene_*")} == before
    run = json.loads((farm / "farm_runlog.json").read_text())["runs"][-1]
    assert run["config"]["seed"] == 0 and run["config"]["resume"] and run["summary"]["skipped"] == 3
    assert run["summary"]["done"] == 0 and run["workers_started"] == 0
    pack = read_training_pack(cache / "campaigns" / "f" / "pack.npz")
    assert pack.names == ["scene_000000", "scene_000001", "scene_000002"]
    assert pack.manifest["source"] == campaign.farm_settings(campaign.parse_args(args))
    made = (cache / "campaigns" / "f" / "pack.npz").stat().st_mtime_ns
    assert campaign.main(args[:7] + ["4"] + args[8:]) == 0  # more steps: the same pack
    assert (cache / "campaigns" / "f" / "pack.npz").stat().st_mtime_ns == made
    capsys.readouterr()
    assert campaign.main(args[:5] + ["4"] + args[6:]) == 2  # another seed: other scenes, refused
    assert "farm.seed 0 -> 4" in capsys.readouterr().err
    # the farm's command: the campaign's seed and settings, into the cache, resuming
    argv = campaign.farm_argv(pack.manifest["source"], farm, 1)
    assert argv[argv.index("--seed") + 1] == "0" and argv[argv.index("--out") + 1] == str(farm)
    assert "--resume" in argv


def _alive(pid: int) -> bool:
    """Whether `pid` still runs (a zombie, killed but not yet reaped, counts as gone)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (FileNotFoundError, ProcessLookupError):
        return False


@pytest.mark.skipif(sys.platform != "linux", reason="PR_SET_PDEATHSIG is Linux's")
def test_a_killed_campaign_takes_its_farm_with_it(tmp_path):
    """Killed while its farm renders, the campaign leaves no farm writing into the folder that the
    next run resumes (before: the farm and its worker rendered on, beside the next run's farm)."""
    faults = tmp_path / "faults"
    faults.mkdir()
    env = {**os.environ, "RELIGHT_CACHE": str(tmp_path / "cache"), "PYTHONPATH": str(ROOT),
           "FARM_FAULT_DIR": str(faults), "FARM_FAULT_SLOW_ALL": "1", "FARM_FAULT_SLOW": "60"}
    proc = subprocess.Popen([sys.executable, "-m", "model.campaign", "--name", "k", "--scenes", "2", "--seed", "0",
                             "--steps", "1", "--farm-job-module", "tests.support.farm_fault_job", "--size", "16",
                             "--order", "2", *TRAIN], cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.DEVNULL)
    events = faults / "events.log"
    try:
        deadline = time.monotonic() + 120
        while not (events.exists() and events.read_text().strip()) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert events.exists(), "the farm's worker never started"
        worker = int(events.read_text().split()[2])  # "start INDEX PID"
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
        deadline = time.monotonic() + 20
        while _alive(worker) and time.monotonic() < deadline:
            time.sleep(0.05)
        assert not _alive(worker), "the farm's worker renders on after its campaign was killed"
    finally:
        if proc.poll() is None:
            proc.kill()
