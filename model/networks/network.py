"""The relighting network (Lagunas et al. 2021, Section "Our Model").

A shared encoder feeds an albedo decoder, transport and residual decoders that
predict positive and negative parts (T = T+ - |T-|, E = E+ - |E-|), a light
decoder fed by the encoder bottleneck and the decoders' residual-block
features, and an alpha (matte) head. Only ONNX opset-17 ops are used: Conv,
BatchNormalization, Relu, Sigmoid, Abs, Resize (nearest), Concat, Slice,
ReduceMean, Gemm, Reshape.

The constructor's efficiency parameters (decoder_width, full_res_convs,
shared_parts, separable) default to the fast product model; PAPER_CONFIG sets
them to the heavy, paper-faithful layout. PRESETS names the shipped sizes
(measured in docs/benchmarks/model.md).
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

MAX_WIDTH_FACTOR = 8  # channels stop doubling after width * 8

# Architecture choices beyond width/depth, with the fast defaults. config()
# records every one of them, so a checkpoint never depends on today's defaults.
ARCH_DEFAULTS = {"decoder_width": 6, "full_res_convs": 1, "shared_parts": True, "separable": False}

# Heavy layout: decoders as wide as the encoder, two full-resolution convs per
# stage, one generator per positive / negative part (Lagunas et al. 2021).
PAPER_CONFIG = {"width": 32, "depth": 4, "decoder_width": None, "full_res_convs": 2,
                "shared_parts": False, "separable": False}

# Named product sizes; figures measured by benchmarks/bench_network.py
# (docs/benchmarks/model.md).
PRESETS = {
    "small": {"width": 8, "depth": 4, "decoder_width": 4, "full_res_convs": 1, "shared_parts": True},
    "default": {"width": 12, "depth": 4, "decoder_width": 6, "full_res_convs": 1, "shared_parts": True},
    "paper": PAPER_CONFIG,
}


def num_coeffs(order: int) -> int:
    return (order + 1) ** 2


def conv3x3(c_in: int, c_out: int, stride: int = 1, bias: bool = True, separable: bool = False) -> nn.Module:
    """3x3 convolution; `separable`: depthwise 3x3 then pointwise 1x1 (9/c_out + 1/9 of the cost)."""
    if separable and c_in > 3:
        return nn.Sequential(nn.Conv2d(c_in, c_in, 3, stride=stride, padding=1, groups=c_in, bias=False),
                             nn.Conv2d(c_in, c_out, 1, bias=bias))
    return nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=bias)


class ConvBlock(nn.Sequential):
    """3x3 convolution, optional BatchNorm, ReLU."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1, batch_norm: bool = True,
                 separable: bool = False):
        layers: list[nn.Module] = [
            conv3x3(c_in, c_out, stride=stride, bias=not batch_norm, separable=separable)
        ]
        if batch_norm:
            layers.append(nn.BatchNorm2d(c_out))
        layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)


class ResidualBlock(nn.Module):
    """ResNet-style block: x + conv(relu(conv(x)))."""

    def __init__(self, channels: int, batch_norm: bool, separable: bool = False):
        super().__init__()
        self.body = nn.Sequential(
            ConvBlock(channels, channels, batch_norm=batch_norm, separable=separable),
            conv3x3(channels, channels, bias=not batch_norm, separable=separable),
            *([nn.BatchNorm2d(channels)] if batch_norm else []),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.body(x))


