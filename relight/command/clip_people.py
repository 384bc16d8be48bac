"""The people of a clip (relight.command.clip): each person found in a frame matched to a track, so
each keeps their identity, and their own smoothed maps and matte, from frame to frame; their mattes
kept from summing past 1 (shared_mattes); the shot's one light over the frames (ShotLight).

    tracker = Tracker(lambda: (MapSmoother(...), MatteSmoother(...)))
    tracks = tracker.match(boxes)      # one Track per box (the frame's people, largest first)

A frame's people are matched to the live tracks by the overlap of their matte boxes with each track's
last box (intersection over union), greedily, best pair first: for the few people of a shot (<= 5)
the greedy choice is the optimal one whenever each person overlaps only their own last box, which
people moving a few pixels a frame do. A pair overlapping by less than MIN_IOU is no match; a person
matched to no track starts a new one (fresh filters, the next number); a track not seen for
MISSED_FRAMES frames in a row ends (the person left), one not seen for fewer is kept (the segmenter
missed someone for a frame). One person and one track are the same person whatever the overlap: a
clip of one person is relit as before tracking existed.
"""

from __future__ import annotations

from collections import deque
from dataclasses import dataclass

import numpy as np

from relight.imaging.box import Box

__all__ = ["ShotLight", "Track", "Tracker", "MIN_IOU", "MISSED_FRAMES", "box_iou", "shared_mattes"]

MIN_IOU = 0.2        # a person moving by a quarter of their width a frame still overlaps their last box by 0.6
MISSED_FRAMES = 5    # frames a track outlives its person (0.2 s at 24 fps): a detector's brief miss


@dataclass
class Track:
    """One person followed over a shot: `number` their identity (1, 2, ... over the clip), `box` the
    matte's box last seen, `missed` frames since, `filters` (MapSmoother, MatteSmoother) their own."""

    number: int
    filters: tuple
    box: Box | None = None
    missed: int = 0
    first: int = 0                    # the clip's frame (0-based) the track began in, and last seen in
    last: int = 0
    first_box: Box | None = None

    @property
    def maps(self):
        return self.filters[0]

    @property
    def matte(self):
        return self.filters[1]


class ShotLight:
    """The mean of the per-frame light estimates over the shot's last `window` frames; while the
    person is still, held: the previous light weighted by `hold` x how still (still_weight)."""

    def __init__(self, window: int, hold: float = 0.0):
        self.lights: deque = deque(maxlen=max(1, int(window)))
        self.hold = float(hold)
        self.held: np.ndarray | None = None  # the last light given

    def reset(self) -> None:
        self.lights.clear()
        self.held = None

    def update(self, light: np.ndarray, still: float = 0.0) -> np.ndarray:
        """The shot's light after this frame's estimate `light`; `still`: the person's stillness
        in [0, 1] (still_weight)."""
        self.lights.append(np.asarray(light, np.float64))
        mean = np.mean(self.lights, axis=0)
        k = self.hold * float(still)
        if self.held is not None and k > 0.0:
            mean = k * self.held + (1.0 - k) * mean
        self.held = mean
        return mean.astype(np.float32)


def box_iou(a, b) -> float:
    """Intersection over union of two boxes (y0, y1, x0, x1), end exclusive."""
    h = min(a[1], b[1]) - max(a[0], b[0])
    w = min(a[3], b[3]) - max(a[2], b[2])
    if h <= 0 or w <= 0:
        return 0.0
    inter = float(h) * float(w)
    union = float(a[1] - a[0]) * float(a[3] - a[2]) + float(b[1] - b[0]) * float(b[3] - b[2]) - inter
    return inter / union if union > 0 else 0.0


