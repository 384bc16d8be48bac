"""Person matte of a real photo: which pixels are the person, softly, at full resolution.

    m = person_matte(photo)            # photo: linear float32 [H, W, 3]
    m.alpha                            # [H, W] float32 in [0, 1], soft edges, hair kept
    m.box                              # relight.imaging.box.Box (y0, y1, x0, x1): pixels where alpha > 0
    m.index, m.count                   # this person (1 = the largest) of how many found

Three MediaPipe networks (Apache-2.0, from the mediapipe 0.10.21 wheel),
converted to ONNX by tools/convert_mediapipe_matte.py and loaded through the
same hash-checked path as the relighting models (relight.models.session.open_session):

* selfie segmentation: a person probability for the whole frame, squeezed
  to 256 x 256;
* pose detection: people (a box and body keypoints each, 224 x 224 letterbox);
* pose landmarks (its segmentation output only): a person's mask in a
  rotated square around the body that the detection gives, 256 x 256.

The people are the detections; each one's matte is the geometric mean of the
two segmentations (the selfie mask limited to the pixels that are that
person's rather than another's), which keeps what both see: the selfie model takes
in what a person holds, the pose model loses edges and thin parts. Without a detection
the people are the connected parts of the selfie mask. Everything runs on a
grid of about 256 px; a guided filter then snaps the matte to the photo's
edges at up to 1023 px and it is brought to full resolution bilinearly.
docs/MATTE.md has the measurements that chose this design; docs/runtime.md
says how it runs. Nothing here imports torch or bpy.
"""

from __future__ import annotations

import threading
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from relight.imaging.box import Box
from relight.person.linear_photo import check_photo
from relight.person.mask_ops import box_mean, dilate, label
from relight.models import REGISTRY_PATH
from relight.person.pose_people import DETECT_SIDE, POSE_SIDE, SAME_PERSON, nchw, pose_people
from relight.imaging.resample import area_shrink, bilinear_rows, resize_linear, upsample_support

__all__ = ["PersonMatte", "NoPersonError", "person_matte", "matte_of_checked_photo", "mattes_of_checked_photo",
           "METHODS", "MODELS", "model_paths"]

# registry name -> default file (relight/models/), for each network of the matte
MODELS = {
    "selfie": ("person-matte-selfie", "person_matte_selfie.onnx"),
    "detector": ("person-matte-pose-detector", "person_matte_pose_detector.onnx"),
    "pose": ("person-matte-pose-segmentation", "person_matte_pose_segmentation.onnx"),
}
METHODS = ("ensemble", "selfie", "pose")  # ensemble: the shipped matte; the others for comparison
NET_SIDE = 256                          # the segmenters' input side, and the grid the matte is built on
GUIDE_SIZE = 512                        # the edge is refined at a longer side in [GUIDE_SIZE, 2 GUIDE_SIZE)
PERSON_THRESHOLD = 0.5                  # probability above which a pixel is a person
MIN_PERSON_FRACTION = 0.002             # people smaller than this share of the frame are noise
KEEP_RADIUS = 3                         # grid pixels of selfie mask kept around a person (the soft fringe)
GUIDE_RADIUS = 2                        # guided-filter window radius, in grid pixels
GUIDE_EPS = 1e-3                        # guided-filter regulariser (guide in [0, 1])
ALPHA_FLOOR = 1.0 / 255                 # below: exactly background; above 1 - this: exactly person
MIN_SIDE = 32                           # px: smaller photos cannot show a person to segment
MIN_FILL = 0.2                          # of its box a person's mask covers at least (a person fills 0.4-0.7 of theirs)
SELFIE_AGREEMENT = 0.25                 # mean selfie probability over a pose mask below which the
                                        # selfie model missed that person: the pose mask alone is used


class NoPersonError(ValueError):
    """The segmenters found nobody in the photo."""


class PersonIndexError(ValueError):
    """A person was asked for by index, but the photo shows fewer people (`count`)."""

    def __init__(self, index: int, count: int):
        super().__init__(f"person {index} asked for, but the photo shows {count} "
                         f"{'person' if count == 1 else 'people'} (1 = the largest)")
        self.index, self.count = index, count


