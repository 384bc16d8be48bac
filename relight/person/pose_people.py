"""The people in a photo, as MediaPipe's pose networks see them: the pose detector (a box and body keypoints
per person, 224 x 224 letterbox) and the pose landmark model's segmentation of each one (a person's mask
in a rotated square around the body that the detection gives, 256 x 256).

The detector answers for about one person a picture (two portraits side by side: one; a row of five
leaves each a few of its pixels), so `pose_people` asks it again: over square windows of the picture
at two sizes, then of the whole picture with each person it found painted out, until it finds nobody
new. relight.person.matte combines these masks with its selfie segmentation into each person's matte.
numpy and the sessions only.
"""

from __future__ import annotations

import math

import numpy as np

from relight.person.mask_ops import dilate
from relight.imaging.resample import bilinear_rows, resize_linear, sample_points

__all__ = ["DETECT_SIDE", "POSE_SIDE", "SAME_PERSON", "candidates", "detect", "nchw", "pose_mask", "pose_people", "roi",
           "same_square"]

POSE_SIDE = 256                         # the landmark model's input side
DETECT_SIDE = 224
DETECT_STRIDES = (8, 16, 32, 32, 32)    # SSD anchor layers (2 anchors per layer and cell)
DETECT_SCORE = 0.5
DETECT_OVERLAP = 0.3                    # IoU above which detections merge (weighted)
ROI_SCALE = 1.25                        # body circle -> the landmark model's square
MAX_PEOPLE = 12                         # detections looked for, one at a time (each found person blanked)
REDETECT_SCORE = 0.8                    # a detection with people painted out: their leftovers (a hat's top) score 0.5-0.7
REDETECT_AGREED = 0.6                   # ... taken from this score where the selfie mask sees a person
WINDOWS_ASPECT = 1.3                    # an image this much wider (or taller) than square is also searched in windows
WINDOW_SCALES = (1.0, 0.6)              # the windows' sides, of the image's shorter side
SAME_PERSON = 0.5                       # a new detection's mask this much inside a found person's (grown) is that person
SAME_SQUARE_SHIFT = 0.05                # two landmark squares whose centres are this share of the smaller side apart,
SAME_SQUARE_SCALE = 1.15                # ... whose sides differ by less than this factor
SAME_SQUARE_TURN = math.radians(10.0)   # ... and whose turns by less than this give one mask (the windows' repeats)

def nchw(srgb: np.ndarray) -> np.ndarray:
    """An sRGB image [h, w, 3] as the networks' input [1, 3, h, w] float32."""
    return np.ascontiguousarray(srgb.transpose(2, 0, 1)[None], dtype=np.float32)


def _anchors() -> np.ndarray:
    """SSD anchor centres [2254, 2] (x, y in [0, 1]) of MediaPipe's pose detector: per layer
    stride, a feature map of ceil(224 / stride) cells, 2 anchors per layer sharing the stride."""
    centres = []
    i = 0
    while i < len(DETECT_STRIDES):
        j = i
        while j < len(DETECT_STRIDES) and DETECT_STRIDES[j] == DETECT_STRIDES[i]:
            j += 1
        cells = math.ceil(DETECT_SIDE / DETECT_STRIDES[i])
        c = (np.arange(cells, dtype=np.float32) + 0.5) / cells
        xy = np.stack(np.meshgrid(c, c), axis=-1).reshape(-1, 1, 2)
        centres.append(np.repeat(xy, 2 * (j - i), axis=1).reshape(-1, 2))
        i = j
    return np.concatenate(centres)


_ANCHORS = _anchors()


