"""What the network saw in one photo, and relighting it: rho * (T . L') + E . L'.

A Decomposition keeps the network's outputs at working resolution over the
crop around the person. Relighting evaluates the formula (relight.network.prt) over the
matte's pixels only, clamps it at 0 (negative light is SH ringing,
docs/conventions.md), and hands it to relight.network.composite, which brings it to the
photo's resolution over the untouched original. The light is SH coefficients
[n, 3]: relight.lighting.light turns maps, presets and other photos into them.
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from relight.lighting import sh
from relight.imaging.box import Box
from relight.network.composite import ALPHA_FLOOR, DETAIL_EPS, composite
from relight.network.foreground import foreground, smooth_colours
from relight.lighting.light import CheckedLight, checked_light, fit_checked
from relight.person.mask_ops import dilate
from relight.imaging.resample import Bilinear
from relight.network.shadowing import ShadowCaster, key_of

__all__ = ["DETAIL_EPS", "DETAIL_MAX", "Decomposition", "RelightStats"]

DETAIL_MAX = 8.0    # cap on the detail ratio: a speck cannot blow up
# the light's bands past the order a relight uses may move a working-resolution value by at
# most this (linear; an 8-bit output step is >= 1/255 of white at sRGB's steepest): per request,
# bands a light does not need are not evaluated (docs/TRADEOFFS.md, "Only what the photo needs")
ORDER_TOLERANCE = 0.25 / 255
STRIP_ROWS = 128    # full-resolution rows resampled at a time by layers() (bounds temporaries)
LAYER_NAMES = ("albedo", "shading", "residual", "alpha")  # Decomposition.layers(), in this order


def _light(coeffs, exposure_ev) -> CheckedLight:
    """The light a caller gives: a CheckedLight without more exposure as it is (checked where it was
    made), anything else checked once by relight.lighting.light.checked_light."""
    if isinstance(coeffs, CheckedLight) and type(exposure_ev) in (int, float) and exposure_ev == 0:
        return coeffs
    return checked_light(coeffs, exposure_ev)


@dataclass(frozen=True)
class RelightStats:
    """Negative light clamped to 0 by one relight, counted at working resolution
    over the matte's pixels (alpha > 0)."""

    clamped: int    # pixels with a channel of albedo * (T . L') + E . L' below 0
    pixels: int     # pixels of the matte
    darkest: float  # the most negative channel value before the clamp (0.0 when none)
    sh_order: int = -1      # the light's order evaluated (bands above moved no value > ORDER_TOLERANCE)
    residual: bool = True   # whether E . L' was evaluated (False: E is zero on the matte)
    shadow_key: object = None   # the key light whose cast shadows dimmed it (relight.network.shadowing), or None
    fraction: float = field(init=False)  # clamped / pixels (0.0 for no pixels), computed once

    def __post_init__(self):
        object.__setattr__(self, "fraction", self.clamped / self.pixels if self.pixels else 0.0)


