"""Relight a clip frame by frame, stable from one frame to the next (docs/video.md).

    clip = ClipRelighter(Relighter(...), sh_light("studio", 4), stability=0.5)
    for frame in frames:                      # linear float32 [H, W, 3], in order
        result = clip.relight(frame)          # FrameResult: .image, .person, .cut, .light ...

Each frame is relit as `relight image` relights a photo, except that what should
not change within a shot is held or smoothed over its frames:

* **cuts**: a frame whose colour histogram differs from the previous one's by more
  than CUT_THRESHOLD (total variation) starts a new shot, and every state below
  starts afresh; so does a frame without a person (it is passed through unchanged);
* **light**: the photo's light, which the geometry-first model fits per frame, is
  the mean of the per-frame estimates over the shot's last 1 + (LIGHT_WINDOW - 1) x
  stability frames, and the albedo is re-derived from the frame under that light
  (the model's own formula, relight.network.refine.consistent_albedo), so a noisy fit no
  longer flickers the brightness;
* **maps**: the transport (and residual; and the albedo of models that are not
  photo-consistent) and the person matte are smoothed over frames where the photo
  agrees with the previous frame (relight.command.clip_maps); the detail transfer uses each
  frame's own photo, so texture stays sharp;
* **a still picture** (clip_maps.Stillness: the frame's blocks against the picture the
  held state belongs to) holds more: the matte where the picture is still, the maps and the
  light as far as the whole person is (still_weight), with the window 1 + (STILL_WINDOW - 1)
  x stability; and a crop box that differs from the previous frame's by the segmenter's jitter
  keeps the previous grid (_on_held_grid); a frame whose held matte reaches past its own crop
  (the segmenter found only part of the person) is decomposed again around it (_on_matte). A
  still shot with sensor noise relit frame by frame moved 12-32x as much as it came, 4.5-18x stabilised; these bring it to 1.2-1.6x
  (docs/video.md, "A still shot").

* **everyone**: without --person, everyone the segmenter finds is relit, each tracked over the
  frames (relight.command.clip_people: matched by their matte boxes' overlap) with their own maps and
  matte filters, under one light for the shot: each frame's estimate is the mean of everyone's
  (relight.network.group.joint_light), smoothed as above. One person: exactly as before.

`stability` in [0, 1] sets the windows: 0 is independent per-frame processing
(exactly `relight image` on each frame), 1 the longest windows (most lag when the
light or the body changes). The whole state is a dict of arrays (state(),
load_state()) so an interrupted job resumes exactly where it stopped.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field

import numpy as np

from relight.imaging.box import Box
from relight.command.clip_maps import (
    FILTER_MODES, MapSmoother, MatteSmoother, Stillness, grid_grey, history_weight, regridded as _regridded,
    with_mask as _with_mask,
)
from relight.command.clip_people import ShotLight, Tracker, shared_mattes as _shared
from relight.lighting.light import checked_light
from relight.network.decomposition import Decomposition
from relight.network.refine import consistent_albedo

__all__ = ["ClipRelighter", "FrameResult", "CutDetector", "ShotLight", "DEFAULT_STABILITY",
           "FILTER_MODES"]

DEFAULT_STABILITY = 0.5
MAP_WINDOW = 9          # frames: the maps' and the matte's effective EMA window at stability 1
# frames: the light's window at stability 1. Measured (docs/video.md): on a person turning in place
# the network's estimate follows the body's view; a whole-shot mean cost 0.95 dB on that clip, 9
# frames 0.4 dB, 5 frames (stability 0.5) 0.2 dB, for flicker within 0.2 points of the whole shot's
LIGHT_WINDOW = 9
# frames: the maps' and the matte's window at stability 1 where the picture is still (clip_maps.Stillness):
# there the network's answers differ by the photo's noise alone, which MAP_WINDOW left flickering (docs/video.md)
STILL_WINDOW = 257
# share of the person that must be still before its light and maps are held, and the share from which
# they are fully held (still_weight): a still shot with sigma 2/255 noise measured 99.3 %, the farm clip
# of a person turning in place 80-85 % (93 % once)
STILL_PERSON = (0.9, 0.98)
CUT_THRESHOLD = 0.35    # histogram total variation between consecutive frames that starts a new shot
CUT_BINS = 8            # per channel, of the sRGB thumbnail's joint histogram
CUT_THUMB = 96          # px: longest side of the thumbnail the histogram counts


@dataclass
class FrameResult:
    image: np.ndarray                 # the relit frame, linear float32 [H, W, 3] (the input when no person)
    person: bool                      # False: nobody found, the frame passed through unchanged
    cut: bool                         # this frame starts a new shot
    light: np.ndarray | None = None   # the network's estimate of this frame's light [n, 3]
    shot_light: np.ndarray | None = None  # the light the frame was decomposed under (smoothed)
    clamped: float = 0.0              # share of the person's pixels whose negative light was clamped
    layers: dict | None = None        # Decomposition.layers() when asked for
    changed: tuple | None = None      # (y0, y1, x0, x1): outside it the image is the input bit for bit
    # everyone relit, largest first: {"track": identity over the clip, "person": size rank (1 = the
    # largest), "box": the matte's box}; `left`: those too small to relight; `found`: everyone found
    people: list = field(default_factory=list)
    left: list = field(default_factory=list)
    found: int = 0


@dataclass
class Seen:
    """Another person of a frame than the largest (Analysis.others)."""

    decomposition: Decomposition
    matte_box: Box | None
    index: int                         # size rank in the frame: 1 = the largest


@dataclass
class Analysis:
    """One frame as ClipRelighter.analyse leaves it for finish()."""

    frame: np.ndarray
    histogram: np.ndarray
    decomposition: Decomposition | None   # None: no person in the frame
    smooth_matte: bool = False            # the mask is the segmenter's: smoothed over frames in finish()
    matte_box: Box | None = None          # the segmenter's matte's box
    others: list = field(default_factory=list)  # everyone else relit (Seen), largest first
    left: list = field(default_factory=list)    # people too small to relight: {"person", "px", "why"}
    found: int = 0                        # people the segmenter found (0: not asked, or nobody)
    index: int = 1                        # `decomposition`'s size rank in the frame

    def people(self) -> list:
        """(decomposition, matte box, size rank) of everyone relit, largest first."""
        if self.decomposition is None:
            return []
        return [(self.decomposition, self.matte_box, self.index)] + \
            [(o.decomposition, o.matte_box, o.index) for o in self.others]


class CutDetector:
    """A new shot where consecutive frames' colour histograms differ by more than the threshold."""

    def __init__(self, threshold: float = CUT_THRESHOLD):
        self.threshold = float(threshold)
        self.previous: np.ndarray | None = None

    @staticmethod
    def histogram(frame: np.ndarray) -> np.ndarray:
        from relight.imaging.colour import srgb_encode

        step = max(1, max(frame.shape[:2]) // CUT_THUMB)
        thumb = srgb_encode(np.ascontiguousarray(frame[::step, ::step]))
        codes = np.minimum((thumb * CUT_BINS).astype(np.intp), CUT_BINS - 1)
        joint = (codes[..., 0] * CUT_BINS + codes[..., 1]) * CUT_BINS + codes[..., 2]
        counts = np.bincount(joint.ravel(), minlength=CUT_BINS ** 3).astype(np.float64)
        return counts / counts.sum()

    def update_histogram(self, hist: np.ndarray) -> bool:
        """True when the frame of histogram `hist` starts a new shot (the first frame does): its
        total variation from the previous frame's exceeds the threshold."""
        d = 1.0 if self.previous is None else 0.5 * float(np.abs(hist - self.previous).sum())
        self.previous = hist
        return d > self.threshold


def still_weight(share: float) -> float:
    """How still the person is, in [0, 1], from the share of them that is still: 0 until
    STILL_PERSON[0], rising linearly to 1 at STILL_PERSON[1]. The light and the network's maps
    are the whole person's: they are held only when nearly all of the person did not move."""
    low, high = STILL_PERSON
    return min(1.0, max(0.0, (share - low) / (high - low)))


class ClipRelighter:
    """Relights a clip's frames in order (see the module doc).

    relighter: relight.network.runtime.Relighter; light: target SH coefficients [n, 3] or a
    relight.lighting.light.CheckedLight; exposure_ev: as in Decomposition.relight (the light and the
    exposure checked here once, as a CheckedLight, which every frame's relight trusts); matte: "person" (the segmenter) or
    "network"; person: which person (1 = the largest), None: everyone the segmenter finds, each
    tracked over the frames (relight.command.clip_people) with their own maps and matte filters,
    under one light for the shot (the mean of everyone's, relight.network.group.joint_light; a
    person under relight.network.group.MIN_PERSON_PX left as they are); stability: 0..1; mode:
    "ema" or "flow" (relight.command.clip_maps); threads: the segmenter's onnxruntime threads;
    light_window: frames the light is averaged over (default 1 + (LIGHT_WINDOW - 1) x stability);
    working_size: the network's working size (default the relighter's own);
    matte_method, augment: the quality preset's person segmenter and network runs
    (relight.network.quality.QualityPreset), so that stability 0 is `relight image` on every frame.
    A preset's light refinement is not applied: a clip's light is the shot's (ShotLight).
    """

    def __init__(self, relighter, light, exposure_ev: float = 0.0, *, matte: str = "person",
                 person: int | None = None, stability: float = DEFAULT_STABILITY, mode: str = "ema",
                 threads: int | None = None, light_window: int | None = None, working_size=None,
                 matte_method: str = "ensemble", augment=()):
        # matte is checked where it is used, by Relighter.decompose (the command's parser has checked it before)
        if isinstance(stability, bool) or not isinstance(stability, (int, float)) or not 0.0 <= stability <= 1.0:
            raise ValueError(f"stability must be a number in [0, 1], got {stability!r}")
        self.relighter, self.light = relighter, checked_light(light, exposure_ev)
        self.matte, self.person, self.threads, self.working_size = matte, person, threads, working_size
        self.matte_method, self.augment = matte_method, tuple(augment)
        self.stability = float(stability)
        history = history_weight(1.0 + self.stability * (MAP_WINDOW - 1))
        hold = history_weight(1.0 + self.stability * (STILL_WINDOW - 1))
        self.cuts = CutDetector()
        if light_window is None:
            light_window = 1 + round(self.stability * (LIGHT_WINDOW - 1))
        elif isinstance(light_window, bool) or not isinstance(light_window, int) or light_window < 1:
            raise ValueError(f"light_window must be a whole number of frames >= 1, got {light_window!r}")
        self.shot_light = ShotLight(light_window, hold)
        MapSmoother(history, mode, hold)  # a bad mode fails here, not at the first person
        self.tracker = Tracker(lambda: (MapSmoother(history, mode, hold), MatteSmoother(history, hold)))
        self.stillness = Stillness(hold)
        self.frame = 0                    # the clip's next frame to finish (the tracks' record)
        self.counts = np.zeros(3, np.int64)  # most people found in a frame, most relit, frames with one left
        config = json.loads(relighter.metadata.get("relight.network_config", "{}") or "{}")
        # the geometry-first model's albedo is photo / shading under its fitted light: re-derived
        # under the shot's light (docs/model.md); other models' albedo is smoothed like the maps
        self.reliable = float(config["reliable"]) if config.get("arch") == "geometry" else None

    def reset(self) -> None:
        """Forget the shot: the next frame starts afresh (a cut, a frame without a person)."""
        self.shot_light.reset()
        self.tracker.reset()
        self.stillness.reset()

    def state(self) -> dict[str, np.ndarray]:
        """Everything the next frame depends on, as arrays (np.savez-able); load_state() restores it."""
        lights = list(self.shot_light.lights)
        out = {"lights": np.stack(lights) if lights else np.zeros((0,))}
        if self.shot_light.held is not None:
            out["held_light"] = self.shot_light.held
        if self.cuts.previous is not None:
            out["cut_histogram"] = self.cuts.previous
        if self.stillness.reference is not None:
            out["still_reference"] = self.stillness.reference
            out["still_block"] = np.asarray(self.stillness.block)
        out.update(self.tracker.state())  # each person's maps and matte
        out["frame"], out["people_counts"] = np.int64(self.frame), self.counts.copy()
        return out

    def load_state(self, state: dict) -> None:
        """Continue from a state() (of a ClipRelighter with the same settings)."""
        self.reset()
        self.cuts.previous = state.get("cut_histogram")
        for light in state["lights"]:
            self.shot_light.lights.append(np.asarray(light, np.float64))
        if "held_light" in state:  # (a state saved before it was kept: the window's mean holds)
            self.shot_light.held = np.asarray(state["held_light"], np.float64)
        elif len(self.shot_light.lights):
            self.shot_light.held = np.mean(self.shot_light.lights, axis=0)
        if "still_reference" in state:  # (a state saved before it was kept: judged afresh)
            self.stillness.reference = np.array(state["still_reference"], np.float32)
            self.stillness.block = int(state["still_block"])
        self.tracker.load_state(state)
        self.frame = int(state.get("frame", 0))
        self.counts = np.array(state.get("people_counts", np.zeros(3)), np.int64)

    def record(self) -> dict:
        """The people of the clip so far (plain JSON values): the most found in one frame, the most
        relit in one frame, the frames where someone was left as they were (too small), and every
        track (clip_people.Tracker.record: its frames and first and last boxes)."""
        found, relit, left = (int(v) for v in self.counts)
        return {"found": found, "relit": relit, "frames_with_people_left": left, "tracks": self.tracker.record(),
                "light": "one for the shot, from everyone relit" if relit > 1 else "the person's own"}

    def analyse(self, frame: np.ndarray, mask: np.ndarray | None = None) -> "Analysis":
        """What does not depend on other frames: the person matte, the network's decomposition
        and the frame's histogram. Thread-safe: a job analyses several frames at once, then
        finish()es them in order. `mask` ([H, W] in [0, 1]): the frame's own person mask (its
        alpha channel), used as it is instead of the matte."""
        from relight.person.matte import NoPersonError, person_matte

        histogram = self.cuts.histogram(frame)
        smooth_matte, matte_box = False, None
        if mask is not None and not np.any(mask > 0):  # the frame's own alpha marks nobody
            return Analysis(frame, histogram, None)
        if mask is None and self.matte == "person" and self.person is None:
            return self._everyone(frame, histogram)
        if mask is None and self.matte == "person":
            try:
                found = person_matte(frame, self.person, threads=self.threads, method=self.matte_method)
            except NoPersonError:
                return Analysis(frame, histogram, None)
            mask, smooth_matte, matte_box = found.alpha, self.stability > 0, found.box
        return Analysis(frame, histogram, self._decompose(frame, mask), smooth_matte, matte_box)

    def _decompose(self, frame: np.ndarray, mask: np.ndarray | None) -> Decomposition:
        """The network's decomposition of `frame` under this clip's settings, cropped around `mask`."""
        return self.relighter.decompose(frame, mask, self.working_size, matte=self.matte, person=self.person,
                                        matte_method=self.matte_method, augment=self.augment)

    def _everyone(self, frame: np.ndarray, histogram: np.ndarray) -> "Analysis":
        """analyse() of everyone the segmenter finds, each decomposed at their own crop (as
        relight.network.group.decompose_people, without its joint light: finish() fits the shot's)."""
        from relight.network.group import MIN_PERSON_PX
        from relight.person import matte as segmenter
        from relight.person.linear_photo import check_photo

        checked = check_photo(frame, segmenter.MIN_SIDE, finite=False, purpose="a person matte")
        try:
            mattes = segmenter.mattes_of_checked_photo(checked, threads=self.threads, method=self.matte_method)
        except segmenter.NoPersonError:
            return Analysis(frame, histogram, None)
        seen, left = [], []
        for m in mattes:
            side = max(m.box.height, m.box.width)
            if side < MIN_PERSON_PX and m.index > 1:  # the largest is always relit (relight.network.group)
                left.append({"person": m.index, "px": int(side),
                             "why": f"too small to relight ({side} < {MIN_PERSON_PX} px)"})
                continue
            d = self.relighter.decompose(frame, m.alpha, self.working_size, matte=self.matte,
                                         matte_method=self.matte_method, augment=self.augment)
            seen.append(Seen(d, m.box, m.index))
        if not seen:
            return Analysis(frame, histogram, None, left=left, found=len(mattes))
        return Analysis(frame, histogram, seen[0].decomposition, self.stability > 0, seen[0].matte_box, seen[1:],
                        left, len(mattes), seen[0].index)

    def finish(self, analysis: "Analysis", layers: bool = False) -> FrameResult:
        """The analysed frame relit, in clip order (the temporal state advances by one frame).
        `layers`: also Decomposition.layers() of the frame (None when it has no person)."""
        cut = self.cuts.update_histogram(analysis.histogram)
        if cut:
            self.reset()
        index, self.frame = self.frame, self.frame + 1
        people = analysis.people()
        found = analysis.found or len(people)
        self.counts = np.maximum(self.counts, [found, len(people), 0]) + [0, 0, bool(analysis.left)]
        if not people:
            self.reset()
            return FrameResult(analysis.frame, False, cut, left=analysis.left, found=found)
        boxes = [b if b is not None else d.box for d, b, _ in people]
        tracks = self.tracker.match(boxes, index)
        ds = [d for d, _, _ in people]
        if len(ds) == 1:
            estimate = np.asarray(ds[0].light, np.float32)
        else:
            from relight.network.group import joint_light

            estimate = joint_light(ds)
        shot_light = estimate
        if self.stability > 0:
            region = None
            for d, t in zip(ds, tracks):
                held = t.maps.state
                box = d.box if held is None else d.box.union(Box(*held["box"]))
                region = box if region is None else region.union(box)
            self.stillness.update(analysis.frame, region)
            stills = [self._person_still(d) for d in ds]
            ds = [self._on_held_grid(d, b, t.maps) if s > 0.0 else d
                  for d, (_, b, _), t, s in zip(ds, people, tracks, stills)]
            if analysis.smooth_matte:
                mattes = _shared([t.matte.update(d.mask, b, self.stillness.at)
                                  for d, (_, b, _), t in zip(ds, people, tracks)], boxes)
                ds = [self._on_matte(d, m, analysis.frame) for d, m in zip(ds, mattes)]
            # the light is the whole shot's: held only as far as everyone is still
            shot_light = self.shot_light.update(estimate, min(stills))
            # the network's answer at a pixel depends on the whole crop: its maps are held where the
            # picture is still only as far as the whole person is
            ds = [self._stabilised(d, shot_light, self.stillness.on_grid(d.box, d.working_size) * np.float32(s),
                                   t.maps) for d, t, s in zip(ds, tracks, stills)]
        elif len(ds) > 1:  # as relight image relights a group: everyone under the photo's one light
            ds = [d.with_light(estimate) for d in ds]
        who = [{"track": t.number, "person": rank, "box": tuple(int(v) for v in box)}
               for t, (_, _, rank), box in zip(tracks, people, boxes)]
        if len(ds) == 1:
            d = ds[0]
            image = d.relight(self.light)
            stats = d.last_stats
            return FrameResult(image, True, cut, estimate, shot_light, stats.fraction if stats is not None else 0.0,
                               d.layers(self.light) if layers else None, d.box, who,
                               analysis.left, found)
        from relight.network.group import Group

        image = Group(ds).relight(self.light)
        clamped = max(d.last_stats.fraction if d.last_stats is not None else 0.0 for d in ds)
        out_layers = None
        if layers:  # each person's layers are zero outside their own matte
            out_layers = ds[0].layers(self.light)
            for d in ds[1:]:
                for name, layer in d.layers(self.light).items():
                    out_layers[name] += layer
        changed = ds[0].box
        for d in ds[1:]:
            changed = changed.union(d.box)
        return FrameResult(image, True, cut, estimate, shot_light, clamped, out_layers, changed, who,
                           analysis.left, found)

    def relight(self, frame: np.ndarray, mask: np.ndarray | None = None, layers: bool = False) -> FrameResult:
        """The next frame (linear float32 [H, W, 3]) relit: finish(analyse(frame, mask))."""
        return self.finish(self.analyse(frame, mask), layers)

    def _person_still(self, d: Decomposition) -> float:
        """How still a person is (still_weight), from this frame's Stillness over their matte."""
        if d.mask is not None:
            return still_weight(self.stillness.share(d.mask))
        grid = self.stillness.on_grid(d.box, d.working_size)  # the network's matte: on its grid
        return still_weight(float((grid * d.alpha).sum() / max(float(d.alpha.sum()), 1e-6)))

    def _on_matte(self, d: Decomposition, matte: np.ndarray, frame: np.ndarray) -> Decomposition:
        """`d` with the smoothed `matte`; decomposed again, cropped around that matte, when it reaches
        past d's crop: a frame whose segmenter found only part of a person the held matte still has
        (a crop holds only what its own matte found, so the rest could not be relit)."""
        held = Box.around(matte, 0.5)
        if held is None or d.box.contains(held):
            return _with_mask(d, matte)
        return self._decompose(frame, matte)

    def _on_held_grid(self, d: Decomposition, matte_box, smoother: MapSmoother) -> Decomposition:
        """`d` on the previous frame's grid when its crop differs from it by the segmenter's jitter
        only (finish() asks when the person is still): the person (the matte's box) inside the
        previous crop, which lies within this frame's own crop grown by its margin. A crop box that
        flicks by a pixel or two resamples a textured photo differently each frame, which the detail
        transfer and the albedo carry into the relit person (docs/video.md); the network's smooth
        maps are resampled onto the held grid instead."""
        from relight.network.runtime import CROP_MARGIN

        held = smoother.state
        if held is None or d.mask is None or tuple(held["box"]) == tuple(d.box):
            return d
        box = Box(*held["box"])
        person = Box(*matte_box) if matte_box is not None else Box.around(d.mask)
        if person is None:
            return d
        pad = int(np.ceil(CROP_MARGIN * max(person.height, person.width)))
        outer = d.box.grown(pad, *d.size)
        if not (box.contains(person) and outer.contains(box)):
            return d
        return _regridded(d, box, held["size"])

    def _stabilised(self, d: Decomposition, shot_light: np.ndarray, still: np.ndarray,
                    smoother: MapSmoother) -> Decomposition:
        """The frame's decomposition with smoothed maps (the person's own `smoother`), under the shot's light."""
        maps = {"transport": d.transport}
        if self.reliable is None:  # the geometry-first model's E is 0 (docs/model.md): nothing to smooth
            maps["residual"] = d.residual
            maps["albedo"] = d.albedo
        if d.mask is None:  # the network's own matte: smoothed with the maps
            maps["alpha"] = d.alpha[..., None]
        grey = grid_grey(d.photo_working)
        smooth = smoother.update(d.box, d.working_size, grey, d.alpha, maps, still)
        transport = smooth["transport"]
        alpha = smooth["alpha"][..., 0] if "alpha" in smooth else d.alpha
        if self.reliable is not None:
            albedo = consistent_albedo(d, transport, shot_light.astype(np.float32), self.reliable)
        else:
            albedo = smooth["albedo"]
        return Decomposition(
            albedo=albedo, transport=transport, residual=smooth.get("residual", d.residual), light=shot_light,
            alpha=alpha,
            box=d.box, working_size=d.working_size, photo=d.photo, photo_working=d.photo_working, mask=d.mask,
            sh_order=d.sh_order, person_matte=d.person_matte, network_alpha=d.network_alpha)

