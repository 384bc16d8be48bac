"""The geometry-first decomposition: learn normals, visibility, an albedo prior and a
light prior; derive transport, the photo's light and the albedo by physics.

    encoder -> geometry generator -> normal n (unit), visibility v, alpha
            -> albedo generator   -> albedo prior rho_p
            -> light head         -> light prior L_p (global pooling)
    T   = v * A_l / pi * Y_lm(n)                        (model.networks.physics.lobe_transport)
    L_a = ridge least squares of photo ~ rho_p * (T . L), toward L_p  (model.networks.physics.fit_light)
          (with fixed_level: rescaled to mean luminance 0.8, docs/conventions.md)
    rho = photo / max(T . L_a, reliable * its mean over the person)
    E   = 0

The outputs are the five of every relighting model (albedo, transport,
residual, light, alpha), so export, runtime, `relight image` and the add-on
are unchanged; `rho * (T . L')` with the photo-consistent rho is quotient
relighting, photo * (T . L') / (T . L_a). Extra outputs for the losses:
normal, visibility, albedo_prior, light_prior, light_fit (before the level).

The light's level, colour and direction all come from the fit, so the albedo
prior settles the photo's exposure and white balance (a single photo cannot
tell a bright light on a dark person from the reverse). `fixed_level` instead
rescales the fitted light to the training lights' reference radiance; measured
worse (docs/EVALUATION.md): the DC term is the part of the light that the
visible half of a body pins down least.
"""

from __future__ import annotations

import math

import torch
from torch import nn

from model.networks import physics
from model.networks.network import MAX_WIDTH_FACTOR, Encoder, Generator, LightDecoder, ResidualBlock, num_coeffs
from relight.network.prt import ALBEDO_RELIABLE  # the photo-consistent albedo's shading floor
from relight.lighting.sh import REFERENCE_LUMINANCE  # a light's solid-angle mean luminance (docs/conventions.md)

ARCH = "geometry"
CLIPPED = 0.99              # encoded input above this in any channel: saturated, not fitted

BODY_CHANNELS = 4  # the body prior's input channels: unit normal and coverage (model.samples.data.body_input)

# Named sizes of the geometry-first layout (docs/model.md); costs in docs/benchmarks/model.md.
GEOMETRY_PRESETS = {
    "geo-small": {"width": 8, "depth": 4, "decoder_width": 6},
    "geo-default": {"width": 12, "depth": 4, "decoder_width": 8},
    "geo-large": {"width": 20, "depth": 4, "decoder_width": 12},  # issue 45's width curve: Best's candidate
}


