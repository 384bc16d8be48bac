"""Writing `relight image`'s output at photo size (issue 40): the PNG and EXR writers, and the
command end to end, each against what it was, as ratios within one run.

    .venv/bin/python benchmarks/bench_write.py                      # writers, then relight image
    .venv/bin/python benchmarks/bench_write.py --tree before=OLD_CHECKOUT   # end to end against a tree

The photo is the bundled public-domain evaluation/data/matte_eval/obama_standing.jpg enlarged
(Lanczos) to 3842 x 6247 (24 MP, as docs/TRADEOFFS.md's "24 MP photo"), saved as a JPEG in a
temporary folder. Writers run on that photo's linear pixels times a smooth gain (what a relit
photo looks like to a writer: float32 values, not the 256 levels a JPEG decodes to); each row
is the median of --repeats runs (wall and the process's CPU time), its ratios to the first row
of its table, and the file's size. End to end: `relight image BIG.jpg --light sunset --out O.png` (and
`--out O.exr`) in a fresh process per run, the trees alternated, wall time, CPU time
(user + system: what it cost whatever ran beside it) and peak RSS (wait4's ru_maxrss).
The machine is shared: compare ratios within one run, and CPU time.
"""

from __future__ import annotations

import argparse
import io
import os
import statistics
import subprocess
import sys
import tempfile
import time
import zlib
from pathlib import Path

import numpy as np
from photos import enlarged_photo  # benchmarks/photos.py
from timing import median_wall_cpu  # benchmarks/timing.py

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
PHOTO = REPO / "evaluation" / "data" / "matte_eval" / "obama_standing.jpg"
SIZE = (3842, 6247)  # width, height: 24 MP


def make_photo(folder: Path) -> Path:
    path = folder / "BIG.jpg"
    enlarged_photo(path, size=SIZE, source=PHOTO)
    return path


def table(title: str, rows: list[tuple[str, tuple[float, float], float | None]]) -> None:
    print(f"\n{title}\n")
    print("| writer | wall s (median) | vs first row | CPU s (median) | vs first row | MB |")
    print("|---|---|---|---|---|---|")
    wall0, cpu0 = rows[0][1]
    for name, (wall, cpu), mb in rows:
        print(f"| {name} | {wall:.3f} | {wall / wall0:.2f}x | {cpu:.3f} | {cpu / cpu0:.2f}x | "
              f"{'' if mb is None else f'{mb:.1f}'} |")


def png_before(linear: np.ndarray, f) -> None:
    """The writer before issue 40: the sRGB curve per strip of 256 rows, Pillow at level 4."""
    from PIL import Image

    from relight.imaging.colour import srgb_encode

    h, w = linear.shape[:2]
    u8 = np.empty((h, w, 3), np.uint8)
    for r0 in range(0, h, 256):
        u8[r0:r0 + 256] = np.rint(srgb_encode(linear[r0:r0 + 256]) * 255.0)
    Image.fromarray(u8, "RGB").save(f, format="PNG", compress_level=4)


def bench_png(linear: np.ndarray, repeats: int) -> None:
    from PIL import Image

    from relight.files import png_encoder
    from relight.imaging.colour import srgb_encode

    cores = min(4, len(os.sched_getaffinity(0)))
    rows = []

    def run(name, write):
        buf = io.BytesIO()
        write(buf)
        rows.append((name, median_wall_cpu(lambda: write(io.BytesIO()), repeats), len(buf.getvalue()) / 1e6))

    run("before: sRGB curve + Pillow level 4", lambda f: png_before(linear, f))
    rows.append(("sRGB encode alone: the curve (rint(255 srgb_encode))",
                 median_wall_cpu(lambda: [np.rint(srgb_encode(linear[r:r + 256]) * 255.0)
                                      for r in range(0, linear.shape[0], 256)], repeats), None))
    codes = png_encoder.encode_srgb8(linear)
    rows.append(("sRGB encode alone: the table (encode_srgb8)",
                 median_wall_cpu(lambda: png_encoder.encode_srgb8(linear), repeats), None))
    for level in (1, 4):
        run(f"table + Pillow level {level}",
            lambda f, level=level: Image.fromarray(png_encoder.encode_srgb8(linear), "RGB").save(
                f, format="PNG", compress_level=level))
    del codes
    original = png_encoder.deflate_module
    engines = [("zlib level 1, run-length", lambda: (zlib, 1, zlib.Z_RLE)),
               ("zlib level 1", lambda: (zlib, 1, zlib.Z_DEFAULT_STRATEGY))]
    try:
        from isal import isal_zlib

        engines += [(f"ISA-L level {lv}", lambda lv=lv: (isal_zlib, lv, isal_zlib.Z_DEFAULT_STRATEGY)) for lv in (0, 1, 2)]
    except ImportError:
        print("(isal not installed: no ISA-L rows; pip install isal)")
    try:
        from zlib_ng import zlib_ng

        engines += [("zlib-ng level 1", lambda: (zlib_ng, 1, zlib_ng.Z_DEFAULT_STRATEGY))]
    except ImportError:
        pass
    try:
        for name, engine in engines:
            png_encoder.deflate_module = engine
            for threads in sorted({1, cores}):
                run(f"table + Up filter + {name}, {threads} thread{'s' if threads > 1 else ''}",
                    lambda f, t=threads: png_encoder.write_png_file(f, linear, {"relight": "{}"}, threads=t))
    finally:
        png_encoder.deflate_module = original
    module = original()[0].__name__
    run(f"after: relight.files.photo.write_png as shipped ({module}, {cores} threads)",
        lambda f: png_encoder.write_png_file(f, linear, {"relight": "{}"}))
    table(f"PNG, {linear.shape[1]} x {linear.shape[0]}, 8-bit sRGB ({cores} cores available)", rows)


