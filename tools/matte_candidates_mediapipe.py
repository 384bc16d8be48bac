"""The MediaPipe candidates of docs/MATTE.md, run by MediaPipe itself on the bundled evaluation photos.

Not run by CI: needs the scratch environment of tools/convert_mediapipe_matte.py
with mediapipe 0.10.21 (numpy<2, protobuf<5):

    /tmp/mattevenv/bin/python tools/matte_candidates_mediapipe.py

Scores each candidate's mask with evaluation.matte_eval's own metrics (IoU of
mask > 0.5, boundary F-score) and times MediaPipe's `process` call (median of
3 after a warm-up; MediaPipe picks its own thread count):
selfie segmentation general (256x256) and landscape (144x256), and the pose
landmarker (model_complexity=1, the only pose model inside the wheel) with
enable_segmentation (a detector finds the person, the landmark model crops
to them, its segmentation is pasted back into the frame).
"""

import sys
import time
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from evaluation.matte_eval import boundary_f, eval_photos, iou, read_reference, spill


def main() -> int:
    import mediapipe as mp

    candidates = {
        "mediapipe selfie general": mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=0),
        "mediapipe selfie landscape": mp.solutions.selfie_segmentation.SelfieSegmentation(model_selection=1),
        "mediapipe pose (full) segmentation": mp.solutions.pose.Pose(static_image_mode=True, model_complexity=1,
                                                                     enable_segmentation=True),
    }
    for label, model in candidates.items():
        print(f"matte: {label}")
        print("| photo | IoU | boundary F | spill | ms |\n|---|---|---|---|---|")
        ious, bfs, spills, mss = [], [], [], []
        for name, photo_path, ref_path in eval_photos():
            rgb = np.ascontiguousarray(np.asarray(Image.open(photo_path).convert("RGB")))
            ref = read_reference(ref_path, rgb.shape[:2])
            result = model.process(rgb)
            times = []
            for _ in range(3):
                t0 = time.perf_counter()
                model.process(rgb)
                times.append(time.perf_counter() - t0)
            mask = result.segmentation_mask
            alpha = np.zeros(rgb.shape[:2], np.float32) if mask is None else mask.astype(np.float32)
            ious.append(iou(alpha, ref))
            bfs.append(boundary_f(alpha, ref))
            spills.append(spill(alpha, ref))
            mss.append(1e3 * float(np.median(times)))
            print(f"| {name} | {ious[-1]:.3f} | {bfs[-1]:.3f} | {spills[-1]:.3f} | {mss[-1]:.0f} |")
        print(f"| mean | {np.mean(ious):.3f} (min {min(ious):.3f}) | {np.mean(bfs):.3f} | {np.mean(spills):.3f} | "
              f"{np.mean(mss):.0f} |\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