class Encoder(nn.Module):
    """Stem of `full_res_convs` convs at full resolution, then `depth` stages halving it."""

    def __init__(self, channels: list[int], full_res_convs: int = 2, separable: bool = False, in_channels: int = 3):
        super().__init__()
        self.stem = nn.Sequential(ConvBlock(in_channels, channels[0]), *(
            ConvBlock(channels[0], channels[0], separable=separable) for _ in range(full_res_convs - 1)))
        self.stages = nn.ModuleList(
            nn.Sequential(ConvBlock(channels[i], channels[i + 1], stride=2, separable=separable),
                          ConvBlock(channels[i + 1], channels[i + 1], separable=separable))
            for i in range(len(channels) - 1)
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Features from full resolution down to the bottleneck (last)."""
        feats = [self.stem(x)]
        for stage in self.stages:
            feats.append(stage(feats[-1]))
        return feats


class Generator(nn.Module):
    """Upsamples the bottleneck by 2 per level, concatenating encoder skips ("C & Up").

    `channels`: encoder channels per level (skips, bottleneck last);
    `dec_channels`: this generator's output channels per level (default: the
    encoder's); the full-resolution stage has `full_res_convs` convs, the
    others two.
    """

    def __init__(self, channels: list[int], c_out: int, batch_norm: bool,
                 dec_channels: list[int] | None = None, full_res_convs: int = 2,
                 separable: bool = False):
        super().__init__()
        dec = list(dec_channels or channels)
        self.ups = nn.ModuleList()
        c_deep = channels[-1]
        for level in range(len(channels) - 1, 0, -1):
            c_skip, c_out_level = channels[level - 1], dec[level - 1]
            n_convs = full_res_convs if level == 1 else 2
            blocks = [ConvBlock(c_deep + c_skip, c_out_level, batch_norm=batch_norm, separable=separable)]
            blocks += [ConvBlock(c_out_level, c_out_level, batch_norm=batch_norm, separable=separable)
                       for _ in range(n_convs - 1)]
            self.ups.append(nn.Sequential(*blocks))
            c_deep = c_out_level
        self.out_channels = c_deep
        self.head = nn.Conv2d(c_deep, c_out, 1)

    def features(self, x: torch.Tensor, skips: list[torch.Tensor]) -> torch.Tensor:
        for up, skip in zip(self.ups, reversed(skips[:-1])):
            x = F.interpolate(x, scale_factor=2.0, mode="nearest")
            x = up(torch.cat([x, skip], dim=1))
        return x

    def forward(self, x: torch.Tensor, skips: list[torch.Tensor]) -> torch.Tensor:
        return self.head(self.features(x, skips))


class SignedDecoder(nn.Module):
    """Residual block + generator(s) for a signed coefficient map.

    With `decomposition`, the positive part and the magnitude of the negative
    part are predicted separately (both through abs, so both are >= 0 and
    always pass gradients): by two generators, or with `shared_parts` by one
    generator whose head has 2 x c_out channels (positive first). Otherwise
    one linear head predicts the signed map.
    """

    def __init__(self, channels: list[int], c_out: int, decomposition: bool,
                 dec_channels: list[int] | None = None, full_res_convs: int = 2,
                 shared_parts: bool = False, separable: bool = False):
        super().__init__()
        self.decomposition = decomposition
        self.shared_parts = decomposition and shared_parts
        self.c_out = c_out
        self.res_block = ResidualBlock(channels[-1], batch_norm=False, separable=separable)
        gen = dict(batch_norm=False, dec_channels=dec_channels, full_res_convs=full_res_convs,
                   separable=separable)
        if self.shared_parts:
            self.gen_parts = Generator(channels, 2 * c_out, **gen)
        else:
            self.gen_pos = Generator(channels, c_out, **gen)
            self.gen_neg = Generator(channels, c_out, **gen) if decomposition else None

    def forward(self, bottleneck: torch.Tensor, skips: list[torch.Tensor]):
        r = self.res_block(bottleneck)
        if self.shared_parts:
            parts = torch.abs(self.gen_parts(r, skips))
            pos, neg = parts[:, : self.c_out], parts[:, self.c_out:]
            return pos - neg, pos, neg, r
        if self.decomposition:
            pos = torch.abs(self.gen_pos(r, skips))
            neg = torch.abs(self.gen_neg(r, skips))
            return pos - neg, pos, neg, r
        signed = self.gen_pos(r, skips)
        return signed, F.relu(signed), F.relu(-signed), r


class LightDecoder(nn.Module):
    """Conv blocks halving resolution, global average pooling, FC to 3 x n (pos and neg)."""

    def __init__(self, c_in: int, c_hidden: int, n: int, decomposition: bool, halvings: int = 2,
                 separable: bool = False):
        super().__init__()
        self.n = n
        self.decomposition = decomposition
        blocks = []
        for i in range(halvings):
            blocks.append(ConvBlock(c_in if i == 0 else c_hidden, c_hidden, stride=2, batch_norm=False,
                                    separable=separable))
        self.convs = nn.Sequential(*blocks)
        self.fc = nn.Linear(c_hidden, 3 * n * (2 if decomposition else 1))

    def forward(self, x: torch.Tensor):
        pooled = self.convs(x).mean(dim=(2, 3))
        out = self.fc(pooled)
        if self.decomposition:
            pos = torch.abs(out[:, : 3 * self.n]).reshape(-1, self.n, 3)
            neg = torch.abs(out[:, 3 * self.n:]).reshape(-1, self.n, 3)
            return pos - neg, pos, neg
        signed = out.reshape(-1, self.n, 3)
        return signed, F.relu(signed), F.relu(-signed)


class RelightNet(nn.Module):
    """Single-image decomposition into albedo, transport T, residual E, light L, alpha.

    forward(image [B,3,H,W] in [-1,1]) -> dict of tensors (see docs/model.md).
    `tstar=True` is the paper's "T* = albedo*T + E" ablation: one map of
    3*n coefficients per pixel (index c*n + k), albedo fixed to 1, E to 0.

    Efficiency (defaults: the fast product layout; PAPER_CONFIG: the heavy one):
    `decoder_width`: the decoders' channels at full resolution, doubling per
    level like the encoder's (None: as wide as the encoder); `full_res_convs`:
    3x3 convs at full resolution in the encoder stem and each generator's last
    stage (1 or 2); `shared_parts`: one generator with a 2n-channel head
    predicts both T+ and |T-| (and E+, |E-|) instead of one generator each;
    `separable`: depthwise + pointwise convs instead of dense 3x3.
    """

    def __init__(self, sh_order: int = 4, width: int = 12, depth: int = 4,
                 with_residual: bool = True, with_matte: bool = True,
                 decomposition: bool = True, tstar: bool = False,
                 decoder_width: int | None = ARCH_DEFAULTS["decoder_width"],
                 full_res_convs: int = ARCH_DEFAULTS["full_res_convs"],
                 shared_parts: bool = ARCH_DEFAULTS["shared_parts"],
                 separable: bool = ARCH_DEFAULTS["separable"]):
        super().__init__()
        if sh_order < 0 or width < 1 or depth < 1:
            raise ValueError(f"RelightNet: need sh_order >= 0, width >= 1, depth >= 1 "
                             f"(got {sh_order}, {width}, {depth})")
        if decoder_width is not None and decoder_width < 1:
            raise ValueError(f"RelightNet: decoder_width must be >= 1 or None, got {decoder_width}")
        if full_res_convs not in (1, 2):
            raise ValueError(f"RelightNet: full_res_convs must be 1 or 2, got {full_res_convs}")
        self.sh_order = int(sh_order)
        self.width = int(width)
        self.depth = int(depth)
        self.with_residual = bool(with_residual) and not tstar
        self.with_matte = bool(with_matte)
        self.decomposition = bool(decomposition)
        self.tstar = bool(tstar)
        self.n = num_coeffs(self.sh_order)
        self.size_multiple = 2 ** self.depth
        self.decoder_width = None if decoder_width is None else int(decoder_width)
        self.full_res_convs = int(full_res_convs)
        self.shared_parts = bool(shared_parts)
        self.separable = bool(separable)

        channels = [self.width * min(2 ** i, MAX_WIDTH_FACTOR) for i in range(self.depth + 1)]
        dec = None
        if self.decoder_width is not None:
            dec = [self.decoder_width * min(2 ** i, MAX_WIDTH_FACTOR) for i in range(self.depth)]
        c_bottle = channels[-1]
        sep = self.separable
        self.encoder = Encoder(channels, self.full_res_convs, separable=sep)
        gen = dict(dec_channels=dec, full_res_convs=self.full_res_convs, separable=sep)
        n_t = 3 * self.n if self.tstar else self.n
        self.transport_decoder = SignedDecoder(channels, n_t, self.decomposition,
                                               shared_parts=self.shared_parts, **gen)
        light_in = 2 * c_bottle  # encoder bottleneck + transport res-block
        if not self.tstar:
            self.albedo_res = ResidualBlock(c_bottle, batch_norm=True, separable=sep)
            self.albedo_gen = Generator(channels, 3, batch_norm=True, **gen)
            light_in += c_bottle
        if self.with_residual:
            self.residual_decoder = SignedDecoder(channels, self.n, self.decomposition,
                                                  shared_parts=self.shared_parts, **gen)
            light_in += c_bottle
        if self.with_matte:
            if self.tstar:  # no albedo decoder to share: a generator of its own
                self.matte_res = ResidualBlock(c_bottle, batch_norm=True, separable=sep)
                self.matte_gen = Generator(channels, 1, batch_norm=True, **gen)
            else:
                # a 1x1 head on the albedo generator's full-resolution features: albedo is 0
                # off the person, so they already encode the silhouette; a separate
                # generator would cost 18 of 119 GFLOP at 256x256 (docs/benchmarks/model.md)
                self.matte_head = nn.Conv2d(self.albedo_gen.out_channels, 1, 1)
        self.light_decoder = LightDecoder(light_in, c_bottle, self.n, self.decomposition, separable=sep)

    def config(self) -> dict:
        """Constructor arguments that rebuild this network (RelightNet(**config))."""
        config = {"sh_order": self.sh_order, "width": self.width, "depth": self.depth,
                  "with_residual": self.with_residual, "with_matte": self.with_matte,
                  "decomposition": self.decomposition, "tstar": self.tstar}
        arch = {"decoder_width": self.decoder_width, "full_res_convs": self.full_res_convs,
                "shared_parts": self.shared_parts, "separable": self.separable}
        config.update(arch)
        return config

    def forward(self, image: torch.Tensor) -> dict[str, torch.Tensor]:
        feats = self.encoder(image)
        bottle = feats[-1]
        light_feats = [bottle]

        transport, t_pos, t_neg, t_res = self.transport_decoder(bottle, feats)
        light_feats.append(t_res)

        if self.tstar:
            albedo = torch.ones_like(image)
        else:
            a_res = self.albedo_res(bottle)
            light_feats.append(a_res)
            a_feats = self.albedo_gen.features(a_res, feats)
            albedo = torch.sigmoid(self.albedo_gen.head(a_feats))

        if self.with_residual:
            residual, e_pos, e_neg, e_res = self.residual_decoder(bottle, feats)
            light_feats.append(e_res)
        else:
            residual = torch.zeros_like(transport[:, : self.n])
            e_pos, e_neg = residual, residual

        if self.with_matte and self.tstar:
            alpha = torch.sigmoid(self.matte_gen(self.matte_res(bottle), feats))
        elif self.with_matte:
            alpha = torch.sigmoid(self.matte_head(a_feats))
        else:
            alpha = torch.ones_like(image[:, :1])

        light, l_pos, l_neg = self.light_decoder(torch.cat(light_feats, dim=1))
        return {
            "albedo": albedo, "transport": transport, "residual": residual,
            "light": light, "alpha": alpha,
            "transport_pos": t_pos, "transport_neg": t_neg,
            "residual_pos": e_pos, "residual_neg": e_neg,
            "light_pos": l_pos, "light_neg": l_neg,
        }

    def check_input(self, image: torch.Tensor) -> None:
        """Raise ValueError unless `image` is a finite [B,3,H,W] batch of the right size."""
        if image.ndim != 4 or image.shape[1] != 3:
            raise ValueError(f"RelightNet: image must be [B,3,H,W], got {tuple(image.shape)}")
        h, w = image.shape[-2:]
        if h % self.size_multiple or w % self.size_multiple:
            raise ValueError(f"RelightNet: H and W must be multiples of {self.size_multiple}, "
                             f"got {h}x{w}")
