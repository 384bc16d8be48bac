"""Speed of the person matte on a 12-megapixel photo: `python benchmarks/bench_matte.py`.

    python benchmarks/bench_matte.py [--threads 2] [--repeats 9] [--size 4000x3000]

The bundled photo evaluation/data/matte_eval/obama_standing.jpg is enlarged to
4000 x 3000 (12 MP, portrait) and relight.person.matte.person_matte runs on it
(after one warm-up that also loads the model). Prints the median wall time,
the median CPU time of the process (all threads), and the wall time of each
stage, plus the median time of one copy of the photo in the same run: on a
loaded machine the ratio matte / copy says more than either figure alone.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np
from timing import median_wall_cpu  # benchmarks/timing.py

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))



def stage_times(photo: np.ndarray, threads: int, repeats: int) -> dict[str, float]:
    """Median wall time of each step of person_matte (the same private steps, in order)."""
    from relight.person import matte, pose_people
    from relight.imaging import resample
    from relight.imaging.colour import srgb_encode

    H, W = photo.shape[:2]
    out = {}
    small = resample.area_shrink(photo, matte.GUIDE_SIZE)
    out["shrink to 512-1023 px"] = median_wall_cpu(lambda: resample.area_shrink(photo, matte.GUIDE_SIZE), repeats)[0]
    small_srgb = srgb_encode(small).astype(np.float32)
    grid = resample.area_shrink(small_srgb, matte.NET_SIDE)
    out["sRGB + grid"] = median_wall_cpu(lambda: resample.area_shrink(srgb_encode(small).astype(np.float32),
                                                            matte.NET_SIDE), repeats)[0]
    selfie = matte._session("selfie", threads)
    out["selfie network"] = median_wall_cpu(lambda: matte._selfie(selfie, grid), repeats)[0]
    detector = matte._session("detector", threads)
    keypoints = pose_people.detect(detector, small_srgb)
    square = pose_people.roi(keypoints[0])
    out["pose detector + NMS"] = median_wall_cpu(lambda: pose_people.detect(detector, small_srgb), repeats)[0]
    pose = matte._session("pose", threads)
    k = max(1, max(small.shape[:2]) // matte.NET_SIDE)
    out["pose segmentation (1 person)"] = median_wall_cpu(
        lambda: pose_people.pose_mask(pose, small_srgb, square, grid.shape[:2], k), repeats)[0]
    people = matte._people(small_srgb, grid, "ensemble", threads, matte.REGISTRY_PATH)
    out["people (all networks + combination)"] = median_wall_cpu(
        lambda: matte._people(small_srgb, grid, "ensemble", threads, matte.REGISTRY_PATH), repeats)[0]
    edge = matte._edge(small, grid, people[0], True)
    out["guided edge"] = median_wall_cpu(lambda: matte._edge(small, grid, people[0], True), repeats)[0]
    out["full-resolution upsample"] = median_wall_cpu(lambda: resample.upsample_support(edge, H, W), repeats)[0]
    alpha = resample.upsample_support(edge, H, W)
    out["box"] = median_wall_cpu(lambda: matte._box(alpha), repeats)[0]
    return out


def main(argv=None) -> int:
    from relight.person import matte
    from relight.files.photo import read_photo
    from relight.imaging.resample import resize_linear

    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--repeats", type=int, default=9)
    p.add_argument("--size", default="4000x3000", help="HEIGHTxWIDTH of the enlarged photo")
    args = p.parse_args(argv)
    H, W = (int(v) for v in args.size.lower().split("x"))
    small, _ = read_photo(ROOT / "evaluation" / "data" / "matte_eval" / "obama_standing.jpg")
    photo = resize_linear(small, H, W)
    run = lambda: matte.person_matte(photo, threads=args.threads)
    run()
    copy_wall, _ = median_wall_cpu(lambda: photo.copy(), args.repeats)
    wall, cpu = median_wall_cpu(run, args.repeats)
    stages = stage_times(photo, args.threads, args.repeats)
    print(f"person_matte on {W}x{H} ({H * W / 1e6:.1f} MP), {args.threads} onnxruntime threads, "
          f"median of {args.repeats}:")
    print(f"  wall {wall * 1e3:.0f} ms, process CPU {cpu * 1e3:.0f} ms; one copy of the photo "
          f"{copy_wall * 1e3:.0f} ms (matte / copy = {wall / copy_wall:.1f})")
    for name, seconds in stages.items():
        print(f"  {name:<28s} {seconds * 1e3:6.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