class GeometryNet(nn.Module):
    """Single-image decomposition with transport built from predicted geometry.

    forward(image [B,3,H,W] in [-1,1]) -> dict (module docstring).
    `ridge`: the light fit's pull toward the light head, relative to the data
    (model.networks.physics.fit_light); `reliable`: the fraction of its mean below which
    the shading is floored when the albedo is photo / shading. With `body_prior`
    the input carries 4 more channels after the photo's three: the unclothed body's
    unit normal and its coverage in [-1, 1] (model.samples.data.body_input).
    """

    arch = ARCH

    def __init__(self, sh_order: int = 4, width: int = 12, depth: int = 4, decoder_width: int = 8,
                 full_res_convs: int = 1, ridge: float = 0.1, reliable: float = ALBEDO_RELIABLE,
                 fixed_level: bool = False, body_prior: bool = False, fit_stride: int = 1,
                 front_facing: bool = False, depth_head: bool = False):
        super().__init__()
        if sh_order < 1 or width < 1 or depth < 1 or decoder_width < 1:
            raise ValueError(f"GeometryNet: need sh_order >= 1 and positive sizes (got {sh_order}, "
                             f"{width}, {depth}, {decoder_width})")
        if not (ridge > 0 and math.isfinite(ridge)):
            raise ValueError(f"GeometryNet: ridge must be > 0, got {ridge}")
        self.sh_order, self.width, self.depth = int(sh_order), int(width), int(depth)
        self.decoder_width, self.full_res_convs = int(decoder_width), int(full_res_convs)
        self.ridge, self.reliable, self.fixed_level = float(ridge), float(reliable), bool(fixed_level)
        self.body_prior = bool(body_prior)
        if isinstance(fit_stride, bool) or not isinstance(fit_stride, int) or not 1 <= fit_stride <= 4:
            raise ValueError(f"GeometryNet: fit_stride must be 1..4, got {fit_stride!r}")
        self.fit_stride = fit_stride
        self.front_facing = bool(front_facing)
        self.depth_head = bool(depth_head)
        # the fit's precision in training (the exported graph fits in float64); benchmarks set
        # float64 here to time what training was before (benchmarks/bench_train.py)
        self.train_fit_precision = torch.float32
        self.in_channels = 3 + (BODY_CHANNELS if self.body_prior else 0)
        self.n = num_coeffs(self.sh_order)
        self.size_multiple = 2 ** self.depth
        # the runtime and evaluation read these like RelightNet's
        self.tstar, self.decomposition, self.with_residual, self.with_matte = False, False, False, True
        channels = [self.width * min(2 ** i, MAX_WIDTH_FACTOR) for i in range(self.depth + 1)]
        dec = [self.decoder_width * min(2 ** i, MAX_WIDTH_FACTOR) for i in range(self.depth)]
        c_bottle = channels[-1]
        gen = dict(batch_norm=True, dec_channels=dec, full_res_convs=self.full_res_convs)
        self.encoder = Encoder(channels, self.full_res_convs, in_channels=self.in_channels)
        self.geometry_res = ResidualBlock(c_bottle, batch_norm=True)
        # normal xyz, visibility, alpha (+ depth: one more channel of the same generator, nearly free)
        self.geometry_gen = Generator(channels, 6 if self.depth_head else 5, **gen)
        self.albedo_res = ResidualBlock(c_bottle, batch_norm=True)
        self.albedo_gen = Generator(channels, 3, **gen)
        self.light_head = LightDecoder(3 * c_bottle, c_bottle, self.n, decomposition=False)

    def config(self) -> dict:
        config = {"arch": ARCH, "sh_order": self.sh_order, "width": self.width, "depth": self.depth,
                  "decoder_width": self.decoder_width, "full_res_convs": self.full_res_convs,
                  "ridge": self.ridge, "reliable": self.reliable, "fixed_level": self.fixed_level}
        if self.body_prior:  # absent when off: configs of models without it stay as they were
            config["body_prior"] = True
        if self.fit_stride != 1:
            config["fit_stride"] = self.fit_stride
        if self.front_facing:
            config["front_facing"] = True
        if self.depth_head:
            config["depth_head"] = True
        return config

    def check_input(self, image: torch.Tensor) -> None:
        if image.ndim != 4 or image.shape[1] != self.in_channels:
            raise ValueError(f"GeometryNet: image must be [B,{self.in_channels},H,W], got {tuple(image.shape)}")
        h, w = image.shape[-2:]
        if h % self.size_multiple or w % self.size_multiple:
            raise ValueError(f"GeometryNet: H and W must be multiples of {self.size_multiple}, got {h}x{w}")

    def forward(self, image: torch.Tensor) -> dict[str, torch.Tensor]:
        feats = self.encoder(image)
        image = image[:, :3]  # the photo; the body prior's channels only feed the encoder
        bottle = feats[-1]
        g_res = self.geometry_res(bottle)
        geo = self.geometry_gen(g_res, feats)
        raw_normal = geo[:, :3]
        if self.front_facing:
            # a surface the camera sees faces it (camera frame: the view axis is +Y), so its
            # normal's y is <= 0; without this, dark clothing in photos came out as surfaces
            # turned away from the camera (unlit) rather than as dark cloth
            raw_normal = torch.cat([raw_normal[:, :1], -torch.abs(raw_normal[:, 1:2]), raw_normal[:, 2:]], dim=1)
        normal = raw_normal / torch.sqrt((raw_normal * raw_normal).sum(dim=1, keepdim=True) + 1e-8)
        visibility = torch.sigmoid(geo[:, 3:4])
        alpha = torch.sigmoid(geo[:, 4:5])
        a_res = self.albedo_res(bottle)
        albedo_prior = torch.sigmoid(self.albedo_gen(a_res, feats))
        light_prior = self.light_head(torch.cat([bottle, g_res, a_res], dim=1))[0]

        transport = physics.lobe_transport(normal, visibility, self.sh_order)
        photo = physics.linear_from_network_input(image)
        # a step made of arithmetic: bool casts and zeros_like export as nodes that pin
        # float32 inside an fp16 graph (onnxconverter-common leaves their types alone)
        unclipped = ((2.0 * CLIPPED - 1.0 - image.max(dim=1, keepdim=True).values) * 1e6).clamp(0.0, 1.0)
        weight = alpha.detach() * unclipped
        # the light is fitted on every fit_stride-th pixel of each row and column: 25 unknowns
        # are as well pinned by a quarter of a crop's pixels, at a quarter of the cost; in
        # float32 while training (twice as fast; the exported graph fits in float64)
        s = self.fit_stride
        light_fit = physics.fit_light(transport[..., ::s, ::s], albedo_prior[..., ::s, ::s], photo[..., ::s, ::s],
                                      weight[..., ::s, ::s], light_prior, self.ridge,
                                      precision=self.train_fit_precision if self.training else torch.float64)
        light = light_fit
        if self.fixed_level:
            lum = mean_luminance(light_fit)
            # a fit with (almost) no light is an error, not a reason to amplify it 800x
            light = light_fit * (REFERENCE_LUMINANCE / lum.clamp(min=0.02))[:, None, None]
        shading = torch.einsum("bnhw,bnc->bchw", transport, light)
        albedo = physics.photo_consistent_albedo(photo, shading, weight, self.reliable)
        out = {
            "albedo": albedo, "transport": transport, "residual": transport * 0.0,
            "light": light, "alpha": alpha,
            "normal": normal, "visibility": visibility, "albedo_prior": albedo_prior,
            "light_prior": light_prior, "light_fit": light_fit,
        }
        if self.depth_head:
            # about the person's own mean (alpha-weighted): a single image has no absolute depth
            raw, a = geo[:, 5:6], alpha.detach()
            mean = (raw * a).sum(dim=(2, 3), keepdim=True) / (a.sum(dim=(2, 3), keepdim=True) + 1e-6)
            out["depth"] = raw - mean
        return out


