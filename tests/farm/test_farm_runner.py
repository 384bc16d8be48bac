"""The render farm's runner: command line, local worker pool, faults, resume, disk space.

Fault tests use tests/support/farm_fault_job.py, a scene module that writes tiny but
real scene files (relight.files.dataset.write_scene) and crashes, hangs or fails on
demand; the end-to-end tests render with the real farm.scene.render_scene.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import queue
import re
import shutil
import signal
import subprocess
import sys
import time
import types
from pathlib import Path

import pytest

from farm import cli
from farm.execution import pool, progress, runbook
from relight.files.dataset import read_scene

REPO = Path(__file__).resolve().parents[2]
PYTHON = sys.executable
FAULT_JOB = "tests.support.farm_fault_job"


def farm_env(fault_dir: Path, faults: dict | None = None, **extra) -> dict:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
    env["FARM_FAULT_DIR"] = str(fault_dir)
    env["FARM_FAULTS"] = json.dumps(faults or {})
    env.update({k: str(v) for k, v in extra.items()})
    return env


def run_farm(args: list[str], env: dict, timeout: float = 120, entry=("-m", "farm")):
    return subprocess.run([PYTHON, *entry, *args], cwd=REPO, env=env, capture_output=True,
                          text=True, timeout=timeout)


def start_slow_farm(out: Path, env: dict, scenes: int) -> subprocess.Popen:
    """The fault job's farm started in the background (one light a scene, no progress bar)."""
    return subprocess.Popen([PYTHON, "-m", "farm", "--out", str(out), "--scenes", str(scenes), "--seed", "0",
                             "--lights", "1", "--job-module", FAULT_JOB, "--no-progress"],
                            cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def events(fault_dir: Path) -> list[tuple[str, int, int]]:
    """(event, index, pid) lines the fault job logged."""
    path = fault_dir / "events.log"
    if not path.exists():
        return []
    return [(e, int(i), int(p)) for e, i, p in (ln.split() for ln in path.read_text().splitlines())]


def run_log(out: Path) -> dict:
    return json.loads((out / runbook.RUN_LOG_NAME).read_text())


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def error_lines(stderr: str) -> list[str]:
    """stderr minus the progress bar (tqdm redraws with carriage returns)."""
    return [ln for ln in stderr.splitlines() if ln.strip() and "scene/s" not in ln and "|" not in ln]


# -- command line ---------------------------------------------------------------

BAD_OPTIONS = [
    (["--res", "0"], "--res: must be an integer in"),
    (["--res", "abc"], "--res: invalid int value"),
    (["--lights", "0"], "--lights: must be an integer in"),
    (["--samples", "-4"], "--samples: must be an integer in"),
    (["--order", "9"], "--order: must be an integer in"),
    (["--directions", "20"], "--directions (20) must be >= (order+1)^2 = 25"),
    (["--passes", "pt,foo"], "--passes must be a comma list"),
    (["--passes", ","], "--passes must be a comma list"),
    (["--specular", "maybe"], "--specular"),
    (["--light-pool", "test"], "--light-pool"),
    (["--workers", "0"], "--workers: must be an integer in"),
    (["--recycle", "0"], "--recycle: must be an integer in"),
    (["--timeout", "0"], "--timeout: must be a finite number of seconds in (0, 604800]"),
    (["--timeout", "nan"], "--timeout: must be a finite number of seconds in (0, 604800]"),
    (["--retries", "-1"], "--retries: must be an integer in"),
    (["--scenes", "0"], "--scenes: must be an integer in"),
    (["--first", "999999", "--scenes", "2"], "--first + --scenes - 1"),
    (["--bogus"], "unrecognized arguments"),
    (["--ray", " "], "--ray needs 'auto' or a cluster address"),
]


@pytest.mark.parametrize("extra,message", BAD_OPTIONS)
def test_bad_option_is_one_line_and_exit_2(extra, message, tmp_path, capsys):
    base = {"--out": str(tmp_path / "out"), "--scenes": "1", "--seed": "0"}
    for flag in extra:
        base.pop(flag, None)
    argv = [x for kv in base.items() for x in kv] + extra
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("farm: error:") and message in err[0], err
    assert not (tmp_path / "out").exists()  # nothing started


def test_missing_required_option_is_one_line(capsys):
    assert cli.main(["--scenes", "1", "--seed", "0"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["farm: error: the following arguments are required: --out"]


def test_render_py_entry_exit_code_and_blender_argv(tmp_path):
    """farm/render.py as Blender runs it: farm arguments after '--', exit status 2, one line."""
    r = subprocess.run([PYTHON, "farm/render.py", "--", "--out", str(tmp_path), "--scenes", "1",
                        "--seed", "0", "--lights", "65"], cwd=REPO,
                       capture_output=True, text=True, timeout=60)
    assert r.returncode == 2
    assert r.stderr.strip().splitlines() == ["farm: error: argument --lights: must be an integer in [1, 64], got 65"]


def test_options_reach_scene_options_one_to_one():
    config = cli.parse_args(["--out", "x", "--scenes", "3", "--seed", "7", "--res", "64", "--lights", "2",
                             "--samples", "8", "--no-denoise", "--order", "2", "--directions", "64",
                             "--passes", "prt", "--specular", "off", "--light-pool", "heldout",
                             "--denoise-prefilter", "accurate", "--framing", "face,waist-up", "--hard-lights", "0.25",
                             "--people", "2-4", "--look-pool", "heldout"])
    assert config.scene.to_json() == {
        "resolution": 64, "lights": 2, "samples": 8, "denoise": False, "denoise_prefilter": "accurate",
        "sh_order": 2,
        "bake_directions": 64, "passes": ["prt"], "specular": "off", "light_pool": "heldout",
        "framing": "face,waist-up", "hard_lights": 0.25, "people": "2-4",
        "look_pool": "heldout"}
    assert list(config.indices) == [0, 1, 2]
    # The real SceneOptions accepts exactly these fields, and they survive the JSON trip.
    from farm import scene

    options = scene.SceneOptions.from_json(json.loads(json.dumps(config.scene.to_json())))
    options.validate()
    assert (options.resolution, options.lights, options.samples, options.denoise, options.denoise_prefilter,
            options.sh_order, options.bake_directions, options.passes, options.specular, options.light_pool,
            options.framing, options.hard_lights, options.people, options.look_pool) == (
        64, 2, 8, False, "accurate", 2, 64, frozenset({"prt"}), "off", "heldout", "face,waist-up", 0.25, "2-4",
        "heldout")
    assert set(config.scene.to_json()) == {f.name for f in dataclasses.fields(scene.SceneOptions)}
    # Raw float32 channels of a 64x64 prt-only scene: 12 geometry (the head mask included) + 9
    # transport + 2*3*2 per light + a mask for each of up to 4 people.
    assert config.scene.expected_channels() == 12 + 9 + 12 + 4
    assert config.scene.path_traced_images() == 0


def test_worker_command_under_real_blender(monkeypatch):
    """Under Blender the workers are the same Blender binary running farm/worker.py with -P."""
    fake_bpy = types.SimpleNamespace(app=types.SimpleNamespace(binary_path="/opt/blender/blender"))
    monkeypatch.setitem(sys.modules, "bpy", fake_bpy)
    config = cli.parse_args(["--out", "/tmp/o", "--scenes", "1", "--seed", "0"])
    command = pool.worker_command(config)
    assert command[:2] == ["/opt/blender/blender", "-b"]
    assert command[command.index("-P") + 1] == str(REPO / "farm" / "worker.py")
    assert command[command.index("--") + 1:][:2] == ["--job-module", "farm.scene"]
    monkeypatch.setitem(sys.modules, "bpy", types.SimpleNamespace(app=types.SimpleNamespace(binary_path="")))
    assert pool.worker_command(config)[:3] == [sys.executable, "-m", "farm.worker"]


def test_worker_script_protocol(tmp_path):
    """farm/worker.py run as a script (as Blender -P does): ready, one reply per task, exit on EOF."""
    out = tmp_path / "out"
    out.mkdir()
    options = json.dumps(cli.SceneOptions(lights=2, sh_order=2).to_json())
    proc = subprocess.run(
        [PYTHON, "farm/worker.py", "--", "--job-module", FAULT_JOB, "--out", str(out), "--options", options],
        input='{"index": 3, "seed": 5}\n{"index": 4, "seed": 5}\n', cwd=REPO, capture_output=True,
        text=True, timeout=60, env=farm_env(tmp_path, {"4": "raise"}))
    assert proc.returncode == 0, proc.stderr
    replies = [json.loads(ln) for ln in proc.stdout.splitlines()]
    assert [r["event"] for r in replies] == ["ready", "done", "failed"]
    assert replies[1]["index"] == 3 and Path(replies[1]["json"]) == out / "scene_000003.json"
    assert replies[2]["error"] == "RuntimeError: injected failure in scene 4"
    assert replies[2]["disk_full"] is False
    assert read_scene(out / "scene_000003.json").sh_order == 2


# -- local pool: faults -----------------------------------------------------------

def test_crash_hang_and_error_are_retried_then_reported(tmp_path):
    """Scene 2 SIGKILLs its worker once, scene 4 hangs once (timeout), scene 5 always raises."""
    out = tmp_path / "out"
    env = farm_env(tmp_path, {"2": "crash-once", "4": "hang-once", "5": "raise"})
    t0 = time.monotonic()
    r = run_farm(["--out", str(out), "--scenes", "7", "--seed", "1", "--workers", "2", "--timeout", "3",
                  "--retries", "2", "--lights", "2", "--job-module", FAULT_JOB], env)
    wall = time.monotonic() - t0
    assert r.returncode == 1
    assert error_lines(r.stderr)[-1].startswith("farm: error: 1 scenes failed, 0 not started")
    ev = events(tmp_path)
    starts = {i: [p for e, j, p in ev if e == "start" and j == i] for i in range(7)}
    ends = {i: [p for e, j, p in ev if e == "end" and j == i] for i in range(7)}
    # Crash and hang: two attempts, the second in a different (fresh) worker, finished once.
    for i in (2, 4):
        assert len(starts[i]) == 2 and starts[i][0] != starts[i][1] and ends[i] == [starts[i][1]]
    assert len(starts[5]) == 3 and len(set(starts[5])) == 3 and ends[5] == []  # 1 + --retries, fresh each
    for i in (0, 1, 3, 6):
        assert len(starts[i]) == 1 and len(ends[i]) == 1  # never rendered twice
    # The hang costs one timeout (3 s); generous bound against a slow shared machine.
    assert wall < 60
    log = run_log(out)["runs"][-1]
    assert log["finished"] is True
    s = log["summary"]
    assert (s["done"], s["failed"], s["retried"], s["skipped"]) == (6, 1, 4, 0)
    assert s["skipped_passes"] == {"specular": 6}
    # Path-traced images: 6 finished scenes x 2 lights, over the run's wall time.
    assert s["images_per_hour"] == pytest.approx(12 * 3600 / s["wall_seconds"])
    by_index = {rec["index"]: rec for rec in log["scenes"]}
    assert by_index[4]["errors"][0].startswith("timeout after 3 s")
    assert "killed by SIGKILL" in by_index[2]["errors"][0]
    assert by_index[5]["errors"] == ["RuntimeError: injected failure in scene 5"] * 3
    assert "done" in r.stdout and "path-traced images/hour" in r.stdout
    for i in (0, 1, 2, 3, 4, 6):
        read_scene(out / f"scene_{i:06d}.json")  # hash and channels check out
    assert not (out / "scene_000005.json").exists()
    assert sorted(p.name for p in out.iterdir() if p.name.startswith(".")) == []  # no temps left


def test_workers_are_recycled_every_m_scenes(tmp_path):
    out = tmp_path / "out"
    # A relative --out means relative to where the farm was started (workers run elsewhere).
    r = subprocess.run([PYTHON, "-m", "farm", "--out", "out", "--scenes", "5", "--seed", "0",
                        "--recycle", "2", "--lights", "1", "--job-module", FAULT_JOB, "--no-progress"],
                       cwd=tmp_path, env=farm_env(tmp_path), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert sorted(p.name for p in out.glob("scene_*.json")) == [f"scene_{i:06d}.json" for i in range(5)]
    pids = [p for e, _, p in events(tmp_path) if e == "start"]
    # One worker at a time, 2 scenes each: scenes (0,1), (2,3), (4) in three processes.
    assert pids[0] == pids[1] != pids[2] == pids[3] != pids[4] and len(set(pids)) == 3
    run = run_log(out)["runs"][-1]
    assert run["workers_started"] == 3 and run["worker_notes"] == []


def test_retired_workers_are_reaped_while_the_run_goes_on(tmp_path):
    """A worker retired after `recycle` scenes is waited for when it exits, not at the end of the
    run: a long campaign (one worker per 100 scenes) kept every past worker as a zombie, with its
    pipes and its temp folder, until it ended."""
    out = tmp_path / "out"
    r = subprocess.run([PYTHON, "-m", "farm", "--out", str(out), "--scenes", "6", "--seed", "0",
                        "--recycle", "1", "--lights", "1", "--job-module", FAULT_JOB, "--no-progress"],
                       env=farm_env(tmp_path), capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    unreaped = {i: n for e, i, n in events(tmp_path) if e == "unreaped"}
    assert sorted(unreaped) == list(range(6))
    # the worker retired just before may not have been waited for yet; none older
    assert max(unreaped.values()) <= 1, unreaped
    folders = {line.split()[1] for line in (tmp_path / "tmpdirs.log").read_text().splitlines()}
    assert len(folders) == 6 and not any(Path(f).exists() for f in folders)


def test_killed_worker_is_detected_and_scene_retried(tmp_path):
    """SIGKILL a worker from outside while it renders; its scene reruns on a fresh worker."""
    out = tmp_path / "out"
    env = farm_env(tmp_path, FARM_FAULT_SLOW_ALL="1", FARM_FAULT_SLOW="0.6")
    proc = start_slow_farm(out, env, 4)
    victim = None
    deadline = time.monotonic() + 60
    while victim is None and time.monotonic() < deadline:
        started = [(i, p) for e, i, p in events(tmp_path) if e == "start" and i == 1]
        victim = started[0][1] if started else None
        time.sleep(0.05)
    assert victim is not None
    os.kill(victim, signal.SIGKILL)
    stdout, stderr = proc.communicate(timeout=90)
    assert proc.returncode == 0, stderr
    ev = events(tmp_path)
    assert [p for e, i, p in ev if e == "start" and i == 1][1] != victim
    # Every worker had its own temp folder, removed with it (the killed one's scratch too).
    tmpdirs = dict(ln.split() for ln in (tmp_path / "tmpdirs.log").read_text().splitlines())
    assert len(set(tmpdirs.values())) == len(tmpdirs) >= 2 and str(victim) in tmpdirs
    assert all(Path(d).name.startswith("farm_worker0_") and not Path(d).exists() for d in tmpdirs.values())
    assert sorted(i for e, i, _ in ev if e == "end") == [0, 1, 2, 3]
    s = run_log(out)["runs"][-1]["summary"]
    assert (s["done"], s["retried"], s["failed"]) == (4, 1, 0)
    # Rerun with --resume: nothing left to render, nothing touched.
    before = {p.name: (p.stat().st_mtime_ns, digest(p)) for p in out.glob("scene_*")}
    r = run_farm(["--out", str(out), "--scenes", "4", "--seed", "0", "--lights", "1", "--resume",
                  "--job-module", FAULT_JOB, "--no-progress"], env)
    assert r.returncode == 0, r.stderr
    assert len(events(tmp_path)) == len(ev)  # no scene started
    assert {p.name: (p.stat().st_mtime_ns, digest(p)) for p in out.glob("scene_*")} == before
    s = run_log(out)["runs"][-1]["summary"]
    assert (s["done"], s["skipped"], s["failed"]) == (0, 4, 0)


def test_resume_after_the_farm_is_killed(tmp_path):
    """SIGKILL the farm (its workers die with it) mid-run; --resume keeps finished scenes
    byte for byte, cleans stray temps and renders every other scene exactly once."""
    out = tmp_path / "out"
    args = ["--out", str(out), "--scenes", "6", "--seed", "3", "--workers", "2", "--lights", "1",
            "--job-module", FAULT_JOB, "--no-progress"]
    env = farm_env(tmp_path, FARM_FAULT_SLOW_ALL="1", FARM_FAULT_SLOW="0.5")
    proc = subprocess.Popen([PYTHON, "-m", "farm", *args], cwd=REPO, env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    while len(list(out.glob("scene_*.json"))) < 2 and time.monotonic() < deadline:
        time.sleep(0.02)
    os.kill(proc.pid, signal.SIGKILL)
    proc.wait(timeout=30)
    first_pids = {p for e, _, p in events(tmp_path)}
    time.sleep(0.3)
    for pid in first_pids:  # workers die with the farm (PR_SET_PDEATHSIG)
        assert not Path(f"/proc/{pid}").exists() or "zombie" in Path(f"/proc/{pid}/status").read_text()
    finished = sorted(int(p.stem[6:]) for p in out.glob("scene_*.json"))
    assert 2 <= len(finished) < 6
    before = {p.name: (p.stat().st_mtime_ns, digest(p)) for p in out.glob("scene_*")}
    unfinished = [i for i in range(6) if i not in finished]
    stray = [out / f".scene_{unfinished[0]:06d}.exr.x1y2.tmp.exr", out / f"scene_{unfinished[-1]:06d}.exr"]
    for path in stray:
        path.write_bytes(b"partial")
    (tmp_path / "events.log").unlink()

    again = run_farm(args, env)  # without --resume: refuses, touches nothing
    assert again.returncode == 1
    assert error_lines(again.stderr) == [
        f"farm: error: {out} already holds {len(finished)} finished scenes of this range; "
        "pass --resume to keep them and render the rest"]
    assert all(p.exists() for p in stray)

    r = run_farm(args + ["--resume"], env)
    assert r.returncode == 0, r.stderr
    ev = events(tmp_path)
    assert sorted(i for e, i, _ in ev if e == "start") == unfinished  # each once, none finished
    assert {p.name: (p.stat().st_mtime_ns, digest(p)) for p in out.glob("scene_*")
            if p.name in before} == before
    assert not any(p.exists() and p.read_bytes() == b"partial" for p in stray)
    for i in range(6):
        read_scene(out / f"scene_{i:06d}.json")
    runs = run_log(out)["runs"]
    assert runs[-1]["summary"]["skipped"] == len(finished)
    assert runs[-1]["summary"]["done"] == len(unfinished)
    # The killed farm could not remove its workers' temp folders (documented); tidy up.
    for line in (tmp_path / "tmpdirs.log").read_text().splitlines():
        shutil.rmtree(line.split()[1], ignore_errors=True)


# -- output disk ---------------------------------------------------------------------

def test_unwritable_output_is_one_line(tmp_path):
    blocker = tmp_path / "file"
    blocker.write_text("not a folder")
    r = run_farm(["--out", str(blocker / "out"), "--scenes", "1", "--seed", "0"], farm_env(tmp_path))
    assert r.returncode == 1
    assert error_lines(r.stderr) == [f"farm: error: output folder {blocker / 'out'} is not writable: Not a directory"]


def _on_small_disk(size: str, shell: str, env: dict, timeout: float = 120):
    """Run `shell` in a private mount namespace with a tmpfs of `size` at $DISK (we are root)."""
    return subprocess.run(["unshare", "-m", "sh", "-c", f'mount -t tmpfs -o size={size} tmpfs "$DISK" && {shell}'],
                          cwd=REPO, env=env, capture_output=True, text=True, timeout=timeout)


def test_disk_without_room_for_a_scene_stops_before_rendering(tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    env = farm_env(tmp_path, DISK=str(disk))
    # A 256x256 scene at K=4, order 4 holds 12 (the head mask included) + 25 + 3*4*3 + 5 (body) =
    # 78 float32 channels: 78 * 256*256*4 B = 19.5 MiB raw, + 1 MiB sidecar allowance = 20.5 MiB.
    r = _on_small_disk("4m", f'{PYTHON} -m farm --out "$DISK/out" --scenes 2 --seed 0 '
                       f"--job-module {FAULT_JOB} --no-progress", env)
    assert r.returncode == 1
    lines = error_lines(r.stderr)
    assert len(lines) == 1 and lines[0].startswith("farm: error: output disk full: 4.0 MiB free in")
    assert "20.5 MiB needed" in lines[0]
    assert events(tmp_path) == []  # no scene started


def test_enospc_while_writing_stops_the_run_and_keeps_finished_scenes(tmp_path):
    disk = tmp_path / "disk"
    disk.mkdir()
    env = farm_env(tmp_path, {"2": "fill"}, DISK=str(disk))
    # At 16x16, K=1, order 1 the pre-check needs (11 + 4 + 6 + 3) * 1 KiB + 1 MiB < 3 MiB free,
    # so the kernel's ENOSPC (the 64 MiB temp of scene 2) is what stops the run.
    r = _on_small_disk("3m", f'{PYTHON} -m farm --out "$DISK/out" --scenes 4 --seed 0 --res 16 --lights 1 '
                       f'--order 1 --job-module {FAULT_JOB} --no-progress; echo "exit=$?"; '
                       f'ls -a "$DISK/out"; cat "$DISK/out/farm_runlog.json"', env)
    assert "exit=1" in r.stdout
    lines = error_lines(r.stderr)
    assert lines == [f"farm: error: output disk full (ENOSPC) while writing scene 2 in {disk / 'out'}"]
    listing = r.stdout.split("exit=1", 1)[1]
    assert "scene_000000.json" in listing and "scene_000001.json" in listing
    assert "scene_000002" not in listing and "scene_000003" not in listing  # temp removed, 3 not started
    log = json.loads(listing[listing.index("{"):])
    s = log["runs"][-1]["summary"]
    assert (s["done"], s["failed"], s["not_started"], s["retried"]) == (2, 1, 1, 0)


def test_sigterm_stops_workers_and_keeps_finished_scenes(tmp_path):
    out = tmp_path / "out"
    env = farm_env(tmp_path, FARM_FAULT_SLOW_ALL="1", FARM_FAULT_SLOW="0.4")
    proc = start_slow_farm(out, env, 20)
    deadline = time.monotonic() + 60
    while not list(out.glob("scene_*.json")) and time.monotonic() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGTERM)
    stdout, stderr = proc.communicate(timeout=60)
    assert proc.returncode == 130
    assert error_lines(stderr) == ["farm: interrupted; finished scenes are kept, rerun with --resume"]
    worker_pids = {p for _, _, p in events(tmp_path)}
    assert all(not Path(f"/proc/{pid}").exists() for pid in worker_pids)
    run = run_log(out)["runs"][-1]
    assert run["finished"] is True and run["summary"]["abort"] == "interrupted"
    done = sorted(rec["index"] for rec in run["scenes"] if rec["status"] == "done")
    # Every scene on disk is in the log (also one written just before the signal), and
    # nothing half-written is left.
    assert done == sorted(int(p.stem[6:]) for p in out.glob("scene_*.json"))
    assert 0 < len(done) < 20
    assert not [p for p in out.iterdir() if p.name.startswith(".")]


# -- end to end with the real scene code ---------------------------------------------

REAL_SCENE = ["--seed", "5", "--res", "64", "--lights", "2", "--samples", "4", "--no-denoise",
              "--order", "2", "--directions", "64", "--no-progress"]


def test_real_scene_end_to_end_through_render_py_then_resume(tmp_path):
    """A 64x64 scene with the real render_scene through the Blender-style entry
    (`python farm/render.py -- ...`), then `python -m farm --resume` adds a second one."""
    out = tmp_path / "out"
    env = farm_env(tmp_path)
    r = run_farm(["--", "--out", str(out), "--scenes", "1", *REAL_SCENE], env, timeout=300,
                 entry=("farm/render.py",))
    assert r.returncode == 0, r.stderr[-2000:]
    scene = read_scene(out / "scene_000000.json")  # SHA-256 and channel list checked
    assert scene.resolution == (64, 64) and scene.sh_order == 2 and scene.meta["seed"] == 5
    assert scene.transport.shape == (64, 64, 9)
    assert len(scene.images) == 2 and len(scene.shading) == 2 and len(scene.prt) == 2
    assert 0.0 <= scene.alpha.min() and scene.alpha.max() <= 1.0 and (scene.alpha > 0.5).mean() > 0.02
    run = run_log(out)["runs"][-1]
    s = run["summary"]
    assert (s["done"], s["failed"], s["skipped"]) == (1, 0, 0)
    # A crash inside bpy is retried (the runner's job), so only consistency is asserted here.
    assert s["retried"] == run["scenes"][0]["attempts"] - 1 == len(run["scenes"][0]["errors"])
    assert s["images_per_hour"] == pytest.approx(2 * 3600 / s["wall_seconds"])
    assert run["scenes"][0]["timings"]["path_trace_render_calls"]  # the sidecar's stages reach the log
    table = dict(re.split(r"\s{2,}", ln.strip(), maxsplit=1) for ln in r.stdout.splitlines() if "  " in ln)
    assert table["done"] == "1" and table["failed"] == "0" and table["retried"] == str(s["retried"])
    assert float(table["path-traced images/hour"]) == pytest.approx(s["images_per_hour"], rel=1e-3)
    first = {p.name: (p.stat().st_mtime_ns, digest(p)) for p in out.glob("scene_000000.*")}

    r = run_farm(["--out", str(out), "--scenes", "2", "--resume", *REAL_SCENE], env, timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert {p.name: (p.stat().st_mtime_ns, digest(p)) for p in out.glob("scene_000000.*")} == first
    second = read_scene(out / "scene_000001.json")
    assert second.index == 1 and second.resolution == (64, 64)
    s = run_log(out)["runs"][-1]["summary"]
    assert (s["done"], s["skipped"], s["failed"]) == (1, 1, 0)
    assert not [p for p in out.iterdir() if p.name.startswith(".")]  # no temps or scratch left


def test_progress_without_tqdm_prints_lines_with_eta(tmp_path, capsys):
    bar = progress._PlainProgress(total=4, file=sys.stderr)
    bar.t0 -= 10.0  # pretend 10 s have passed: 2 of 4 done -> 10 s left at the same rate
    bar.set_postfix(failed=0, retried=1)
    bar.update(2)
    assert capsys.readouterr().err == "farm: 2/4 scenes, 10 s, ETA 10 s failed=0 retried=1\n"


def test_worker_output_that_is_not_protocol_is_ignored(tmp_path):
    """Blender prints a banner on stdout before the worker script takes it over; such lines
    (even ones that parse as JSON) must not reach the farm as messages."""
    script = tmp_path / "fake_worker.py"
    script.write_text('import sys\nprint("Blender 5.0.1 (hash 0123)")\nprint("1")\nprint("[]")\n'
                      'print(\'{"event": "ready", "pid": 1}\')\nsys.stdout.flush()\n')
    events_q = queue.Queue()
    worker = pool._Worker(0, [PYTHON, str(script)], tmp_path / "w.log", events_q, threads=1)
    got = [events_q.get(timeout=30), events_q.get(timeout=30)]
    assert [m for _, m in got] == [{"event": "ready", "pid": 1}, None]  # then EOF
    worker.proc.wait(timeout=30)
    worker.remove_tmp()
    assert not worker.tmp.exists()


def test_worker_that_cannot_start_stops_the_run_with_its_error(tmp_path):
    out = tmp_path / "out"
    r = run_farm(["--out", str(out), "--scenes", "3", "--seed", "0", "--job-module", "tests.no_such_job",
                  "--no-progress"], farm_env(tmp_path))
    assert r.returncode == 1
    lines = error_lines(r.stderr)
    assert len(lines) == 1 and lines[0].startswith("farm: error: worker could not start (worker ")
    assert "exited with code 1): ModuleNotFoundError: No module named 'tests.no_such_job'" in lines[0]
    s = run_log(out)["runs"][-1]["summary"]
    assert (s["done"], s["failed"], s["not_started"]) == (0, 0, 3)


def test_worker_cpus_are_disjoint_equal_shares_or_none():
    from farm.execution.pool import worker_cpus

    cores = {0, 1, 2, 3, 5, 7}
    shares = [worker_cpus(slot, 3, cores) for slot in range(3)]
    assert shares == [{0, 1}, {2, 3}, {5, 7}]
    assert [worker_cpus(slot, 4, cores) for slot in range(4)] == [{0}, {1}, {2}, {3}]  # 5, 7 left idle
    assert worker_cpus(0, 7, cores) is None  # more workers than cores: the OS schedules them
    assert worker_cpus(0, 1, {3}) == {3}


def test_started_worker_runs_on_its_pinned_cores():
    import functools
    import subprocess

    from farm.execution.pool import _start_child

    core = min(os.sched_getaffinity(0))
    out = subprocess.run(
        [sys.executable, "-c", "import os; print(sorted(os.sched_getaffinity(0)))"],
        capture_output=True, text=True, check=True, preexec_fn=functools.partial(_start_child, {core}),
    ).stdout
    assert json.loads(out) == [core]


def test_pin_flag_reaches_the_run_config(tmp_path):
    assert cli.parse_args(["--out", str(tmp_path), "--scenes", "1", "--seed", "0"]).pin is True
    assert cli.parse_args(["--out", str(tmp_path), "--scenes", "1", "--seed", "0", "--no-pin"]).pin is False
