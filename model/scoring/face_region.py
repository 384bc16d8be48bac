"""The face region of an evaluation pair (issue 37): the farm's head mask (the scene's `head`
channel: the head's skin and the face's details), cropped and resized as the pair's other maps
are, times the pair's metric weight; and the rows of model.evaluate measured over it.

Every row is the same function as the whole person's with the face as its metric weight, so a
face column means what the person's column means: relit PSNR, SI PSNR, the identity baselines,
the PRT oracle, the breakdown's ceilings (true input light, true normals), and the normals'
median angle over the face. A pair whose face covers fewer than MIN_FACE_PIXELS metric pixels
(a full-body scene at 128 px: the face is about 10 px wide) is left out of the face columns,
and the count of pairs that had one is reported beside them.
"""

from __future__ import annotations

from collections import defaultdict
from pathlib import Path

import numpy as np

from model.samples.data_crops import DEFAULT_PADDING, crop_box, crop_resize

HEAD_THRESHOLD = 0.5  # a pixel is the face's when at least half of its person is head
MIN_FACE_PIXELS = 16


def face_weight(metric_weight: np.ndarray, head: np.ndarray) -> np.ndarray:
    """The face's metric weight: the pair's weight where the head mask is above HEAD_THRESHOLD."""
    return (np.asarray(metric_weight, np.float32) * (np.asarray(head) > HEAD_THRESHOLD)).astype(np.float32)


def cropped_head(json_path, size: int, padding: int = DEFAULT_PADDING) -> np.ndarray | None:
    """[1, S, S] head mask cropped and resized as model.samples.data_crops.load_cropped does the scene's
    maps (the same box from the same alpha), or None for a scene made before the farm wrote one."""
    from relight.files.dataset import read_scene

    scene = read_scene(Path(json_path), verify_hash=False)
    if scene.head is None:
        return None
    box = crop_box(scene.alpha[..., 0], padding)
    return np.clip(crop_resize(scene.head, box, size), 0.0, 1.0)


def normal_angles_deg(predicted: np.ndarray, truth: np.ndarray, mask: np.ndarray) -> np.ndarray:
    """Angles in degrees between unit normals [H, W, 3] at the mask's pixels (mask > 0.5)."""
    cos = np.clip((np.asarray(predicted, np.float64) * np.asarray(truth, np.float64)).sum(-1), -1.0, 1.0)
    return np.degrees(np.arccos(cos))[np.asarray(mask) > 0.5]


class FaceRows:
    """Per-pair face metrics of model.evaluate's rows, and their means over the pairs with a face."""

    def __init__(self, size: int, padding: int = DEFAULT_PADDING):
        self.size, self.padding = size, padding
        self._heads: dict[str, np.ndarray | None] = {}
        self.rows: dict[str, list[dict]] = defaultdict(list)
        self.normal_median: list[float] = []
        self.pairs = 0
        self.with_face = 0
        self.face_pixels: list[int] = []

    def head(self, json_path) -> np.ndarray | None:
        key = str(json_path)
        if key not in self._heads:
            self._heads[key] = cropped_head(json_path, self.size, self.padding)
        return self._heads[key]

    def face_sample(self, sample: dict, json_path) -> dict | None:
        """The sample with the face as its metric weight, or None (no head mask, face too small)."""
        self.pairs += 1
        head = self.head(json_path)
        if head is None:
            return None
        weight = face_weight(sample["metric_weight"], head)
        pixels = int((weight > 0.5).sum())
        if pixels < MIN_FACE_PIXELS:
            return None
        self.with_face += 1
        self.face_pixels.append(pixels)
        return dict(sample, metric_weight=weight)

    def add(self, name: str, row: dict) -> None:
        """One pair's metrics of the row `name` ({"relighting/image": {...}, ...}) over the face."""
        if "relighting/image" in row:
            self.rows[name].append(row["relighting/image"])

    def add_normals(self, predicted_hwc: np.ndarray, truth_hwc: np.ndarray, weight_chw: np.ndarray) -> None:
        angles = normal_angles_deg(predicted_hwc, truth_hwc, weight_chw[0])
        if angles.size:
            self.normal_median.append(float(np.median(angles)))

    def summary(self) -> dict:
        return {"pairs": self.pairs, "pairs_with_face": self.with_face,
                "face_pixels_median": float(np.median(self.face_pixels)) if self.face_pixels else 0.0,
                "normal_median_deg": float(np.mean(self.normal_median)) if self.normal_median else float("nan"),
                "methods": {name: {"psnr": float(np.mean([r["psnr"] for r in rs])),
                                   "si_psnr": float(np.mean([r["si_psnr"] for r in rs]))}
                            for name, rs in self.rows.items() if rs}}

    def markdown(self) -> str:
        s = self.summary()
        if not s["pairs_with_face"]:
            return (f"\n## Face region\n\nNo pair has a face of {MIN_FACE_PIXELS} metric pixels or more "
                    "(or the scenes have no head mask).\n")
        lines = ["", "## Face region", "",
                 f"{s['pairs_with_face']} of {s['pairs']} pairs have a face of at least {MIN_FACE_PIXELS} metric "
                 f"pixels (median {s['face_pixels_median']:.0f}): the farm's head mask (> {HEAD_THRESHOLD}) times "
                 "the metric weight (model/scoring/face_region.py). Normals' median angle over the face, mean over those "
                 f"pairs: {s['normal_median_deg']:.1f} degrees.", "",
                 "| method (relighting, image, face) | face PSNR | face SI PSNR |", "|---|---|---|"]
        for name, m in s["methods"].items():
            lines.append(f"| {name} | {m['psnr']:.2f} | {m['si_psnr']:.2f} |")
        return "\n".join(lines) + "\n"

