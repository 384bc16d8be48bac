"""Person mattes against reference mattes on real photos: `python -m evaluation.matte_eval`.

    python -m evaluation.matte_eval [--photos DIR] [--matte person|raw|selfie|pose|network|decompose]
                                    [--threads N] [--repeat N] [--json OUT.json]

For every photo of DIR (default: the bundled set evaluation/data/matte_eval,
references in DIR/reference/NAME.png, white = person) prints the IoU of
alpha > 0.5 with the reference, the boundary F-score, the spill (the matte's
soft mass outside the reference, per reference pixel: ghosts that the 0.5
threshold hides) and the time the matte took (median of --repeat runs after one warm-up):
wall time and the process's CPU time (all threads; steadier than wall time on a
loaded machine, and on an idle one with as many cores as threads the wall time
is at most this). `--matte person` is
relight.person.matte.person_matte as shipped (the selfie and pose segmentations
combined, guided edge), `raw` the same without the guided edge, `selfie` and
`pose` one network each (with the guided edge), `network` the relighting
network's alpha head (Relighter.decompose(matte="network"), the matte
`relight image --matte network` uses), `decompose` what the library's default
`Relighter().decompose(photo)` mattes with (the person matte).

Boundary F-score: the boundary of a mask is its pixels with a 4-neighbour
outside it; precision is the share of predicted boundary pixels within
BOUNDARY_TOLERANCE x the image diagonal (chessboard distance) of a
reference boundary pixel, recall the converse, F their harmonic mean (the
tolerance of the DAVIS benchmark).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from relight.person.mask_ops import dilate

EVAL_DIR = Path(__file__).resolve().parent / "data" / "matte_eval"
REFERENCE_SUBDIR = "reference"
BOUNDARY_TOLERANCE = 0.008   # of the image diagonal
THRESHOLD = 0.5
MATTES = ("person", "raw", "selfie", "pose", "network", "decompose")


def iou(alpha: np.ndarray, reference: np.ndarray) -> float:
    """Intersection over union of alpha > 0.5 and the reference (bool)."""
    pred = alpha > THRESHOLD
    union = np.count_nonzero(pred | reference)
    return float(np.count_nonzero(pred & reference) / union) if union else 1.0


def spill(alpha: np.ndarray, reference: np.ndarray) -> float:
    """Sum of alpha outside the reference over the reference's area (0: nothing outside)."""
    return float(alpha[~reference].sum(dtype=np.float64) / max(1, np.count_nonzero(reference)))


def _boundary(mask: np.ndarray) -> np.ndarray:
    inner = mask.copy()
    inner[1:] &= mask[:-1]
    inner[:-1] &= mask[1:]
    inner[:, 1:] &= mask[:, :-1]
    inner[:, :-1] &= mask[:, 1:]
    return mask & ~inner


def boundary_f(alpha: np.ndarray, reference: np.ndarray, tolerance: float = BOUNDARY_TOLERANCE) -> float:
    """Boundary F-score of alpha > 0.5 against the reference (bool), tolerance x diagonal."""
    radius = max(1, round(tolerance * float(np.hypot(*reference.shape))))
    pred_b, ref_b = _boundary(alpha > THRESHOLD), _boundary(reference)
    if not pred_b.any() or not ref_b.any():
        return float(pred_b.any() == ref_b.any())
    # within `radius` (chessboard distance) of the other boundary: a dilation by a square
    precision = np.count_nonzero(pred_b & dilate(ref_b, radius)) / np.count_nonzero(pred_b)
    recall = np.count_nonzero(ref_b & dilate(pred_b, radius)) / np.count_nonzero(ref_b)
    return float(2 * precision * recall / (precision + recall)) if precision + recall else 0.0


def eval_photos(folder: Path = EVAL_DIR) -> list[tuple[str, Path, Path]]:
    """(name, photo, reference) for every photo of `folder` with a reference matte."""
    from relight.files.photo import PHOTO_SUFFIXES

    folder = Path(folder)
    if not folder.is_dir():
        raise ValueError(f"photo folder not found: {folder}")
    found = []
    for p in sorted(folder.iterdir()):
        ref = folder / REFERENCE_SUBDIR / (p.stem + ".png")
        if p.is_file() and p.suffix.lower() in PHOTO_SUFFIXES and ref.is_file():
            found.append((p.stem, p, ref))
    if not found:
        raise ValueError(f"no photos with a reference matte ({REFERENCE_SUBDIR}/NAME.png) in {folder}")
    return found