def bench_exr(linear: np.ndarray, repeats: int, folder: Path) -> None:
    """OpenEXR's own writer (what relight.files.exr used before issue 48) against
    relight.files.exr_zip (ISA-L), and relight.files.photo.write_exr_image as shipped."""
    import OpenEXR

    from relight.files import exr_zip
    from relight.files.exr import write_exr
    from relight.files.photo import write_exr_image

    channels = {c: np.ascontiguousarray(linear[..., i]) for i, c in enumerate("RGB")}
    before = OpenEXR.global_thread_count()
    cores = min(4, len(os.sched_getaffinity(0)))
    rows = []

    def run(name, write, path):
        seconds = median_wall_cpu(write, repeats)
        rows.append((name, seconds, path.stat().st_size / 1e6))
        path.unlink()

    available = exr_zip.available
    exr_zip.available = lambda: False  # write_exr on the library's writer
    try:
        for threads in sorted({0, cores}):
            OpenEXR.set_global_thread_count(threads)
            for compression in ("zip", "none"):  # (piz, zips and rle lost to zip: time or size)
                path = folder / f"o_{compression}.exr"
                run(f"OpenEXR's writer, float32 {compression}, its threads {threads}",
                    lambda: write_exr(path, channels, compression=compression), path)
    finally:
        exr_zip.available = available
        OpenEXR.set_global_thread_count(before)
    h, w = linear.shape[:2]
    for threads in sorted({1, cores}):
        path = folder / "o_isal.exr"

        def ours(threads=threads, path=path):
            with open(path, "wb") as f:
                exr_zip.write_zip_exr(f, ["R", "G", "B"], h, w, (linear[y:y + 64] for y in range(0, h, 64)),
                                      threads=threads)

        run(f"exr_zip, float32 zip, ISA-L level {exr_zip.LEVEL}, {threads} thread{'s' if threads > 1 else ''}",
            ours, path)
    path = folder / "o.exr"
    run("relight.files.photo.write_exr_image as shipped", lambda: write_exr_image(path, linear), path)
    table(f"EXR, {w} x {h}, RGB float32 (lossless), OpenEXR {OpenEXR.__version__}", rows)


def run_command(python: str, tree: Path, photo: Path, out: Path) -> tuple[float, float, float]:
    """(wall s, CPU s, peak RSS MB) of one `relight image` in a fresh process of `tree`."""
    env = dict(os.environ, PYTHONPATH=str(tree))
    t0 = time.perf_counter()
    proc = subprocess.Popen([python, "-m", "relight.cli", "image", str(photo), "--light", "sunset", "--out", str(out)],
                            cwd=tree, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(proc.pid, 0)
    wall = time.perf_counter() - t0
    err = proc.stderr.read().decode(errors="replace")
    proc.stderr.close()
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode != 0:
        raise SystemExit(f"relight image failed in {tree}: {err.strip()}")
    return wall, usage.ru_utime + usage.ru_stime, usage.ru_maxrss / 1024


def bench_command(trees: list[tuple[str, Path]], photo: Path, runs: int, folder: Path) -> None:
    print(f"\n`relight image` on the 24 MP JPEG, --light sunset, Balanced, {runs} runs a tree, alternated\n")
    print("| tree | output | wall s (median) | vs first row | CPU s (median) | peak RSS MB (max) |")
    print("|---|---|---|---|---|---|")
    results = {}
    for i in range(runs):
        for name, tree in trees:
            for suffix in (".png", ".exr"):
                python = str(tree / ".venv" / "bin" / "python") if (tree / ".venv").exists() else sys.executable
                results.setdefault((name, suffix), []).append(run_command(python, tree, photo, folder / f"o{suffix}"))
    base = None
    for (name, suffix), got in results.items():
        wall = statistics.median(g[0] for g in got)
        base = base or wall
        print(f"| {name} | {suffix} | {wall:.2f} | {wall / base:.2f}x | {statistics.median(g[1] for g in got):.2f} | "
              f"{max(g[2] for g in got):.0f} |")


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--repeats", type=int, default=3, help="runs of each writer (median)")
    p.add_argument("--runs", type=int, default=3, help="end-to-end runs of each tree")
    p.add_argument("--tree", action="append", default=[], metavar="NAME=DIR",
                   help="another checkout to run end to end beside this one (its .venv if it has one)")
    p.add_argument("--skip", action="append", default=[], choices=("png", "exr", "command"))
    args = p.parse_args()
    trees = [("this tree", REPO)] + [(t.split("=", 1)[0], Path(t.split("=", 1)[1]).resolve()) for t in args.tree]
    with open("/proc/loadavg") as f:
        print(f"load average before: {f.read().split()[0]}; {time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        photo = make_photo(folder)
        if "png" not in args.skip or "exr" not in args.skip:
            from relight.files.photo import read_photo

            linear = read_photo(photo)[0]
            # a smooth gain, as relighting gives: float32 values off the 256 levels a JPEG decodes to
            # (on those levels alone PIZ looked 2x cheaper than ZIP; on relit values it is not)
            linear *= (0.7 + 0.6 * np.linspace(0, 1, linear.shape[1], dtype=np.float32))[None, :, None]
            if "png" not in args.skip:
                bench_png(linear, args.repeats)
            if "exr" not in args.skip:
                bench_exr(linear, args.repeats, folder)
            del linear
        if "command" not in args.skip:
            bench_command(trees, photo, args.runs, folder)
    with open("/proc/loadavg") as f:
        print(f"\nload average after: {f.read().split()[0]}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
