"""The Ray executor, on a local Ray cluster kept on loopback.

Ray binds to the machine's primary interface whatever it is told
(ray-project/ray#26293), so the test re-executes this file inside a network
namespace that has only loopback (`unshare -n`, needs root), starts
`ray.init(num_cpus=2, include_dashboard=False)` there, runs the jobs, shuts
Ray down and prints what it saw as JSON; the assertions run out here.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from relight.files.dataset import read_scene  # noqa: E402

REAL_ARGS = ["--scenes", "2", "--seed", "11", "--res", "32", "--lights", "1", "--samples", "4",
             "--no-denoise", "--order", "2", "--directions", "64", "--recycle", "1", "--no-progress"]
FAULT_ARGS = ["--scenes", "5", "--seed", "2", "--lights", "1", "--timeout", "4", "--retries", "2",
              "--recycle", "2", "--job-module", "tests.support.farm_fault_job", "--no-progress"]
FAULTS = {"1": "crash-once", "2": "hang-once", "3": "raise"}


def _inside_namespace(work: Path) -> dict:
    """Runs in the loopback-only namespace: both jobs on one local Ray cluster."""
    import ray

    from farm import cli
    from farm.execution.ray_executor import remove_dead_workers_tmp, run_on_ray

    # Ray's session files go to a short private folder (its socket paths must stay < 108 bytes).
    ray_tmp = tempfile.mkdtemp(prefix="ray_")
    ray.init(num_cpus=2, include_dashboard=False, _temp_dir=ray_tmp)
    report = {"ray_version": ray.__version__, "cpus": ray.cluster_resources().get("CPU")}
    try:
        for name, args in (("real", REAL_ARGS), ("faults", FAULT_ARGS)):
            config = cli.parse_args(["--out", str(work / name), "--ray", "auto", *args])
            try:
                summary = run_on_ray(config)
                report[name] = {"ok": summary.ok, **summary.__dict__}
            except cli.FarmError as exc:
                report[name] = {"error": str(exc)}
        report["still_connected"] = ray.is_initialized()  # a cluster we did not start stays up
    finally:
        ray.shutdown()
        shutil.rmtree(ray_tmp, ignore_errors=True)
    # Worker processes that Ray shut down (not only those killed mid-scene) leave their
    # temp folders to the next cleanup pass; give the processes a moment to be gone.
    deadline = time.monotonic() + 10
    while time.monotonic() < deadline and list(Path(tempfile.gettempdir()).glob("farm_ray_*")):
        remove_dead_workers_tmp()
        time.sleep(0.2)
    return report


def test_ray_executor_on_a_loopback_cluster(tmp_path):
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join(p for p in (str(REPO), env.get("PYTHONPATH")) if p)
    env["FARM_FAULT_DIR"] = str(tmp_path)
    env["FARM_FAULTS"] = json.dumps(FAULTS)
    env["RAY_AUTH_MODE"] = "disabled"  # no token written to ~/.ray for a throwaway cluster
    r = subprocess.run(
        ["unshare", "-n", "sh", "-c", 'ip link set lo up && exec "$0" "$@"',
         sys.executable, __file__, str(tmp_path)],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=200)
    assert r.returncode == 0, r.stderr[-3000:]
    report = json.loads(r.stdout.strip().splitlines()[-1])
    assert report["cpus"] == 2.0 and report["still_connected"] is True

    real = report["real"]
    assert real["ok"], real
    assert (real["done"], real["failed"]) == (2, 0)
    real_log = json.loads((tmp_path / "real" / "farm_runlog.json").read_text())["runs"][-1]
    # A crash inside bpy would be retried by Ray: the count must match the attempts.
    assert real["retried"] == sum(rec["attempts"] - 1 for rec in real_log["scenes"])
    assert all(rec["attempts"] >= 1 for rec in real_log["scenes"])
    for i in range(2):
        scene = read_scene(tmp_path / "real" / f"scene_{i:06d}.json")  # hash, channels
        assert scene.resolution == (32, 32) and scene.sh_order == 2 and len(scene.images) == 1

    faults = report["faults"]
    # Scene 1 SIGKILLs its worker once, scene 2 hangs past the 4 s timeout once (the task's
    # watchdog kills its process), scene 3 raises on all 1 + 2 attempts.
    assert (faults["done"], faults["failed"], faults["retried"]) == (4, 1, 4)
    starts = {}
    for line in (tmp_path / "events.log").read_text().splitlines():
        event, index, pid = line.split()
        if event == "start":
            starts.setdefault(int(index), []).append(int(pid))
    assert {i: len(p) for i, p in starts.items()} == {0: 1, 1: 2, 2: 2, 3: 3, 4: 1}
    assert starts[1][0] != starts[1][1] and starts[2][0] != starts[2][1]  # fresh worker after a kill
    calls = [pid for pids in starts.values() for pid in pids]
    assert max(calls.count(pid) for pid in calls) <= 2  # --recycle 2: max_calls=2 per process
    log = json.loads((tmp_path / "faults" / "farm_runlog.json").read_text())["runs"][-1]
    errors = {rec["index"]: rec["errors"] for rec in log["scenes"]}
    assert errors[2][0] == "timeout after 4 s"
    assert errors[3][:3] == ["RuntimeError: injected failure in scene 3"] * 3
    for i in (0, 1, 2, 4):
        read_scene(tmp_path / "faults" / f"scene_{i:06d}.json")
    assert not (tmp_path / "faults" / "scene_000003.json").exists()
    # Every task process had its own temp folder; those of the processes killed mid-scene
    # (scenes 1 and 2) are gone once the run is over, like every process Ray retired.
    tmpdirs = dict(ln.split() for ln in (tmp_path / "tmpdirs.log").read_text().splitlines())
    assert all(Path(d).name == f"farm_ray_{pid}" for pid, d in tmpdirs.items())
    assert not [d for d in tmpdirs.values() if Path(d).exists()]


def test_ray_missing_is_one_clear_error(tmp_path, monkeypatch, capsys):
    """Without the 'distributed' extra, --ray fails with one line and exit 1; Ray is
    imported only when --ray is given."""
    from farm import cli

    monkeypatch.setitem(sys.modules, "ray", None)  # import ray -> ImportError
    code = cli.main(["--out", str(tmp_path / "out"), "--scenes", "1", "--seed", "0", "--ray", "auto"])
    assert code == 1
    assert capsys.readouterr().err.splitlines() == [
        "farm: error: --ray needs Ray: pip install 'fullbody-relight[distributed]' (or pip install ray)"]
    assert not (tmp_path / "out").exists()
    probe = subprocess.run([sys.executable, "-c", "import sys, farm.cli, farm.execution.executors; "
                            "print('ray' in sys.modules)"], cwd=REPO, capture_output=True, text=True)
    assert probe.stdout.strip() == "False"


if __name__ == "__main__":
    print(json.dumps(_inside_namespace(Path(sys.argv[1])), default=str))
