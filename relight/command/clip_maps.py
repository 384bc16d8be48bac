"""The temporal filters of a clip (relight.command.clip): low-resolution maps and the person matte
smoothed over frames, and the photo-consistent albedo of the geometry-first model; a frame's
decomposition given the smoothed matte (with_mask) or moved onto a held grid (regridded).

Maps live on a grid: the working-resolution crop `box` = (y0, y1, x0, x1) of the frame
resized to `size` = (h, w). The previous frame's smoothed maps are resampled onto this
frame's grid (the boxes may differ), optionally displaced by optical flow, and blended:

    smoothed = k * previous(warped) + (1 - k) * current,   k = history * previous alpha * agree

`agree` = exp(-(d / AGREE_SCALE)^2), d the absolute difference between this frame's
working-resolution photo and the previous one's warped the same way (sRGB grey): where
the photo changed (the person moved more than the warp explains, or something new came
in), the current maps win, so motion leaves no trail. Where the picture is still
(Stillness: the frame's own blocks, whatever the crop), the history's weight is the
longer `hold` instead: a still shot's network answers differ only by its noise. `mode`: "ema" (no motion
compensation: the boxes' geometry only), "flow" (DIS optical flow, OpenCV; measured
against "ema" in docs/video.md). The full-resolution person matte gets the same
agreement test against its own previous value (MatteSmoother).
"""

from __future__ import annotations

import numpy as np

from relight.network.decomposition import Decomposition
from relight.imaging.box import Box
from relight.person.mask_ops import box_mean

__all__ = ["MapSmoother", "MatteSmoother", "Stillness", "grid_grey", "with_mask", "regridded", "FILTER_MODES",
           "AGREE_SCALE", "MATTE_AGREE_SCALE", "STILL_SCALE"]

FILTER_MODES = ("ema", "flow")
AGREE_SCALE = 0.08        # sRGB grey difference at which the history's weight falls to 1/e
MATTE_AGREE_SCALE = 0.25  # alpha difference at which the matte's history weight falls to 1/e
# the share of the person by which a frame's matte may outgrow the held one and still be held (jitter):
# a segmenter that missed most of the person in one frame and finds them in the next was wrong before,
# and holding its answer where the picture is still kept it wrong (issue 45: a farm clip's segmenter
# found 550 of 1,400 pixels in 4 of 12 frames; held, the stabilised clip lost 1.9 dB)
MATTE_AREA_AGREE = 0.2
# sRGB grey difference of a frame's STILL_BLOCKS (3 x 3 of them averaged) from the picture the held
# state belongs to at which a pixel stops counting as still: 10x sensor noise of sigma 2/255 there
# (3 q x 3 q pixels averaged, q >= 1: <= 0.74/255; its difference from a long mean: ~0.003); a 0.3
# contrast edge that moved by a third of a block changes its block by 0.1
STILL_SCALE = 0.03
STILL_BLOCKS = 256  # blocks along the frame's longer side: the stillness test's resolution


def grid_grey(photo_working: np.ndarray) -> np.ndarray:
    """sRGB grey [h, w] float32 of a working-resolution linear crop (what flow and the
    agreement test compare)."""
    from relight.imaging.colour import luminance, srgb_encode

    grey = luminance(photo_working)
    return srgb_encode(grey.astype(np.float32)).astype(np.float32)


def grid_axes(box_from, size_from, box_to, size_to) -> tuple[np.ndarray, np.ndarray]:
    """For each row and each column of grid `to`, its position (pixel units, centres at
    integers) on grid `from`: both grids are crops of one frame resized, so the mapping
    is separable."""
    fy0, fy1, fx0, fx1 = box_from
    ty0, ty1, tx0, tx1 = box_to
    fh, fw = size_from
    th, tw = size_to
    # frame coordinates of the `to` pixel centres, then `from` grid coordinates
    ys = ty0 + (np.arange(th, dtype=np.float64) + 0.5) * ((ty1 - ty0) / th)
    xs = tx0 + (np.arange(tw, dtype=np.float64) + 0.5) * ((tx1 - tx0) / tw)
    return (ys - fy0) * (fh / (fy1 - fy0)) - 0.5, (xs - fx0) * (fw / (fx1 - fx0)) - 0.5