def detect(session, grid: np.ndarray, min_score: float = DETECT_SCORE, scores: list | None = None) -> list[np.ndarray]:
    """People found by the pose detector in an sRGB image: for each, its 4 keypoints
    [4, 2] in the image's pixels (0: hips' centre, 1: a point on the body's enclosing
    circle), after MediaPipe's weighted non-maximum suppression; each one's best score is
    appended to `scores` when given."""
    h, w = grid.shape[:2]
    scale = DETECT_SIDE / max(h, w)
    nh, nw = max(1, round(h * scale)), max(1, round(w * scale))
    oy, ox = (DETECT_SIDE - nh) // 2, (DETECT_SIDE - nw) // 2
    canvas = np.zeros((DETECT_SIDE, DETECT_SIDE, 3), np.float32)  # letterboxed, black borders
    canvas[oy:oy + nh, ox:ox + nw] = resize_linear(grid, nh, nw)
    raw, logits = session.run(["boxes", "scores"], {"image": nchw(canvas)})
    logits = np.clip(logits[0, :, 0], -100.0, 100.0)
    keep = np.flatnonzero(logits >= math.log(min_score / (1.0 - min_score)))
    if keep.size == 0:
        return []
    score = 1.0 / (1.0 + np.exp(-logits[keep]))
    r = raw[0, keep].astype(np.float64)
    anchor = _ANCHORS[keep]
    # canvas pixels -> grid pixels: offsets relative to the anchor centre, in canvas pixels
    to_x = lambda v: (v - ox) / scale
    to_y = lambda v: (v - oy) / scale
    cx, cy = r[:, 0] + anchor[:, 0] * DETECT_SIDE, r[:, 1] + anchor[:, 1] * DETECT_SIDE
    boxes = np.stack([to_x(cx - r[:, 2] / 2), to_y(cy - r[:, 3] / 2), to_x(cx + r[:, 2] / 2),
                      to_y(cy + r[:, 3] / 2)], axis=1)
    kx = r[:, 4:12:2] + anchor[:, :1] * DETECT_SIDE
    ky = r[:, 5:12:2] + anchor[:, 1:] * DETECT_SIDE
    keypoints = np.stack([to_x(kx), to_y(ky)], axis=-1)            # [n, 4, 2]
    people = []
    remaining = np.argsort(-score)
    while remaining.size:
        top = boxes[remaining[0]]
        b = boxes[remaining]
        inter = (np.clip(np.minimum(b[:, 2], top[2]) - np.maximum(b[:, 0], top[0]), 0, None)
                 * np.clip(np.minimum(b[:, 3], top[3]) - np.maximum(b[:, 1], top[1]), 0, None))
        area = (b[:, 2] - b[:, 0]) * (b[:, 3] - b[:, 1])
        overlap = inter / np.maximum(area + area[0] - inter, 1e-12)
        group = remaining[overlap > DETECT_OVERLAP]
        weights = score[group][:, None, None]
        people.append((keypoints[group] * weights).sum(axis=0) / weights.sum())
        if scores is not None:
            scores.append(float(score[remaining[0]]))
        remaining = remaining[overlap <= DETECT_OVERLAP]
    return people


def roi(keypoints: np.ndarray) -> tuple[float, float, float, float]:
    """(centre x, centre y, side, rotation) of the landmark model's square, in grid pixels:
    centred on the hips, side 2 x 1.25 x the body circle's radius, turned so the body is upright."""
    (x0, y0), (x1, y1) = keypoints[0], keypoints[1]
    side = 2.0 * ROI_SCALE * math.hypot(x1 - x0, y1 - y0)
    rotation = math.pi / 2 - math.atan2(-(y1 - y0), x1 - x0)
    rotation -= 2 * math.pi * math.floor((rotation + math.pi) / (2 * math.pi))
    return x0, y0, side, rotation


def pose_mask(session, image: np.ndarray, square: tuple[float, float, float, float], grid_shape, k: int) -> np.ndarray:
    """The pose landmark model's segmentation of one detected person (`square`: their landmark square,
    `roi`, in pixels of `image`, sRGB), resampled onto the grid [h, w] whose pixels are k x k pixels of `image`."""
    h, w = grid_shape
    cx, cy, side, rotation = square
    c, s = math.cos(rotation), math.sin(rotation)
    # the rotated square sampled into the network's 256 x 256 (pixel centres)
    t = ((np.arange(POSE_SIDE, dtype=np.float64) + 0.5) / POSE_SIDE - 0.5) * side
    u, v = np.meshgrid(t, t)
    crop = sample_points(image, c * u - s * v + cx, s * u + c * v + cy)
    mask = session.run(["mask"], {"image": nchw(crop)})[0][0, 0]
    # back to the grid, over the square's bounding box only
    half = side * (abs(c) + abs(s)) / 2
    x0, x1 = max(0, int((cx - half) / k)), min(w, int(math.ceil((cx + half) / k)) + 1)
    y0, y1 = max(0, int((cy - half) / k)), min(h, int(math.ceil((cy + half) / k)) + 1)
    out = np.zeros((h, w), np.float32)
    if x1 <= x0 or y1 <= y0 or side <= 0:
        return out
    yy, xx = (np.mgrid[y0:y1, x0:x1].astype(np.float64) + 0.5) * k  # grid pixel centres, in image pixels
    dx, dy = xx - cx, yy - cy
    mu = (c * dx + s * dy) / side + 0.5
    mv = (-s * dx + c * dy) / side + 0.5
    out[y0:y1, x0:x1] = sample_points(mask, mu * POSE_SIDE, mv * POSE_SIDE)
    return out