def read_reference(path: Path, shape) -> np.ndarray:
    from PIL import Image

    with Image.open(path) as im:
        ref = np.asarray(im.convert("L")) > 127
    if ref.shape != tuple(shape):
        raise ValueError(f"{path}: reference is {ref.shape}, the photo {tuple(shape)}")
    return ref


def _matte_function(kind: str, threads: int | None):
    if kind == "network":
        from relight.network import quality
        from relight.network.runtime import Relighter

        relighter = Relighter(quality.model_path(quality.DEFAULT), threads=threads)
        return lambda photo: relighter.decompose(photo, matte="network").full_alpha()
    if kind == "decompose":  # the library's default, as a Python user calls it
        from relight.network.runtime import Relighter

        default = Relighter(threads=threads)
        return lambda photo: default.decompose(photo).full_alpha()
    from relight.person.matte import person_matte

    method = {"person": "ensemble", "raw": "ensemble"}.get(kind, kind)
    return lambda photo: person_matte(photo, threads=threads, method=method, refine=kind != "raw").alpha


def evaluate(kind: str = "person", folder: Path = EVAL_DIR, threads: int | None = None,
             repeat: int = 3) -> list[dict]:
    """One row per photo: name, size, iou, boundary_f, ms (median of `repeat` after a warm-up)."""
    from relight.files.photo import read_photo

    if kind not in MATTES:
        raise ValueError(f"--matte must be one of {MATTES}, got {kind!r}")
    run = _matte_function(kind, threads)
    rows = []
    for name, photo_path, ref_path in eval_photos(folder):
        photo, _ = read_photo(photo_path)
        reference = read_reference(ref_path, photo.shape[:2])
        alpha = run(photo)  # warm-up (and the result)
        times, cpu = [], []
        for _ in range(repeat):
            t0, c0 = time.perf_counter(), time.process_time()
            run(photo)
            times.append(time.perf_counter() - t0)
            cpu.append(time.process_time() - c0)
        rows.append({"name": name, "size": list(photo.shape[:2]), "iou": iou(alpha, reference),
                     "boundary_f": boundary_f(alpha, reference), "spill": spill(alpha, reference),
                     "ms": 1e3 * float(np.median(times)) if times else None,
                     "cpu_ms": 1e3 * float(np.median(cpu)) if cpu else None})
    return rows


def format_table(rows: list[dict], kind: str) -> str:
    lines = [f"matte: {kind}", "| photo | size | IoU | boundary F | spill | ms | CPU ms |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        ms = "- | -" if r["ms"] is None else f"{r['ms']:.0f} | {r['cpu_ms']:.0f}"
        lines.append(f"| {r['name']} | {r['size'][1]}x{r['size'][0]} | {r['iou']:.3f} | {r['boundary_f']:.3f} | "
                     f"{r['spill']:.3f} | {ms} |")
    ious = [r["iou"] for r in rows]
    bfs = [r["boundary_f"] for r in rows]
    times = [r["ms"] for r in rows if r["ms"] is not None]
    cpus = [r["cpu_ms"] for r in rows if r["cpu_ms"] is not None]
    lines.append(f"| mean ({len(rows)} photos) | | {np.mean(ious):.3f} (min {min(ious):.3f}) | {np.mean(bfs):.3f} | "
                 f"{np.mean([r['spill'] for r in rows]):.3f} | "
                 + (f"{np.mean(times):.0f} | {np.mean(cpus):.0f} |" if times else "- | - |"))
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m evaluation.matte_eval", description=__doc__.split("\n\n")[0])
    p.add_argument("--photos", type=Path, default=EVAL_DIR, help="folder of photos with reference/NAME.png")
    p.add_argument("--matte", choices=MATTES, default="person")
    p.add_argument("--threads", type=int, default=None, help="onnxruntime threads (default: all cores)")
    p.add_argument("--repeat", type=int, default=3, help="timed runs per photo after a warm-up (0: none)")
    p.add_argument("--json", type=Path, default=None, help="also write the rows as JSON")
    args = p.parse_args(argv)
    try:
        rows = evaluate(args.matte, args.photos, args.threads, max(0, args.repeat))
        print(format_table(rows, args.matte))
        if args.json is not None:
            from relight.files.fileio import atomic_write_json

            atomic_write_json(args.json, {"matte": args.matte, "rows": rows}, indent=2)
    except (ValueError, OSError) as exc:
        print(f"evaluation.matte_eval: error: {exc}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