def _taps(g: np.ndarray, n: int):
    """Bilinear taps along one axis: (first index, second index, weight of the second, inside)."""
    inside = (g > -0.5) & (g < n - 0.5)
    c = np.clip(g, 0, n - 1)
    i0 = np.minimum(np.floor(c).astype(np.intp), max(n - 2, 0))
    i1 = np.minimum(i0 + 1, n - 1)
    return i0, i1, (c - i0).astype(np.float32), inside


def sample_separable(image: np.ndarray, gy: np.ndarray, gx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of image [h, w, C] on the grid gy [H] x gx [W] (pixel units, centres at
    integers), and which samples fell inside the image [H, W] (outside: 0)."""
    h, w = image.shape[:2]
    y0, y1, fy, in_y = _taps(gy, h)
    x0, x1, fx, in_x = _taps(gx, w)
    fy = fy[:, None, None]
    rows = image[y0] * (1 - fy) + image[y1] * fy
    fx = fx[None, :, None]
    out = rows[:, x0] * (1 - fx) + rows[:, x1] * fx
    inside = in_y[:, None] & in_x[None, :]
    out[~inside] = 0.0
    return out.astype(np.float32, copy=False), inside


def sample(image: np.ndarray, gy: np.ndarray, gx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Bilinear samples of image [h, w, C] at (gy, gx) [H, W] (pixel units, centres at
    integers), and which samples fell inside the image [H, W] bool (outside: 0)."""
    h, w = image.shape[:2]
    flat = image.reshape(h * w, -1)
    y0, y1, fy, in_y = _taps(gy, h)
    x0, x1, fx, in_x = _taps(gx, w)
    fy, fx = fy[..., None], fx[..., None]
    top = flat[y0 * w + x0] * (1 - fx) + flat[y0 * w + x1] * fx
    bottom = flat[y1 * w + x0] * (1 - fx) + flat[y1 * w + x1] * fx
    out = top * (1 - fy) + bottom * fy
    inside = in_y & in_x
    out[~inside] = 0.0
    return out.astype(np.float32, copy=False), inside


def dis_flow(current: np.ndarray, previous: np.ndarray) -> np.ndarray:
    """Flow [h, w, 2] (dy, dx) with current(p) ~ previous(p + flow(p)): OpenCV's DIS on the
    sRGB greys (ValueError when OpenCV is not installed)."""
    try:
        import cv2
    except ImportError:
        raise ValueError("flow-guided filtering needs OpenCV: pip install opencv-python-headless") from None
    dis = cv2.DISOpticalFlow_create(cv2.DISOPTICAL_FLOW_PRESET_FAST)
    to_u8 = lambda g: np.clip(np.rint(g * 255.0), 0, 255).astype(np.uint8)
    h, w = current.shape
    if min(h, w) < 8:  # DIS needs a few patches
        return np.zeros((h, w, 2), np.float32)
    flow = dis.calc(to_u8(current), to_u8(previous), None)  # (dx, dy)
    return np.ascontiguousarray(flow[..., ::-1], dtype=np.float32)


class MapSmoother:
    """Exponential smoothing of named working-resolution maps over a clip's frames, the
    previous frame's maps warped onto this frame's grid first (see the module doc)."""

    def __init__(self, history: float, mode: str = "ema", hold: float = 0.0):
        for name, value in (("history", history), ("hold", hold)):
            if not 0.0 <= value < 1.0:
                raise ValueError(f"{name} must be in [0, 1), got {value}")
        if mode not in FILTER_MODES:
            raise ValueError(f"mode must be one of {FILTER_MODES}, got {mode!r}")
        self.history, self.mode, self.hold = float(history), mode, float(hold)
        self.state: dict | None = None

    def reset(self) -> None:
        self.state = None

    def update(self, box, size, grey: np.ndarray, alpha: np.ndarray, maps: dict,
               still: np.ndarray | None = None) -> dict:
        """The smoothed `maps` ({name: [h, w, C]}) of this frame (grid `box`, `size`; its
        sRGB grey [h, w] and alpha [h, w]; `still` [h, w]: the picture's stillness there,
        Stillness.on_grid, None: nowhere); the state becomes them. Never modifies its inputs."""
        prev = self.state
        if prev is None or self.history == 0.0:
            out = dict(maps)
        else:
            gy, gx = grid_axes(prev["box"], prev["size"], box, size)
            names = sorted(maps)
            stacked = np.concatenate([prev["maps"][k] for k in names] + [prev["alpha"][..., None],
                                                                         prev["grey"][..., None]], axis=2)
            if self.mode == "flow":
                warped_grey, _ = sample_separable(prev["grey"][..., None], gy, gx)
                flow = dis_flow(grey, warped_grey[..., 0])
                # the flow is measured on this grid; the previous grid's pixels are scaled by the boxes
                sy = prev["size"][0] / (prev["box"][1] - prev["box"][0]) * ((box[1] - box[0]) / size[0])
                sx = prev["size"][1] / (prev["box"][3] - prev["box"][2]) * ((box[3] - box[2]) / size[1])
                warped, inside = sample(stacked, gy[:, None] + flow[..., 0] * sy, gx[None, :] + flow[..., 1] * sx)
            else:
                warped, inside = sample_separable(stacked, gy, gx)
            prev_alpha, prev_grey = warped[..., -2], warped[..., -1]
            weight = np.float32(self.history) * np.exp(-np.square((grey - prev_grey) / np.float32(AGREE_SCALE)))
            if still is not None and self.hold > 0.0:
                weight = np.maximum(weight, np.float32(self.hold) * still)
            k = (weight * np.clip(prev_alpha, 0.0, 1.0) * inside)[..., None]
            out, c = {}, 0
            for name in names:
                n = maps[name].shape[2]
                out[name] = (k * warped[..., c:c + n] + (1 - k) * maps[name]).astype(np.float32)
                c += n
        self.state = {"box": tuple(int(v) for v in box), "size": tuple(int(v) for v in size),
                      "grey": grey, "alpha": alpha, "maps": out}
        return out


def _holds(alpha: np.ndarray, previous: np.ndarray) -> bool:
    """Whether MatteSmoother holds the previous matte where the picture is still: unless the current
    one covers more than MATTE_AREA_AGREE more of the person (the segmenter found what it had missed)."""
    now, before = float(alpha.sum(dtype=np.float64)), float(previous.sum(dtype=np.float64))
    return now - before <= MATTE_AREA_AGREE * max(now, before, 1e-6)


class MatteSmoother:
    """The full-resolution person matte smoothed over frames where it hardly changed:
    alpha = k * previous + (1 - k) * current, k = max(history * exp(-(|current - previous| /
    MATTE_AGREE_SCALE)^2), hold * still). A moving edge (a change near 1) takes the current
    matte at once unless the picture there is still (Stillness): the segmenter's small
    frame-to-frame jitter is averaged, and where the picture did not change at all its
    jitter, however large, is held with the longer `hold`. A person does not vanish from a still
    picture, so a matte that loses part of them there is held; one that covers more than
    MATTE_AREA_AGREE more of the person than the held matte found what the segmenter had missed,
    and is taken at once (nothing held that frame)."""

    def __init__(self, history: float, hold: float = 0.0):
        self.history, self.hold = float(history), float(hold)
        self.previous: np.ndarray | None = None
        self.box: Box | None = None  # holds every non-zero pixel of `previous`

    def reset(self) -> None:
        self.previous, self.box = None, None

    def update(self, alpha: np.ndarray, box=None, still=None) -> np.ndarray:
        """The smoothed matte of this frame; `box` (relight.imaging.box.Box), when known, holds every
        non-zero pixel of `alpha` (the person matte's box: spares a full-frame search); `still`
        (Stillness.at): (rows, cols) -> the picture's stillness at those pixels, None: nowhere."""
        prev = self.previous
        box = Box.around(alpha) if box is None else Box(*box)
        if prev is None or prev.shape != alpha.shape or self.history == 0.0:
            out = alpha
        else:
            out = alpha.copy()
            box = box.union(self.box) if box is not None else self.box
            if box is not None:  # only where either matte is non-zero: elsewhere both are 0
                r0, r1, c0, c1 = box
                a, p = alpha[r0:r1, c0:c1], prev[r0:r1, c0:c1]
                # where the mattes agree (inside the person, the background) the result is the
                # current matte already: only the pixels that differ (the edges) are computed
                where = np.nonzero(a != p)
                av, pv = a[where], p[where]
                d = (av - pv) * np.float32(1.0 / MATTE_AGREE_SCALE)
                k = np.exp(-(d * d)) * np.float32(self.history)
                if still is not None and self.hold > 0.0 and k.size and _holds(a, p):
                    k = np.maximum(k, np.float32(self.hold) * still(where[0] + r0, where[1] + c0))
                out[r0:r1, c0:c1][where] = av + k * (pv - av)
        self.previous, self.box = out, box
        return out


class Stillness:
    """Where the picture is still, judged on the frame's own blocks (q x q pixels, the frame's
    longer side in STILL_BLOCKS of them), so a crop that moves with the person's box does not
    count as change: still = exp(-(d / STILL_SCALE)^2), d the sRGB grey of the blocks around a
    block (3 x 3) less the reference's. The reference is the picture the held state belongs to:
    blended into with the same weight, hold * still, so a still picture's reference is its long
    mean (its noise averaged) and a slow drift adds up against it until it no longer counts as still.
    Only the blocks around the person's crop are computed; elsewhere the reference keeps the last
    picture seen there (unseen: never still)."""

    def __init__(self, hold: float):
        self.hold = float(hold)
        self.reference: np.ndarray | None = None  # [Hb, Wb] float32, NaN where never seen
        self.block = 1
        self.still: np.ndarray | None = None      # this frame's, over its blocks `span`
        self.span: tuple | None = None            # (b0, b1, c0, c1): the blocks computed

    def reset(self) -> None:
        self.reference, self.still, self.span = None, None, None

    def update(self, frame: np.ndarray, box) -> None:
        """Judge `frame` (linear [H, W, 3]) around `box` (y0, y1, x0, x1) against the reference."""
        from relight.imaging.colour import luminance, srgb_encode

        H, W = frame.shape[:2]
        q = max(1, int(round(max(H, W) / STILL_BLOCKS)))
        hb, wb = H // q, W // q  # whole blocks only: a partial one at the frame's edge is never still
        if self.reference is None or self.block != q or self.reference.shape != (hb, wb):
            self.reference, self.block = np.full((hb, wb), np.nan, np.float32), q
        y0, y1, x0, x1 = box
        b0, b1, c0, c1 = min(y0 // q, hb), min(-(-y1 // q), hb), min(x0 // q, wb), min(-(-x1 // q), wb)
        region = frame[b0 * q:b1 * q, c0 * q:c1 * q]
        # block sums per channel: every q-th row added in turn (whole rows at a time), then every q-th column
        rows = region[0::q].copy()
        for i in range(1, q):
            rows += region[i::q]
        sums = rows[:, 0::q].copy()
        for i in range(1, q):
            sums += rows[:, i::q]
        grey = srgb_encode(luminance(sums) * np.float32(1.0 / (q * q)))
        grey = grey.astype(np.float32)
        ref = self.reference[b0:b1, c0:c1]
        seen = np.isfinite(ref)
        change = box_mean(np.where(seen, grey - ref, np.float32(0.0)), 1)
        seen_all = box_mean(seen.astype(np.float32), 1) > 0.999  # every block around it seen before
        still = np.where(seen_all, np.exp(-np.square(change / np.float32(STILL_SCALE))), 0.0).astype(np.float32)
        k = np.float32(self.hold) * still
        # a new array, never the old one changed: a job's saved state (relight.command.cli_video) is a snapshot
        self.reference = self.reference.copy()
        self.reference[b0:b1, c0:c1] = np.where(seen, k * ref + (1 - k) * grey, grey)
        self.still, self.span = still, (b0, b1, c0, c1)

    def share(self, mask: np.ndarray) -> float:
        """The mask-weighted share of this frame's blocks that are still (`mask` [H, W], the person's
        full-resolution matte, read at the blocks' centres)."""
        b0, b1, c0, c1 = self.span
        q = self.block
        weight = mask[b0 * q + q // 2:b1 * q:q, c0 * q + q // 2:c1 * q:q]
        total = float(weight.sum(dtype=np.float64))
        return float((self.still * weight).sum(dtype=np.float64)) / total if total > 0 else 0.0

    def at(self, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        """This frame's stillness at full-resolution pixels (rows, cols): their blocks' (0 off them)."""
        b0, b1, c0, c1 = self.span
        q = self.block
        padded = np.pad(self.still, 1)  # a ring of 0: whatever lies off the blocks reads it
        r = np.clip(rows // q - (b0 - 1), 0, b1 - b0 + 1)
        c = np.clip(cols // q - (c0 - 1), 0, c1 - c0 + 1)
        return padded[r, c]

    def on_grid(self, box, size) -> np.ndarray:
        """This frame's stillness [h, w] on a working grid (the crop `box` resized to `size`)."""
        b0, _, c0, _ = self.span
        q = self.block
        gy, gx = grid_axes((b0 * q, (b0 + self.still.shape[0]) * q, c0 * q, (c0 + self.still.shape[1]) * q),
                           self.still.shape, box, size)
        return sample_separable(self.still[..., None], gy, gx)[0][..., 0]


def with_mask(d: Decomposition, mask: np.ndarray) -> Decomposition:
    """`d` with another full-resolution matte (the smoothed one), its working-resolution alpha
    resampled from it as decompose() does."""
    from relight.imaging.resample import resize_linear

    y0, y1, x0, x1 = d.box
    h, w = d.working_size
    alpha = np.clip(resize_linear(mask[y0:y1, x0:x1], h, w), 0.0, 1.0).astype(np.float32)
    return Decomposition(albedo=d.albedo, transport=d.transport, residual=d.residual, light=d.light, alpha=alpha,
                         box=d.box, working_size=d.working_size, photo=d.photo, photo_working=d.photo_working,
                         mask=mask, sh_order=d.sh_order, person_matte=d.person_matte, network_alpha=d.network_alpha)


def regridded(d: Decomposition, box: Box, size: tuple) -> Decomposition:
    """`d` on another grid of its photo (the crop `box` resized to `size`): the network's maps
    resampled bilinearly (edge values held past the old crop), the working photo cut and
    resized again from the frame as decompose() does."""
    from relight.imaging.resample import resize_linear

    gy, gx = grid_axes(d.box, d.working_size, box, size)
    h, w = d.working_size
    gy, gx = np.clip(gy, 0, h - 1), np.clip(gx, 0, w - 1)
    parts = [d.albedo, d.transport, d.residual, d.alpha[..., None]]
    if d.network_alpha is not None:
        parts.append(d.network_alpha[..., None])
    out, _ = sample_separable(np.concatenate(parts, axis=2), gy, gx)
    n = d.transport.shape[2]
    split = np.cumsum([3, n, n, 1])
    albedo, transport, residual, alpha = (np.ascontiguousarray(a) for a in np.split(out, split, axis=2)[:4])
    network_alpha = np.ascontiguousarray(out[..., -1]) if d.network_alpha is not None else None
    y0, y1, x0, x1 = box
    photo_working = resize_linear(d.photo[y0:y1, x0:x1], *size)
    return Decomposition(albedo=albedo, transport=transport, residual=residual, light=d.light, alpha=alpha[..., 0],
                         box=box, working_size=tuple(size), photo=d.photo, photo_working=photo_working,
                         mask=d.mask, sh_order=d.sh_order, person_matte=d.person_matte, network_alpha=network_alpha)


def history_weight(window: float) -> float:
    """The EMA weight whose effective window ((1 + k) / (1 - k) frames) is `window`."""
    return 0.0 if window <= 1.0 else (window - 1.0) / (window + 1.0)

