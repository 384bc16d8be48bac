"""Photo-like capture for training inputs: real backgrounds, white balance, exposure, blur, noise, JPEG.

A training input is a rendered person composited over a background. Real
photos differ in ways the network otherwise reads as light, so
`photo_like` turns the composite into what a camera would have delivered:

1. background (probability BACKGROUND_P): a perspective view cut from a
   real photograph, the CC0 Poly Haven HDR panoramas bundled in
   relight/data/hdri (LICENSE.md there; held-out maps excluded), at a random
   yaw, a pitch of +-15 degrees and a 45-90 degree field of view, exposed
   relative to the person by 2^N(0, 0.7^2);
2. white balance and exposure: per-channel gains (a colour-temperature-like
   red/blue tilt of luminance 1, times 2^N(0, 0.35^2)) applied to the whole
   photo *and* to the input light and its image, so the targets stay exact
   (radiance is linear in the light, per channel);
3. optical blur: a Gaussian of sigma 0-1.2 px;
4. sensor noise: Poisson-Gaussian in linear values, variance a*x + b;
5. JPEG at quality 35-95 (Pillow, 4:2:0), decoded back to linear.

Steps 3-5 degrade the input only; the albedo, transport and light targets
are untouched. Every parameter is drawn from the generator it is given
(model.samples.data passes default_rng([seed, epoch, index, 20])), so a sample is
reproducible, and `CaptureParams.as_dict` records them.
"""

from __future__ import annotations

import functools
import io
import math
from dataclasses import asdict, dataclass, field

import numpy as np

from relight.imaging.colour import luminance, srgb_decode, srgb_encode

BACKGROUND_P = 0.5
PITCH_DEG = 15.0
FOV_DEG = (45.0, 90.0)
WB_SIGMA = 0.12  # log red/blue tilt
EXPOSURE_SIGMA = 0.35  # stops
BLUR_MAX = 1.2  # px
SHOT_MAX = 5e-4  # linear variance per unit signal
READ_MAX = 4e-6  # linear variance floor
JPEG_QUALITY = (35, 95)
LICENCES = {"hdri": "CC0-1.0, Poly Haven via @pmndrs/assets 1.7.0 (relight/data/hdri/LICENSE.md)"}


@dataclass
class CaptureParams:
    background: dict | None  # {"map", "yaw_deg", "pitch_deg", "fov_deg", "relative_ev"} or None (kept)
    gains: list[float]  # white balance x exposure, per channel (applied to photo, light and image)
    white_balance: list[float]
    exposure_ev: float
    blur_px: float
    shot: float
    read: float
    jpeg_quality: int
    extra: dict = field(default_factory=dict)

    def as_dict(self) -> dict:
        return asdict(self)


@functools.lru_cache(maxsize=1)
def background_maps() -> tuple[str, ...]:
    from relight.lighting import presets

    return tuple(n for n in presets.training_presets() if n not in presets.HELD_OUT)


@functools.lru_cache(maxsize=32)
def _map_pixels(name: str) -> np.ndarray:
    from relight.lighting import presets
    from relight.lighting.envmap import load_equirect

    return np.asarray(load_equirect(presets.preset_path(name)).pixels, dtype=np.float32)


def sample_params(rng: np.random.Generator, background_p: float = BACKGROUND_P) -> CaptureParams:
    background = None
    if rng.uniform() < background_p:
        maps = background_maps()
        background = {
            "map": str(maps[int(rng.integers(len(maps)))]),
            "yaw_deg": float(rng.uniform(0.0, 360.0)),
            "pitch_deg": float(rng.uniform(-PITCH_DEG, PITCH_DEG)),
            "fov_deg": float(rng.uniform(*FOV_DEG)),
            "relative_ev": float(rng.normal(0.0, 0.7)),
        }
    tilt = rng.normal(0.0, WB_SIGMA)
    wb = np.exp(np.array([tilt, rng.normal(0.0, 0.03), -tilt + rng.normal(0.0, 0.04)]))
    wb = wb / float(luminance(wb))  # luminance 1: exposure is separate
    ev = float(rng.normal(0.0, EXPOSURE_SIGMA))
    return CaptureParams(
        background=background,
        gains=[float(g) for g in wb * 2.0**ev],
        white_balance=[float(g) for g in wb],
        exposure_ev=ev,
        blur_px=float(rng.uniform(0.0, BLUR_MAX)),
        shot=float(rng.uniform(0.0, SHOT_MAX)),
        read=float(rng.uniform(0.0, READ_MAX)),
        jpeg_quality=int(rng.integers(JPEG_QUALITY[0], JPEG_QUALITY[1] + 1)),
    )