def pose_people(detector, pose_session, small: np.ndarray, grid_shape, k: int, floor: float, threshold: float,
                keep_radius: int, selfie: np.ndarray | None = None) -> list[np.ndarray]:
    """Each detected person's pose mask on the grid. MediaPipe's detector answers for about one person
    a picture (two portraits side by side: one), so the first look also searches windows (`candidates`)
    and the whole picture is asked again with each person found painted out (mid-grey), at a higher
    score (REDETECT_SCORE; from REDETECT_AGREED when the selfie mask sees a person there too), until it
    finds nobody new or MAX_PEOPLE. The later looks skip the windows: on 60 pasted groups
    (benchmarks/bench_groups.py) they found one person after the first look, a false one, and cost
    9 of a portrait's 20 detections. A detection whose landmark square repeats one already segmented
    (`same_square`: the windows find the same person 5-9 times) takes that mask. `small` is the photo
    (sRGB), the grid [h, w] = grid_shape has k x k of its pixels each; a mask is a person above
    `threshold`, grown by `keep_radius` where it is compared; `floor` is the fewest grid pixels a person has."""
    h, w = grid_shape
    image = small
    poses: list[np.ndarray] = []
    known: list[np.ndarray] = []  # each found person's mask, grown: made once, compared with every candidate
    segmented: list[tuple[tuple, np.ndarray]] = []  # (square, mask) of each detection segmented so far
    for _ in range(MAX_PEOPLE):
        fresh = []
        first = not poses
        for keypoints, score in candidates(detector, image, DETECT_SCORE if first else REDETECT_AGREED, windows=first):
            square = roi(keypoints)
            mask = next((m for sq, m in segmented if same_square(sq, square)), None)
            if mask is None:
                mask = pose_mask(pose_session, small, square, (h, w), k)
                segmented.append((square, mask))
            inside = mask > threshold
            if np.count_nonzero(inside) < floor:
                continue
            if not first and score < REDETECT_SCORE and (selfie is None or selfie[inside].mean() < threshold):
                continue  # a weak second look (people painted out) that the selfie model does not back
            if max((np.count_nonzero(inside & m) / np.count_nonzero(inside) for m in known), default=0.0) < SAME_PERSON:
                fresh.append(mask)  # mostly outside everyone found: someone new
                known.append(dilate(inside, keep_radius))
        if not fresh:
            break
        poses += fresh
        found = dilate(np.max(fresh, axis=0) > threshold, keep_radius)
        image = np.where(bilinear_rows(found.astype(np.float32), *small.shape[:2])[..., None] > 0.5,
                         np.float32(0.5), image).astype(np.float32)
    return poses


def same_square(a: tuple, b: tuple) -> bool:
    """Whether two landmark squares (`roi`: centre x, centre y, side, turn) frame the same person alike:
    the pose model's masks of the two, resampled onto the grid, then differ at the edges only."""
    side = min(a[2], b[2])
    turn = abs(a[3] - b[3]) % (2 * math.pi)
    return (math.hypot(a[0] - b[0], a[1] - b[1]) <= SAME_SQUARE_SHIFT * side
            and max(a[2], b[2]) < SAME_SQUARE_SCALE * side
            and min(turn, 2 * math.pi - turn) < SAME_SQUARE_TURN)


def candidates(detector, image: np.ndarray, min_score: float, windows: bool = True) -> list[tuple[np.ndarray, float]]:
    """(keypoints in the image's pixels, score) of the people the detector sees in the whole
    image (at min_score) and, when `windows`, in square windows half a side apart, WINDOW_SCALES of its
    shorter side (at REDETECT_AGREED at least): letterboxed whole, a row of five people leaves each a few
    detector pixels, and a small person beside a tall one is missed. The whole image's first, then by score."""
    scores: list[float] = []
    found = detect(detector, image, min_score, scores)
    whole = len(found)
    if not windows:
        return list(zip(found, scores))
    h, w = image.shape[:2]
    for scale in WINDOW_SCALES:
        side = round(scale * min(h, w))
        if scale == 1.0 and max(h, w) < WINDOWS_ASPECT * side:
            continue  # about square: the whole image is that window
        rows, cols = (np.unique(np.linspace(0, n - side, 2 * math.ceil(n / side) - 1).round().astype(int))
                      for n in (h, w))
        for y, x in ((y, x) for y in rows for x in cols):
            for keypoints in detect(detector, image[y:y + side, x:x + side], max(min_score, REDETECT_AGREED), scores):
                found.append(keypoints + np.array([x, y], np.float64))
    order = list(range(whole)) + sorted(range(whole, len(found)), key=lambda i: -scores[i])
    return [(found[i], scores[i]) for i in order]