@dataclass
class PersonMatte:
    alpha: np.ndarray                   # [H, W] float32 in [0, 1]; 0 = untouched background
    box: Box                            # (y0, y1, x0, x1) of alpha > 0, end exclusive
    index: int                          # which person: 1 = the largest
    count: int                          # people found


_NOBODY = "no person found in the photo: give a mask (--mask) or a photo where a person is clearly visible"


# ------------------------------------------------------------------ the networks


_SESSION_LOCK = threading.Lock()
_SESSIONS: dict = {}
_SIGNATURES = {"selfie": (["mask"], (NET_SIDE, NET_SIDE)), "detector": (["boxes", "scores"], (DETECT_SIDE,) * 2),
               "pose": (["mask"], (POSE_SIDE, POSE_SIDE))}


def model_paths(registry_path=REGISTRY_PATH) -> dict[str, Path]:
    """The files of the matte's networks: their registry entries, else the default names."""
    from relight.models import load_registry

    registry = load_registry(registry_path)["models"]
    out = {}
    for kind, (entry_name, default_file) in MODELS.items():
        entry = registry.get(entry_name)
        name = entry.get("file", default_file) if isinstance(entry, dict) else default_file
        out[kind] = Path(registry_path).parent / name
    return out


def _session(kind: str, threads: int | None = None, registry_path=REGISTRY_PATH):
    """One network's onnxruntime session, hash-checked once per process and then shared."""
    from relight.models.session import open_session

    path = model_paths(registry_path)[kind]
    key = (kind, str(path.resolve()), threads, str(Path(registry_path).resolve()))
    with _SESSION_LOCK:
        if key not in _SESSIONS:
            session, _ = open_session(path, threads=threads, registry_path=registry_path)
            outputs, side = _SIGNATURES[kind]
            shape = list(session.get_inputs()[0].shape)
            if [i.name for i in session.get_inputs()] != ["image"] or shape != [1, 3, *side] \
                    or [o.name for o in session.get_outputs()] != outputs:
                raise ValueError(f"{path}: not the {kind} network of the person matte "
                                 f"(expected image [1, 3, {side[0]}, {side[1]}] -> {', '.join(outputs)})")
            _SESSIONS[key] = session
        return _SESSIONS[key]


def _selfie(session, grid: np.ndarray) -> np.ndarray:
    """Selfie segmentation of the grid image (sRGB [h, w, 3]) -> probability on the grid."""
    x = resize_linear(grid, NET_SIDE, NET_SIDE)  # squeezed to the square, as MediaPipe feeds it
    p = session.run(["mask"], {"image": nchw(x)})[0][0, 0]
    return bilinear_rows(p, *grid.shape[:2])


# ------------------------------------------------------------------ the matte


def person_matte(photo, person: int | None = None, *, threads: int | None = None, registry_path=REGISTRY_PATH,
                 method: str = "ensemble", refine: bool = True) -> PersonMatte:
    """The matte of one person in `photo` (linear float32 [H, W, 3]).

    person: 1 = the largest person (default), 2 = the next, ...; NoPersonError
    (a ValueError) when the photo shows nobody, ValueError when `person` is
    out of range or the photo is not linear RGB at least MIN_SIDE px a side.
    method: "ensemble" (shipped), "selfie" or "pose" alone (for comparison);
    refine=False skips the guided edge (for comparison).
    """
    photo = check_photo(photo, MIN_SIDE, finite=False, purpose="a person matte")  # NaN/Inf: below, on the small
    return matte_of_checked_photo(photo, person, threads=threads, registry_path=registry_path, method=method,
                                  refine=refine)


def matte_of_checked_photo(photo: np.ndarray, person: int | None = None, *, threads: int | None = None,
                           registry_path=REGISTRY_PATH, method: str = "ensemble",
                           refine: bool = True) -> PersonMatte:
    """person_matte of a photo that relight.person.linear_photo.check_photo(photo, MIN_SIDE) returned
    (relight.network.runtime checks it once for the matte and the network)."""
    if person is not None and (isinstance(person, bool) or not isinstance(person, (int, np.integer))
                               or person < 1):
        raise ValueError(f"person must be 1 (the largest), 2, ... or None, got {person!r}")
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    small, grid, people = _found(photo, method, threads, registry_path)
    index = 1 if person is None else int(person)
    if index > len(people):
        raise PersonIndexError(index, len(people))
    return _full_matte(small, grid, people[index - 1], refine, photo.shape[:2], index, len(people))


