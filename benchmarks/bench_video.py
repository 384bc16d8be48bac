"""Speed and memory of `relight video` end to end (decode -> relight -> encode).

    python benchmarks/bench_video.py [--quality balanced] [--frames 240] [--long 2000] [--hd-seconds 10]

Three measurements, each a `relight video` run in a fresh process (model loading included):

* 640 x 360: frames/s over a generated clip of --frames frames (a person walking across a
  textured background: the bundled photo of Grace Hopper), H.264 in and out;
* 1920 x 1080: the seconds a --hd-seconds clip at 24 fps takes, against its duration;
* memory: the process's resident set sampled every 0.2 s over a --long-frame clip of
  small frames (160 x 90): flat means no growth per frame (the slope per 1,000 frames).

Prints a Markdown table with the load average before and after (the machine may be shared) and
each run's CPU time (user + system): what the job itself cost, whatever else ran beside it.
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(REPO / "tests"))


def _load() -> str:
    return " / ".join(f"{x:.2f}" for x in os.getloadavg())


def _clip(path: Path, frames: int, w: int, h: int) -> Path:
    from fractions import Fraction

    from clip_support import person_clip
    from relight.files.video_io import ClipInfo
    from relight.files.video_out import VideoWriter

    writer = VideoWriter(path, ClipInfo(path, "frames", w, h, Fraction(24), frames))
    # a walk of a few seconds, repeated: generating every frame anew would dominate the set-up
    cycle = person_clip(48, h=h, w=w, step=max(1, w // 160), start=w // 8)
    for i in range(frames):
        writer.write(cycle[i % len(cycle)] if (i // len(cycle)) % 2 == 0 else cycle[-1 - i % len(cycle)])
    return writer.close()


def _rss_kib(pid: int) -> int | None:
    try:
        with open(f"/proc/{pid}/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith("VmRSS:"))
    except (OSError, StopIteration):
        return None


def _run(source: Path, out: Path, quality: str, sample_rss: bool = False):
    """(wall seconds, [(seconds, RSS KiB)], CPU seconds) of one `relight video` process."""
    import resource

    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    cmd = [sys.executable, "-m", "relight.cli", "video", str(source), "--light", "studio", "--quality", quality,
           "--out", str(out)]
    env = {**os.environ, "TQDM_DISABLE": "1"}
    t0 = time.perf_counter()
    proc = subprocess.Popen(cmd, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    samples = []
    while proc.poll() is None:
        if sample_rss:
            rss = _rss_kib(proc.pid)
            if rss is not None:
                samples.append((time.perf_counter() - t0, rss))
        time.sleep(0.2)
    wall = time.perf_counter() - t0
    _, err = proc.communicate()
    if proc.returncode != 0:
        raise SystemExit(f"relight video failed ({proc.returncode}): {err.decode()[-500:]}")
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, samples, cpu


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--quality", default="balanced")
    p.add_argument("--frames", type=int, default=240, help="frames of the 640x360 clip")
    p.add_argument("--hd-seconds", type=float, default=10.0)
    p.add_argument("--long", type=int, default=2000, help="frames of the memory run")
    p.add_argument("--runs", default="sd,hd,memory", help="which measurements (comma list of sd, hd, memory)")
    args = p.parse_args(argv)
    runs = set(args.runs.split(","))
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        print(f"load average before: {_load()}", file=sys.stderr)
        if "sd" in runs:
            src = _clip(tmp / "sd.mp4", args.frames, 640, 360)
            wall, _, cpu = _run(src, tmp / "sd_out.mp4", args.quality)
            rows.append(("640x360", args.frames, wall, f"{args.frames / wall:.1f} frames/s; CPU {cpu:.1f} s "
                                                        f"({1000 * cpu / args.frames:.0f} ms a frame)"))
            print(rows[-1], _load(), file=sys.stderr)
        if "hd" in runs:
            hd_frames = int(round(args.hd_seconds * 24))
            src = _clip(tmp / "hd.mp4", hd_frames, 1920, 1080)
            wall, _, cpu = _run(src, tmp / "hd_out.mp4", args.quality)
            rows.append(("1920x1080", hd_frames, wall, f"{wall / args.hd_seconds:.2f} x its duration "
                                                        f"({hd_frames / wall:.1f} frames/s); CPU {cpu:.1f} s "
                                                        f"({1000 * cpu / hd_frames:.0f} ms a frame)"))
            print(rows[-1], _load(), file=sys.stderr)
        if "memory" in runs:
            src = _clip(tmp / "long.mp4", args.long, 160, 90)
            wall, samples, _ = _run(src, tmp / "long_out.mp4", args.quality, sample_rss=True)
            t = np.array([s[0] for s in samples])
            rss = np.array([s[1] for s in samples]) / 1024.0
            # the median RSS of each quarter of the run: flat means no growth per frame
            quarters = [float(np.median(rss[(t >= q * wall / 4) & (t < (q + 1) * wall / 4)])) for q in range(4)]
            steady = t > 0.25 * wall  # past start-up (model loading, first frames)
            slope = np.polyfit(t[steady], rss[steady], 1)[0] * wall / args.long * 1000
            rows.append(("160x90", args.long, wall,
                         f"{args.long / wall:.1f} frames/s; median RSS by quarter "
                         f"{' / '.join(f'{q:.0f}' for q in quarters)} MiB (peak {rss.max():.0f}); "
                         f"slope after the first quarter {slope:+.1f} MiB per 1,000 frames"))
            print(rows[-1], _load(), file=sys.stderr)
    after = _load()
    print(f"quality {args.quality}, {os.cpu_count()} CPUs; load average (1/5/15 min) at the end: {after}\n")
    print("| clip | frames | wall s | result |")
    print("|---|---|---|---|")
    for name, n, wall, result in rows:
        print(f"| {name} | {n} | {wall:.1f} | {result} |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