def mean_luminance(light: torch.Tensor) -> torch.Tensor:
    """[B] solid-angle mean luminance of lights [B,n,3] (Rec.709 Y of the DC term)."""
    from relight.imaging.colour import LUMINANCE_WEIGHTS

    r, g, b = (float(w) for w in LUMINANCE_WEIGHTS)  # plain floats: constants in a traced graph
    dc = light[:, 0, :]
    return (dc[:, 0] * r + dc[:, 1] * g + dc[:, 2] * b) / (2.0 * math.sqrt(math.pi))


# Loss weights of geometry_losses (model.train --loss-weight NAME=VALUE changes one).
GEOMETRY_LOSS_WEIGHTS = {"normal": 1.0, "visibility": 1.0, "albedo": 1.0, "alpha": 1.0, "light": 0.2,
                         "transport": 1.0, "relight": 1.0, "reconstruction": 0.5, "light_fit": 0.0,
                         "depth": 1.0, "sun_response": 0.0}
FITTED_BANDS = 3  # light_fit compares bands 0-2: all a Lambertian lobe passes (band 3's A_l is 0, band 4's 0.04)


def geometry_losses(pred: dict, batch: dict, weights: dict | None = None) -> dict[str, torch.Tensor]:
    """Loss terms of the geometry-first model (weights: name -> factor; defaults below).

    normal: 1 - cos on the person; visibility: L1 against the baked T's DC ratio;
    albedo: L1 of the prior (linear, and of its square root, which weighs dark
    albedo as the eye does); alpha: L1 everywhere; light: L1 of the light head
    against the true input light; transport: L1 of the lobe T against the baked
    T (what the lobe cannot represent stays); relight: L1 of albedo * (T . L_b)
    against the target image under light b (through the fit: end to end);
    reconstruction: the same under the fitted light against the input image; light_fit: L1
    of the fitted light's bands 0-2 against the true input light's, in units of the true
    DC's luminance (the fit's answer itself, which relighting divides by; off by default);
    depth (models with the depth head): model.networks.depth_loss.ssi_depth_loss of the depth
    against the farm's depth pass, over the person's interior pixels; sun_response (off by
    default): model.networks.response_loss.sun_response_loss of the relit person under the batch's
    hard sun ("sun_light", drawn by the data when the weight is set) against the truth by PRT.
    """
    w = {**GEOMETRY_LOSS_WEIGHTS, **(weights or {})}
    mask = batch["alpha"]
    interior = (mask > 0.999).to(mask.dtype)

    def masked_mean(values, m):
        return (values * m).sum() / (m.sum() * values.shape[1] / m.shape[1]).clamp_min(1.0)

    terms = {}
    cos = (pred["normal"] * batch["normal"]).sum(dim=1, keepdim=True)
    terms["normal"] = masked_mean(1.0 - cos, interior)
    terms["visibility"] = masked_mean(torch.abs(pred["visibility"] - physics.visibility_from_transport(
        batch["transport"])), interior)
    gt_albedo = batch["albedo"]
    prior = pred["albedo_prior"]
    terms["albedo"] = masked_mean(torch.abs(prior - gt_albedo), interior) + masked_mean(
        torch.abs(torch.sqrt(prior + 1e-4) - torch.sqrt(gt_albedo + 1e-4)), interior)
    terms["alpha"] = torch.abs(pred["alpha"] - mask).mean()
    terms["light"] = torch.abs(pred["light_prior"] - batch["light"]).mean()
    if w.get("light_fit", 0.0):
        k = FITTED_BANDS * FITTED_BANDS
        level = mean_luminance(batch["light"]).clamp(min=1e-3)[:, None, None]
        terms["light_fit"] = (torch.abs(pred["light_fit"][:, :k] - batch["light"][:, :k]) / level).mean()
    terms["transport"] = masked_mean(torch.abs(pred["transport"] - batch["transport"]), interior)
    relit = pred["albedo"] * torch.einsum("bnhw,bnc->bchw", pred["transport"], batch["target_light"])
    terms["relight"] = masked_mean(torch.abs(relit - batch["target_image"]), interior)
    recon = pred["albedo"] * torch.einsum("bnhw,bnc->bchw", pred["transport"], pred["light"])
    terms["reconstruction"] = masked_mean(torch.abs(recon - batch["image"]), interior)
    if "depth" in pred:
        if "depth" not in batch:
            raise ValueError("the model has a depth head but the batch carries no depth (scenes need the "
                             "farm's depth pass; a pack made before issue 45's depth must be made again)")
        from model.networks.depth_loss import ssi_depth_loss

        terms["depth"] = ssi_depth_loss(pred["depth"], batch["depth"], interior * (batch["depth"] > 0))
    if w["sun_response"]:
        if "sun_light" not in batch:
            raise ValueError("the sun_response loss needs the batch's sun_light (model.train draws it "
                             "when --loss-weight sun_response=W is above 0)")
        from model.networks.response_loss import sun_response_loss

        sun = batch["sun_light"]
        relit_sun = pred["albedo"] * torch.einsum("bnhw,bnc->bchw", pred["transport"], sun)
        truth_sun = gt_albedo * torch.einsum("bnhw,bnc->bchw", batch["transport"], sun)
        terms["sun_response"] = sun_response_loss(relit_sun, truth_sun, interior)
    terms["total"] = sum(w[k] * v for k, v in terms.items())
    return terms