@dataclass
class Decomposition:
    """What the network saw in one photo, kept at working resolution.

    albedo [h, w, 3], transport [h, w, n], residual [h, w, n], alpha [h, w]
    and light [n, 3] belong to the crop `box` (relight.imaging.box.Box: y0, y1, x0, x1) of the
    photo resized to `working_size` = (h, w). `photo` is the original (not copied).
    residual=None: the model has no residual E (its metadata says so): the field then
    reads as zeros without holding any, and E . L' is never evaluated. Built once per
    photo; `with_light` gives it another estimate of the photo's light.
    """

    albedo: np.ndarray
    transport: np.ndarray
    residual: np.ndarray
    light: np.ndarray
    alpha: np.ndarray
    box: Box
    working_size: tuple[int, int]
    photo: np.ndarray = field(repr=False)
    photo_working: np.ndarray = field(repr=False)   # the crop at working resolution
    mask: np.ndarray | None = field(default=None, repr=False)  # user mask (full resolution)
    sh_order: int = 4
    person_matte: object = field(default=None, repr=False)  # relight.person.matte.PersonMatte when it gave the mask
    network_alpha: np.ndarray | None = field(default=None, repr=False)  # the alpha head's [h, w], as it came
    choices: dict = field(default_factory=dict)  # what the runtime decided for this photo (output metadata)
    depth: np.ndarray | None = field(default=None, repr=False)  # the depth head's [h, w] (issue 45), or None

    def __post_init__(self):
        self.box = Box(*self.box)
        h, w = self.working_size
        n = self._n = sh.num_coeffs(self.sh_order)  # the model's order, checked once: trusted after
        zero_residual = self.residual is None
        if zero_residual:  # the model has no E (relight.models.session.ModelSession.residual_is_zero): no array
            self.residual = np.broadcast_to(np.zeros((), np.float32), (h, w, n))  # zeros, no memory
        # matte pixels grown by one: the bilinear taps of every full-resolution
        # pixel inside the matte then read relit values, never the zeros around
        self._matte = np.flatnonzero(dilate(self.alpha > 0, 1).reshape(-1))
        inside = self.alpha.reshape(-1)[self._matte] > 0  # the grown ring is not the person
        if zero_residual:
            self._residual_m, self._has_residual = None, False
        else:
            self._residual_m = np.ascontiguousarray(self.residual.reshape(-1, n)[self._matte])
            self._has_residual = bool(np.any(self._residual_m))
        self._inside = inside.astype(np.float32)
        self._inside_count = int(np.count_nonzero(inside))
        self.last_stats: RelightStats | None = None  # set by every relight (the latest call's)
        y0, y1, x0, x1 = self.box
        self._up = Bilinear(y1 - y0, x1 - x0, h, w)
        self._alpha_prepared = None
        self._smooth_prepared = None  # relight.network.foreground's smooth colours, prepared on demand
        self._exposed_last: tuple | None = None  # (light, exposure, exposed): _exposed's last answer
        self.shadows = ShadowCaster(self.transport, self.alpha, self._matte, self.depth)
        self._gather()

    def _gather(self) -> None:
        """The albedo and transport over the matte's pixels, and what each light band can add."""
        n = self._n
        self._albedo_m = np.ascontiguousarray(self.albedo.reshape(-1, 3)[self._matte])
        self._transport_m = np.ascontiguousarray(self.transport.reshape(-1, n)[self._matte])
        # per band l, the largest |T_l(x)| (and |E_l(x)|) over the matte: bounds what the light's
        # band l can add to any pixel (Cauchy-Schwarz), so a request evaluates only the bands it needs
        bands = [slice(l * l, (l + 1) * (l + 1)) for l in range(self.sh_order + 1)]
        reach = np.zeros(len(bands))
        for part in (self._transport_m, self._residual_m) if self._has_residual else (self._transport_m,):
            if part.shape[0]:
                albedo_max = 1.0 if part is self._residual_m else max(float(self._albedo_m.max(initial=0.0)), 0.0)
                reach += albedo_max * np.array([np.sqrt((part[:, b].astype(np.float64) ** 2).sum(axis=1)).max()
                                                for b in bands])
        self._band_reach = reach

    def with_light(self, light: np.ndarray, transport: np.ndarray | None = None,
                   reliable: float | None = None) -> "Decomposition":
        """This photo's decomposition under another estimate of its light [n, 3] (and, from
        relight.network.tta, its transport [h, w, n]): the one step that changes the photo's light. The
        albedo follows from them by the model's photo-consistent rule
        (relight.network.refine.consistent_albedo -> relight.network.prt.photo_consistent_albedo, the rule the
        graph runs; `reliable`: its shading floor, None: relight.network.prt.ALBEDO_RELIABLE). The
        matte, crop and resamplers are kept, not rebuilt; this object is unchanged."""
        from relight.network.refine import consistent_albedo

        transport = self.transport if transport is None else transport
        light = np.asarray(light, np.float32)
        new = copy.copy(self)
        new.transport, new.light = transport, light
        new.albedo = consistent_albedo(self, transport, light, *(() if reliable is None else (reliable,)))
        if transport is not self.transport:
            new.shadows = ShadowCaster(transport, self.alpha, self._matte, self.depth)
        new.choices = dict(self.choices)
        new.last_stats = None
        new._gather()
        return new

    @property
    def size(self) -> tuple[int, int]:
        """(H, W) of the photo."""
        return self.photo.shape[:2]

    def exposed_light(self, coeffs, exposure_ev: float = 0.0) -> np.ndarray:
        """The light a relight uses: SH coefficients [m, 3] (checked; a
        relight.lighting.light.CheckedLight is trusted) cut or zero-padded to the model's order,
        times 2**exposure_ev, float32. Made once per light: asked again for the same coefficients
        and exposure (the add-on's layers, relight then layers) it returns the same array."""
        light = _light(coeffs, exposure_ev)
        return self._exposed(light.coeffs, light.scale)

    def _exposed(self, light: np.ndarray, scale: float) -> np.ndarray:
        """exposed_light of a CheckedLight's coefficients and scale: nothing checked again."""
        last = self._exposed_last
        if last is not None and last[1] == scale and last[0].shape == light.shape and np.array_equal(last[0], light):
            return last[2]
        at_order = light if light.shape[0] == self._n else fit_checked(light, self._n)
        L = (at_order * scale).astype(np.float32)
        L.setflags(write=False)  # shared by every call with this light
        self._exposed_last = (light.copy(), scale, L)
        return L

    def order_needed(self, light: np.ndarray) -> int:
        """The smallest SH order k whose dropped bands (k+1 .. the model's order) can move no
        value of this decomposition's relight by more than ORDER_TOLERANCE under `light`
        [n, 3] (fitted to the model's order, exposure applied)."""
        bands = np.array([np.linalg.norm(light[l * l:(l + 1) * (l + 1)], axis=0).max()
                          for l in range(self.sh_order + 1)])
        tail = np.cumsum((self._band_reach * bands)[::-1])[::-1]  # tail[l]: bands l.. together
        for k in range(self.sh_order):
            if tail[k + 1] <= ORDER_TOLERANCE:
                return k
        return self.sh_order

    def relit_at_working_size(self, coeffs, exposure_ev: float = 0.0, *, output_scale: float = 1.0,
                              shadows: bool = False) -> np.ndarray:
        """The relit person at working resolution, [h, w, 3], zero outside the matte:
        max(0, albedo * (T . L') + E . L') on the matte's pixels (float32 matmuls).
        Only the light's bands this request needs are evaluated (order_needed, judged on the
        result times `output_scale`: the exposure a caller applies after), and E . L' only when
        E is not zero; `last_stats` says which.

        A radiance is >= 0; negative values are SH truncation ringing (or network
        error), not light: they are set to 0 and counted in `last_stats`
        (docs/conventions.md, "Ringing and negative light"). `shadows`: see relight().
        """
        return self._relit_working(self.exposed_light(coeffs, exposure_ev), output_scale, shadows)

    def _relit_working(self, L: np.ndarray, output_scale: float, shadows: bool = False) -> np.ndarray:
        """relit_at_working_size under the exposed light L; `shadows`: its key light's cast shadows drawn
        (relight.network.shadowing; none when L has no directional part)."""
        h, w = self.working_size
        order = self.order_needed(L * np.float32(output_scale))
        n = (order + 1) ** 2  # order_needed's answer: within the model's order
        shading = self._transport_m[:, :n] @ L[:n]
        key = key_of(L) if shadows else None
        if key is not None:
            shading -= self.shadows.blocked_shading(key, self._transport_m, order)
        relit = self._albedo_m * shading
        if self._has_residual:
            relit += self._residual_m[:, :n] @ L[:n]
        # per-pixel minimum as two column minima: relit.min(axis=1) loops 3 values at a time, 30x slower
        darkest = np.minimum(np.minimum(relit[:, 0], relit[:, 1]), relit[:, 2])
        np.minimum(darkest, np.float32(0.0), out=darkest)
        darkest *= self._inside  # only the person's pixels count, not the grown ring
        self.last_stats = RelightStats(clamped=int(np.count_nonzero(darkest)), pixels=self._inside_count,
                                       darkest=float(darkest.min(initial=0.0)), sh_order=order,
                                       residual=self._has_residual, shadow_key=key)
        np.maximum(relit, np.float32(0.0), out=relit)
        if self._matte.size == h * w:  # matte covers the crop: no scatter needed
            return relit.reshape(h, w, 3)
        out = np.zeros((h * w, 3), np.float32)
        out[self._matte] = relit
        return out.reshape(h, w, 3)

    def relight(self, coeffs, exposure_ev: float = 0.0, detail: bool = True,
                out: np.ndarray | None = None, shadows: bool = False, accumulate: bool = False) -> np.ndarray:
        """The photo relit by the SH light `coeffs`, linear float32 [H, W, 3] at full resolution.

        `coeffs`: SH coefficients [m, 3] (cut or zero-padded to the model's order;
        relight.lighting.light.sh_light makes them from a map, preset or another photo), checked
        here, or a relight.lighting.light.CheckedLight, checked where it was made (`relight image`'s
        light, relight.lighting.light.SHLight.checked_at) and trusted; scaled by 2**exposure_ev. Pixels outside the matte keep their values bit
        for bit. When the crop was resized for the network, `detail` relights the
        full-resolution photo by the upsampled quotient relit / photo of working
        resolution (keeps the photo's fine texture); without it the relit person
        is just upsampled. The relit person is >= 0 (negative light clamped;
        `last_stats` counts it). `out` ([H, W, 3] float32, a strided view too):
        written and returned instead of a new array (relight.network.composite). `shadows`: the
        light's directional part casts shadows on the person (relight.network.shadowing). `accumulate`:
        `out` already holds the photo with other people relit; this person's change is added over its
        box (relight.network.group).
        """
        light = _light(coeffs, exposure_ev)
        scale = np.float32(light.scale)
        relit = self._relit_working(self._exposed(light.coeffs, 1.0), float(scale), shadows)
        quotient = detail and not self._up.identity
        if quotient:
            source = (relit + DETAIL_EPS) / (self.photo_working + DETAIL_EPS)
            # capped: a bright speck averaged away at working resolution would
            # otherwise be multiplied by relit / (its dark surroundings)
            np.clip(source, 0.0, DETAIL_MAX, out=source)
        else:
            source = relit
        # exposure folded into what is upsampled: a power of two for whole EV
        # steps, so +1 EV still doubles the person exactly
        source *= scale
        return composite(self.photo, self.box, self._up, self.alpha, self.mask, source, quotient, scale, out,
                         accumulate)

    def _alpha_strip(self, r0: int, r1: int) -> np.ndarray:
        y0, _, x0, x1 = self.box
        if self.mask is not None:
            return self.mask[y0 + r0:y0 + r1, x0:x1, None]
        if self._up.identity:
            return self.alpha[r0:r1, :, None]  # already floored at decomposition
        if self._alpha_prepared is None:
            self._alpha_prepared = self._up.prepare(self.alpha[..., None])
        a = self._up.strip(self._alpha_prepared, r0, r1)  # a fresh array
        a[a < ALPHA_FLOOR] = 0.0
        return a

    def full_alpha(self, out: np.ndarray | None = None) -> np.ndarray:
        """The matte at full resolution [H, W] (zero outside the crop); `out`: see layer()."""
        out = self._full_out(out, ())
        y0, y1, x0, x1 = self.box
        for r0 in range(0, y1 - y0, STRIP_ROWS):
            r1 = min(r0 + STRIP_ROWS, y1 - y0)
            out[y0 + r0:y0 + r1, x0:x1] = self._alpha_strip(r0, r1)[..., 0]
        return out

    def _edge_colour(self, r0: int, r1: int):
        """Where the matte is soft in the crop's rows r0:r1: (soft [r1 - r0, w] bool, the photo
        there [k, 3], the person's own colour there [k, 3]); None where it is nowhere soft. An
        edge pixel of the photo mixes the person with the background, which the albedo layer
        would otherwise carry into a composite over another background (relight.network.foreground)."""
        a = self._alpha_strip(r0, r1)[..., 0]
        soft = (a > 0.0) & (a < 1.0)
        if not soft.any():
            return None
        if self._smooth_prepared is None:
            self._smooth_prepared = self._up.prepare(smooth_colours(self.photo_working, self.alpha))
        ys, xs = np.nonzero(soft)
        y0, _, x0, _ = self.box
        photo = self.photo[y0 + r0 + ys, x0 + xs]
        return soft, photo, foreground(photo, a[soft][:, None], self._up.at(self._smooth_prepared, ys + r0, xs))

    def _full_out(self, out: np.ndarray | None, channels: tuple) -> np.ndarray:
        """A full-size float32 array [H, W, *channels], zero outside the crop (the crop is written
        next): `out` when given (checked), else a new one."""
        shape = (*self.size, *channels)
        if out is None:
            return np.zeros(shape, np.float32)
        if out.shape != shape or out.dtype != np.float32:
            raise ValueError(f"out must be float32 {shape}, got {out.dtype} {out.shape}")
        y0, y1, x0, x1 = self.box
        for c in range(channels[0]) if channels else [slice(None)]:
            o = out[..., c]  # channel by channel: a strided view's inner loops run along the rows
            o[:y0], o[y1:], o[y0:y1, :x0], o[y0:y1, x1:] = 0.0, 0.0, 0.0, 0.0
        return out

    def layers(self, coeffs=None, exposure_ev: float = 0.0) -> dict[str, np.ndarray]:
        """Full-resolution albedo, shading T . L', residual E . L' ([H, W, 3], zero
        outside the matte) and alpha [H, W]; L' is the SH light `coeffs`, or the
        photo's own light when None. albedo * shading + residual is the relit
        person before the clamp at 0 (the layers keep their sign: linear, for
        compositing). Where the crop was resized for the network, the albedo carries the
        photo's full-resolution texture by the same detail transfer as relight() (the
        shading and residual are smooth: upsampled), so the product is relight()'s person
        up to the order of upsampling, except where the matte is soft: there the albedo is
        the person's own colour (relight.network.foreground), without the background the photo's edge
        pixels mix in, so the layers composite over another background without its fringe."""
        L = self.exposed_light(self.light if coeffs is None else coeffs, exposure_ev)
        return {name: self._full_map(name, L) for name in LAYER_NAMES}

    def layer(self, name: str, coeffs=None, exposure_ev: float = 0.0, out: np.ndarray | None = None) -> np.ndarray:
        """One of layers() at full resolution, alone: a caller that packs each map as it comes
        holds one full-size map at a time (a 24 MP map is 288 MB). `out` ([H, W, 3], alpha
        [H, W], float32; a strided view too, e.g. channels of an RGBA buffer): written and
        returned instead of a new array, so such a caller holds none at all."""
        if name not in LAYER_NAMES:
            raise ValueError(f"layer must be one of {LAYER_NAMES}, got {name!r}")
        L = None if name in ("alpha", "albedo") else self.exposed_light(self.light if coeffs is None else coeffs,
                                                                         exposure_ev)
        return self._full_map(name, L, out)

    def _full_map(self, name: str, L: np.ndarray | None, out: np.ndarray | None = None) -> np.ndarray:
        """The layer `name` at full resolution under the exposed light L (None for the albedo and alpha)."""
        if name == "alpha":
            return self.full_alpha(out)
        if name == "albedo":
            if not self._up.identity:  # the photo's own detail, as relight() gives the relit person
                return self._albedo_detailed(out)
            values = self._albedo_m
        elif name == "residual" and not self._has_residual:  # black under every light: no upsampling
            if out is None:
                return np.zeros((*self.size, 3), np.float32)
            out = self._full_out(out, (3,))
            y0, y1, x0, x1 = self.box
            for c in range(3):
                out[y0:y1, x0:x1, c] = 0.0
            return out
        else:
            values = (self._transport_m if name == "shading" else self._residual_m) @ L
        h, w = self.working_size
        small = np.zeros((h * w, 3), np.float32)
        small[self._matte] = values
        return self._to_full(small.reshape(h, w, 3), out, edge_colour=name == "albedo")

    def shadow_layer(self, coeffs=None, exposure_ev: float = 0.0, out: np.ndarray | None = None) -> np.ndarray:
        """The share of the light's key each pixel sees past the person's body [H, W] at full resolution (1 where
        nothing blocks it, off the person, for a light without a directional part); the light as layer() takes it."""
        key = key_of(self.exposed_light(self.light if coeffs is None else coeffs, exposure_ev))
        h, w = self.working_size
        blocked = np.zeros((h, w, 1), np.float32)
        if key is not None:
            blocked[..., 0] = 1.0 - self.shadows.visibility(key)
        full = self._to_full(blocked, None if out is None else out[..., None])[..., 0]
        y0, y1, x0, x1 = self.box
        for r0 in range(0, y1 - y0, STRIP_ROWS):  # nothing is blocked where the full-resolution matte is 0
            r1 = min(r0 + STRIP_ROWS, y1 - y0)
            full[y0 + r0:y0 + r1, x0:x1][self._alpha_strip(r0, r1)[..., 0] <= 0.0] = 0.0
        np.subtract(1.0, full, out=full)
        return full

    @property
    def has_residual(self) -> bool:
        """False when the residual transport E is zero wherever the matte is (the geometry-first
        model has none): its layer is black under every light."""
        return self._has_residual

    def _albedo_detailed(self, out: np.ndarray | None = None) -> np.ndarray:
        """The albedo layer at full resolution with the photo's fine texture: the full-resolution
        photo times the upsampled quotient albedo / photo of working resolution (the detail
        transfer of relight(), so albedo x shading is the relit person as relight() gives it, up to
        the order of upsampling), capped like it and kept in [0, 1]."""
        h, w = self.working_size
        small = np.zeros((h * w, 3), np.float32)
        photo_m = self.photo_working.reshape(-1, 3)[self._matte]
        small[self._matte] = np.clip((self._albedo_m + DETAIL_EPS) / (photo_m + DETAIL_EPS), 0.0, DETAIL_MAX)
        return self._to_full(small.reshape(h, w, 3), out, times_photo=True)

    def _to_full(self, small: np.ndarray, out: np.ndarray | None = None, times_photo: bool = False,
                 edge_colour: bool = False) -> np.ndarray:
        """`small` [h, w, C] upsampled into the crop of a full-size array (zero outside it); with
        `times_photo`, multiplied by the photo + DETAIL_EPS there, the person's own colour
        (_edge_colour) standing in for the photo's where the matte is soft, and kept in [0, 1]
        (an albedo); with `edge_colour` (an albedo at the photo's own size), only the latter."""
        channels = small.shape[2]
        out = self._full_out(out, (channels,))
        packed = out.flags.c_contiguous
        prepared = self._up.prepare(small)
        y0, y1, x0, x1 = self.box
        eps = np.float32(DETAIL_EPS)
        for r0 in range(0, y1 - y0, STRIP_ROWS):
            r1 = min(r0 + STRIP_ROWS, y1 - y0)
            strip, target = self._up.strip(prepared, r0, r1), out[y0 + r0:y0 + r1, x0:x1]
            if times_photo or edge_colour:  # (at the photo's own size the strip is a view of
                if times_photo:              # `small`, this call's own array: changed in place)
                    strip *= self.photo[y0 + r0:y0 + r1, x0:x1] + eps
                edge = self._edge_colour(r0, r1)
                if edge is not None:  # the photo's colour there exchanged for the person's
                    soft, photo, person = edge
                    strip[soft] *= (person + eps) / (photo + eps)
                np.clip(strip, 0.0, 1.0, out=strip)
            for c in [slice(None)] if packed else range(channels):
                target[..., c] = strip[..., c]
        return out