class Tracker:
    """The live tracks of a shot (see the module doc); `filters()` makes a new track's filters."""

    def __init__(self, filters):
        self.filters = filters
        self.tracks: list[Track] = []
        self.next_number = 1
        self.ended: list[Track] = []   # tracks ended since the caller last took them (for its record)

    def reset(self) -> None:
        """A new shot: every track ends (the numbers go on: a person after a cut is a new identity)."""
        self.ended.extend(_ended(t) for t in self.tracks)
        self.tracks = []

    def match(self, boxes, frame: int = 0) -> list[Track]:
        """The track of each of this frame's people (`boxes`, their matte boxes), in the same order;
        their boxes and the tracks' bookkeeping advance to this frame (`frame`: its index in the clip)."""
        boxes = [Box(*(int(v) for v in b)) for b in boxes]
        chosen: list[Track | None] = [None] * len(boxes)
        if len(boxes) == 1 and len(self.tracks) == 1:
            chosen[0] = self.tracks[0]
        else:
            pairs = sorted(((box_iou(b, t.box), i, j) for i, b in enumerate(boxes)
                            for j, t in enumerate(self.tracks)), key=lambda p: (-p[0], p[1], p[2]))
            taken = set()
            for iou, i, j in pairs:
                if iou < MIN_IOU:
                    break
                if chosen[i] is None and j not in taken:
                    chosen[i] = self.tracks[j]
                    taken.add(j)
        for i, box in enumerate(boxes):
            if chosen[i] is None:
                chosen[i] = Track(self.next_number, self.filters(), first=frame, first_box=box)
                self.next_number += 1
                self.tracks.append(chosen[i])
        kept = []
        for t in self.tracks:
            if any(t is c for c in chosen):
                t.missed = 0
            else:
                t.missed += 1
                if t.missed >= MISSED_FRAMES:
                    self.ended.append(_ended(t))
                    continue
            kept.append(t)
        self.tracks = kept
        for t, box in zip(chosen, boxes):
            t.box, t.last = box, frame
        return chosen

    # ------------------------------------------------------------ state (a resumed job continues here)

    def state(self) -> dict[str, np.ndarray]:
        """The tracks as arrays: "tracks" (and "tracks_ended") [k, 12] ints (number, missed, first frame,
        last frame, box, first box), "track_next"; each live track's filters (filters_state) under
        "track{number}_", the first's under the bare keys a one-person clip's state has always had."""
        out = {"tracks": _rows(self.tracks), "tracks_ended": _rows(self.ended), "track_next": np.int64(self.next_number)}
        for i, t in enumerate(self.tracks):
            head = "" if i == 0 else f"track{t.number}_"
            out.update({head + k: v for k, v in filters_state(t.filters).items()})
        return out

    def load_state(self, state: dict) -> None:
        """Continue from a state() (one saved before tracking holds its one person's filters: track 1)."""
        self.next_number = int(state.get("track_next", 1))
        self.ended = [_ended(self._track(row)) for row in _unrows(state.get("tracks_ended"))]
        self.tracks = []
        for i, row in enumerate(_unrows(state.get("tracks"))):
            head = "" if i == 0 else f"track{int(row[0])}_"
            t = self._track(row)
            load_filters(t.filters, {k[len(head):]: v for k, v in state.items() if k.startswith(head)})
            self.tracks.append(t)
        if "tracks" not in state and ("matte" in state or "maps_box" in state):
            t = Track(1, self.filters())
            load_filters(t.filters, state)
            t.box = t.first_box = t.matte.box or (Box(*t.maps.state["box"]) if t.maps.state is not None else None)
            self.tracks, self.next_number = [t] if t.box is not None else [], 2

    def _track(self, row) -> Track:
        return Track(int(row[0]), self.filters(), box=Box(*map(int, row[4:8])), missed=int(row[1]),
                     first=int(row[2]), last=int(row[3]), first_box=Box(*map(int, row[8:12])))

    def record(self) -> list[dict]:
        """Every track of the clip so far, by number: {"track", "frames": [first, last] (0-based), "first_box",
        "last_box"} (boxes y0, y1, x0, x1)."""
        return [{"track": t.number, "frames": [t.first, t.last], "first_box": [int(v) for v in t.first_box],
                 "last_box": [int(v) for v in t.box]} for t in sorted(self.ended + self.tracks, key=lambda t: t.number)]


def _ended(t: Track) -> Track:
    """An ended track keeps its record only: its filters' frames are let go."""
    t.filters = None
    return t


def _rows(tracks) -> np.ndarray:
    rows = [[t.number, t.missed, t.first, t.last, *t.box, *(t.first_box or t.box)] for t in tracks]
    return np.asarray(rows, np.int64).reshape(len(rows), 12)


def _unrows(rows) -> np.ndarray:
    return np.zeros((0, 12), np.int64) if rows is None else np.asarray(rows, np.int64).reshape(-1, 12)


def filters_state(filters) -> dict[str, np.ndarray]:
    """A track's (MapSmoother, MatteSmoother) as arrays (the keys ClipRelighter has always saved)."""
    maps, matte = filters
    out = {}
    if matte.previous is not None:
        out["matte"] = matte.previous
        if matte.box is not None:
            out["matte_box"] = np.asarray(matte.box)
    if maps.state is not None:
        s = maps.state
        out.update({"maps_box": np.asarray(s["box"]), "maps_size": np.asarray(s["size"]),
                    "maps_grey": s["grey"], "maps_alpha": s["alpha"]})
        out.update({f"map_{k}": v for k, v in s["maps"].items()})
    return out


def load_filters(filters, state: dict) -> None:
    """filters_state's arrays back into a track's (MapSmoother, MatteSmoother)."""
    maps, matte = filters
    matte.previous = state.get("matte")
    matte.box = Box(*(int(v) for v in state["matte_box"])) if "matte_box" in state else None
    if "maps_box" in state:
        maps.state = {"box": tuple(int(v) for v in state["maps_box"]),
                      "size": tuple(int(v) for v in state["maps_size"]),
                      "grey": state["maps_grey"], "alpha": state["maps_alpha"],
                      "maps": {k[4:]: v for k, v in state.items() if k.startswith("map_")}}


def shared_mattes(mattes: list, boxes: list) -> list:
    """Several people's smoothed mattes scaled to sum to at most 1 where their soft edges overlap (as
    relight.person.matte.mattes_of_checked_photo leaves each frame's), so no light is counted twice;
    new arrays where changed, the filters' own never modified. One matte: as it is."""
    if len(mattes) < 2:
        return mattes
    region = boxes[0]
    for b in boxes[1:]:
        region = region.union(Box(*b))
    rows, cols = slice(region[0], region[1]), slice(region[2], region[3])
    total = np.sum([m[rows, cols] for m in mattes], axis=0)
    over = total > 1.0
    if not over.any():
        return mattes
    out = []
    for m in mattes:
        m = m.copy()
        part = m[rows, cols]
        part[over] /= total[over]
        out.append(m)
    return out