def mattes_of_checked_photo(photo: np.ndarray, *, threads: int | None = None, registry_path=REGISTRY_PATH,
                            method: str = "ensemble", refine: bool = True) -> list[PersonMatte]:
    """Every person's matte (largest first), as matte_of_checked_photo gives each: the segmenters run
    once for all. Where two soft edges overlap the mattes are scaled to sum to at most 1, so the
    people composite over the photo together without light counted twice."""
    if method not in METHODS:
        raise ValueError(f"method must be one of {METHODS}, got {method!r}")
    small, grid, people = _found(photo, method, threads, registry_path)
    mattes = [_full_matte(small, grid, p, refine, photo.shape[:2], i, len(people)) for i, p in enumerate(people, 1)]
    if len(mattes) > 1:
        total = mattes[0].alpha.copy()  # summed in place: one full-size array however many people
        for m in mattes[1:]:
            total += m.alpha
        over = total > 1.0
        if over.any():
            for m in mattes:
                m.alpha[over] /= total[over]
    return mattes


def _found(photo: np.ndarray, method: str, threads, registry_path):
    """(the photo shrunk to GUIDE_SIZE, the grid the segmenters see, each person's probability on
    the grid: largest first); NoPersonError when there is nobody."""
    small = area_shrink(photo, GUIDE_SIZE)
    # a NaN or Inf survives the block average (a sum of huge values may overflow to Inf:
    # refused too), so one check of the small image covers the photo at a fraction of the cost
    if not np.all(np.isfinite(small)):
        raise ValueError("photo contains NaN or Inf (or values too large to average)")
    from relight.imaging.colour import srgb_encode

    small_srgb = srgb_encode(small).astype(np.float32)
    grid = area_shrink(small_srgb, NET_SIDE)
    people = _people(small_srgb, grid, method, threads, registry_path)
    if not people:
        raise NoPersonError(_NOBODY)
    return small, grid, people


def _full_matte(small: np.ndarray, grid: np.ndarray, probability: np.ndarray, refine: bool, size, index: int,
                count: int) -> PersonMatte:
    """One person's probability on the grid -> their PersonMatte at the photo's `size` (H, W)."""
    H, W = size
    alpha_small = _edge(small, grid, probability, refine)
    # snapped at the small size: bilinear interpolation between equal values is exact, so the
    # full-resolution matte is exactly 0 (photo untouched) and exactly 1 where its taps are
    alpha_small[alpha_small < ALPHA_FLOOR] = 0.0
    alpha_small[alpha_small > 1.0 - ALPHA_FLOOR] = 1.0
    alpha = upsample_support(alpha_small, H, W)
    box = Box.around(alpha)
    if box is None:  # the edge refinement erased a part the networks saw: treat as nobody
        raise NoPersonError(_NOBODY)
    return PersonMatte(alpha=alpha, box=box, index=index, count=count)