def perspective_view(pixels: np.ndarray, yaw_deg: float, pitch_deg: float, fov_deg: float, size: int) -> np.ndarray:
    """A size x size pinhole view [3, S, S] of an equirect map [H, W, 3] (bilinear, longitude wraps).

    Longitude runs with the column (u = 0.5 + phi / 2 pi), latitude with the
    row (the top row looks straight up); yaw turns the view about the
    vertical, pitch tilts it up.
    """
    h, w = pixels.shape[:2]
    f = 0.5 / math.tan(math.radians(fov_deg) / 2)
    s = (np.arange(size) + 0.5) / size - 0.5
    xx, yy = np.meshgrid(s, -s)  # x right, y up
    d = np.stack([xx, yy, np.full_like(xx, f)], -1)  # camera looks along +z
    p, yw = math.radians(pitch_deg), math.radians(yaw_deg)
    rx = np.array([[1, 0, 0], [0, math.cos(p), math.sin(p)], [0, -math.sin(p), math.cos(p)]])
    ry = np.array([[math.cos(yw), 0, math.sin(yw)], [0, 1, 0], [-math.sin(yw), 0, math.cos(yw)]])
    d = d @ (ry @ rx).T
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    phi = np.arctan2(d[..., 0], d[..., 2])
    theta = np.arccos(np.clip(d[..., 1], -1.0, 1.0))
    u = (0.5 + phi / (2 * math.pi)) * w - 0.5
    v = np.clip(theta / math.pi * h - 0.5, 0.0, h - 1.0)
    u0 = np.floor(u).astype(np.int64)
    v0 = np.minimum(np.floor(v).astype(np.int64), h - 2)
    fu, fv = (u - u0)[..., None], (v - v0)[..., None]
    u0 %= w
    u1 = (u0 + 1) % w
    out = ((1 - fv) * ((1 - fu) * pixels[v0, u0] + fu * pixels[v0, u1])
           + fv * ((1 - fu) * pixels[v0 + 1, u0] + fu * pixels[v0 + 1, u1]))
    return out.transpose(2, 0, 1).astype(np.float32)


def gaussian_blur(chw: np.ndarray, sigma: float) -> np.ndarray:
    """Separable Gaussian (edge-replicated) of [C, H, W]; sigma < 0.05 px returns the input."""
    if sigma < 0.05:
        return chw
    r = max(1, int(math.ceil(3 * sigma)))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    out = np.pad(chw, ((0, 0), (r, r), (0, 0)), mode="edge")
    out = sum(k[i] * out[:, i : i + chw.shape[1]] for i in range(2 * r + 1))
    out = np.pad(out, ((0, 0), (0, 0), (r, r)), mode="edge")
    out = sum(k[i] * out[:, :, i : i + chw.shape[2]] for i in range(2 * r + 1))
    return out.astype(np.float32)


def jpeg_roundtrip(linear_chw: np.ndarray, quality: int) -> np.ndarray:
    """Linear [3, H, W] through 8-bit sRGB JPEG and back to linear."""
    from PIL import Image

    srgb = np.clip(srgb_encode(np.clip(linear_chw, 0.0, None).transpose(1, 2, 0)), 0.0, 1.0)
    buf = io.BytesIO()
    Image.fromarray(np.round(srgb * 255).astype(np.uint8)).save(buf, format="JPEG", quality=int(quality))
    buf.seek(0)
    decoded = np.asarray(Image.open(buf).convert("RGB"), dtype=np.float32) / 255.0
    return srgb_decode(decoded).transpose(2, 0, 1).astype(np.float32)


def photo_like(composite: np.ndarray, image: np.ndarray, alpha: np.ndarray, light: np.ndarray,
               rng: np.random.Generator, params: CaptureParams | None = None):
    """(composite, image, light, params): the composite as a camera would deliver it.

    composite, image: linear [3, S, S] (the person over its background, and
    the person's own render); alpha [1, S, S]; light [n, 3] SH. The image and
    the light get the same white-balance and exposure gains as the photo, so
    image == albedo * (T . light) still holds where it held.
    """
    p = sample_params(rng) if params is None else params
    size = composite.shape[-1]
    if p.background is not None:
        b = p.background
        view = perspective_view(_map_pixels(b["map"]), b["yaw_deg"], b["pitch_deg"], b["fov_deg"], size)
        person = float((image * alpha).sum() / max(float(alpha.sum()) * 3, 1e-6))
        level = float(np.mean(view)) + 1e-6
        view = view * (max(person, 0.02) / level * 2.0 ** b["relative_ev"])
        composite = alpha * image + (1 - alpha) * view
    gains = np.asarray(p.gains, dtype=np.float32)
    composite = composite * gains[:, None, None]
    image = image * gains[:, None, None]
    light = light * gains[None, :].astype(light.dtype)
    out = gaussian_blur(composite, p.blur_px)
    x = np.clip(out, 0.0, None)
    out = x + np.sqrt(p.shot * x + p.read) * rng.standard_normal(x.shape).astype(np.float32)
    out = jpeg_roundtrip(out, p.jpeg_quality)
    return out.astype(np.float32), image.astype(np.float32), light, p