def _people(small: np.ndarray, grid: np.ndarray, method: str, threads, registry_path) -> list[np.ndarray]:
    """Each person's probability on the grid, largest first. `small` is the shrunken photo
    (sRGB, 512-1023 px: the detector and the pose crops see it), `grid` the same averaged
    over k x k blocks (256-511 px: the selfie model sees it, the masks are combined on it)."""
    h, w = grid.shape[:2]
    k = max(1, max(small.shape[:2]) // NET_SIDE)  # as area_shrink chose it
    floor = MIN_PERSON_FRACTION * h * w
    selfie = _selfie(_session("selfie", threads, registry_path), grid) if method != "pose" else None
    poses = [] if method == "selfie" else pose_people(
        _session("detector", threads, registry_path), _session("pose", threads, registry_path), small, (h, w), k,
        floor, PERSON_THRESHOLD, KEEP_RADIUS, selfie)
    if not poses:
        if selfie is None:
            return []
        labels, areas = _components(selfie)  # no detection: the selfie mask's parts are the people
        return [np.where(dilate(labels == i + 1, KEEP_RADIUS), selfie, np.float32(0.0)).astype(np.float32)
                for i in range(len(areas))]
    poses.sort(key=lambda m: -np.count_nonzero(m > PERSON_THRESHOLD))
    if selfie is None:
        return poses
    people = []
    for i, pose in enumerate(poses):
        others = np.max([m for j, m in enumerate(poses) if j != i], axis=0) if len(poses) > 1 else 0.0
        # the selfie mask has no people in it: its pixels near this person's mask, where
        # this person's mask beats the others', are this person's. Geometric mean: a soft
        # "both": a pixel only one network claims stays faint (less ghosting than the mean)
        mine = pose >= others  # where another person's mask is stronger, that person is
        before = np.count_nonzero(pose > PERSON_THRESHOLD)
        pose = np.where(mine, pose, np.float32(0.0))
        near = dilate(pose > PERSON_THRESHOLD, KEEP_RADIUS * max(1, round(max(h, w) / NET_SIDE)))
        own = np.where(near & mine, selfie, np.float32(0.0))
        inside = pose > PERSON_THRESHOLD
        if np.count_nonzero(inside) < max(floor, SAME_PERSON * before):  # others hold most of it: one person twice
            continue
        rows, cols = np.flatnonzero(inside.any(axis=1)), np.flatnonzero(inside.any(axis=0))
        if np.count_nonzero(inside) < MIN_FILL * (rows[-1] + 1 - rows[0]) * (cols[-1] + 1 - cols[0]):
            continue  # scraps strewn over others' edges and the background: no one's silhouette
        if own[inside].mean() < SELFIE_AGREEMENT:  # the selfie model missed this person
            people.append(pose.astype(np.float32))
        else:
            people.append(np.sqrt(own * pose).astype(np.float32))
    return people


def _components(probability: np.ndarray) -> tuple[np.ndarray, list[int]]:
    """Parts of probability > PERSON_THRESHOLD at least MIN_PERSON_FRACTION of the frame:
    (labels, 1 = largest; their areas)."""
    labels, areas = label(probability > PERSON_THRESHOLD)
    floor = MIN_PERSON_FRACTION * probability.size
    order = [i + 1 for i in sorted(range(len(areas)), key=lambda i: -areas[i]) if areas[i] >= floor]
    remap = np.zeros(len(areas) + 1, np.int32)
    for rank, lab in enumerate(order, start=1):
        remap[lab] = rank
    return remap[labels], [areas[lab - 1] for lab in order]


# ------------------------------------------------------------------ edge refinement


def _edge(small: np.ndarray, grid: np.ndarray, p: np.ndarray, refine: bool) -> np.ndarray:
    """The person's probability p (on the grid) at `small`'s size, snapped to the photo's edges.

    A fast guided filter (He and Sun 2015): the linear coefficients of alpha in
    a grey guide are fitted on the grid, where box filters are cheap, then
    upsampled and applied to the guide at `small`'s size, so the edge follows
    the photo's own edges there.
    """
    h, w = small.shape[:2]
    same = grid.shape[:2] == (h, w)
    if not refine:
        return p.copy() if same else bilinear_rows(p, h, w)
    from relight.imaging.colour import luminance

    # grey guides, roughly perceptual: the grid is sRGB already; at the small size the
    # sqrt of linear luminance stands in for the sRGB curve (cheaper)
    coarse = luminance(grid)
    guide = coarse if same else np.sqrt(np.clip(luminance(small), 0.0, 1.0)).astype(np.float32)
    ch, cw = coarse.shape
    r = max(1, round(GUIDE_RADIUS * max(ch, cw) / NET_SIDE))
    mean_i, mean_p = box_mean(coarse, r), box_mean(p, r)
    a = (box_mean(coarse * p, r) - mean_i * mean_p) / (box_mean(coarse * coarse, r) - mean_i * mean_i
                                                        + np.float32(GUIDE_EPS))
    b = mean_p - a * mean_i
    a, b = box_mean(a, r), box_mean(b, r)
    support = p
    if not same:
        a, b, support = bilinear_rows(a, h, w), bilinear_rows(b, h, w), bilinear_rows(p, h, w)
    out = a * guide + b
    np.clip(out, 0.0, 1.0, out=out)
    # where the person's probability is zero the background stands: the filter would
    # otherwise bleed into background that looks like the person
    out[support <= 0.0] = 0.0
    return out.astype(np.float32)
