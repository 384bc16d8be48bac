"""The relighting network (Lagunas et al. 2021, Section "Our Model").

A shared encoder feeds an albedo decoder, transport and residual decoders that
predict positive and negative parts (T = T+ - |T-|, E = E+ - |E-|), a light
decoder fed by the encoder bottleneck and the decoders' residual-block
features, and an alpha (matte) head. Only ONNX opset-17 ops are used: Conv,
BatchNormalization, Relu, Sigmoid, Abs, Resize (nearest), Concat, ReduceMean,
Gemm, Reshape.
"""

from __future__ import annotations

import torch
from torch import nn
from torch.nn import functional as F

MAX_WIDTH_FACTOR = 8  # channels stop doubling after width * 8


def num_coeffs(order: int) -> int:
    return (order + 1) ** 2


class ConvBlock(nn.Sequential):
    """3x3 convolution, optional BatchNorm, ReLU."""

    def __init__(self, c_in: int, c_out: int, stride: int = 1, batch_norm: bool = True):
        layers: list[nn.Module] = [
            nn.Conv2d(c_in, c_out, 3, stride=stride, padding=1, bias=not batch_norm)
        ]
        if batch_norm:
            layers.append(nn.BatchNorm2d(c_out))
        layers.append(nn.ReLU(inplace=True))
        super().__init__(*layers)


class ResidualBlock(nn.Module):
    """ResNet-style block: x + conv(relu(conv(x)))."""

    def __init__(self, channels: int, batch_norm: bool):
        super().__init__()
        self.body = nn.Sequential(
            ConvBlock(channels, channels, batch_norm=batch_norm),
            nn.Conv2d(channels, channels, 3, padding=1, bias=not batch_norm),
            *([nn.BatchNorm2d(channels)] if batch_norm else []),
        )

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return F.relu(x + self.body(x))


class Encoder(nn.Module):
    """Stem at full resolution, then `depth` stages that halve the resolution."""

    def __init__(self, channels: list[int]):
        super().__init__()
        self.stem = nn.Sequential(ConvBlock(3, channels[0]), ConvBlock(channels[0], channels[0]))
        self.stages = nn.ModuleList(
            nn.Sequential(ConvBlock(channels[i], channels[i + 1], stride=2),
                          ConvBlock(channels[i + 1], channels[i + 1]))
            for i in range(len(channels) - 1)
        )

    def forward(self, x: torch.Tensor) -> list[torch.Tensor]:
        """Features from full resolution down to the bottleneck (last)."""
        feats = [self.stem(x)]
        for stage in self.stages:
            feats.append(stage(feats[-1]))
        return feats


class Generator(nn.Module):
    """Upsamples the bottleneck by 2 per level, concatenating encoder skips ("C & Up")."""

    def __init__(self, channels: list[int], c_out: int, batch_norm: bool):
        super().__init__()
        self.ups = nn.ModuleList()
        for level in range(len(channels) - 1, 0, -1):
            c_deep, c_skip = channels[level], channels[level - 1]
            self.ups.append(nn.Sequential(ConvBlock(c_deep + c_skip, c_skip, batch_norm=batch_norm),
                                          ConvBlock(c_skip, c_skip, batch_norm=batch_norm)))
        self.head = nn.Conv2d(channels[0], c_out, 1)

    def features(self, x: torch.Tensor, skips: list[torch.Tensor]) -> torch.Tensor:
        for up, skip in zip(self.ups, reversed(skips[:-1])):
            x = F.interpolate(x, scale_factor=2.0, mode="nearest")
            x = up(torch.cat([x, skip], dim=1))
        return x

    def forward(self, x: torch.Tensor, skips: list[torch.Tensor]) -> torch.Tensor:
        return self.head(self.features(x, skips))


class SignedDecoder(nn.Module):
    """Residual block + generator(s) for a signed coefficient map.

    With `decomposition`, two generators predict the positive part and the
    magnitude of the negative part (both through abs, so both are >= 0 and
    always pass gradients); otherwise one linear head predicts the signed map.
    """

    def __init__(self, channels: list[int], c_out: int, decomposition: bool):
        super().__init__()
        self.decomposition = decomposition
        self.res_block = ResidualBlock(channels[-1], batch_norm=False)
        self.gen_pos = Generator(channels, c_out, batch_norm=False)
        self.gen_neg = Generator(channels, c_out, batch_norm=False) if decomposition else None

    def forward(self, bottleneck: torch.Tensor, skips: list[torch.Tensor]):
        r = self.res_block(bottleneck)
        if self.decomposition:
            pos = torch.abs(self.gen_pos(r, skips))
            neg = torch.abs(self.gen_neg(r, skips))
            return pos - neg, pos, neg, r
        signed = self.gen_pos(r, skips)
        return signed, F.relu(signed), F.relu(-signed), r


class LightDecoder(nn.Module):
    """Conv blocks halving resolution, global average pooling, FC to 3 x n (pos and neg)."""

    def __init__(self, c_in: int, c_hidden: int, n: int, decomposition: bool, halvings: int = 2):
        super().__init__()
        self.n = n
        self.decomposition = decomposition
        blocks = []
        for i in range(halvings):
            blocks.append(ConvBlock(c_in if i == 0 else c_hidden, c_hidden, stride=2, batch_norm=False))
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
    """

    def __init__(self, sh_order: int = 4, width: int = 32, depth: int = 4,
                 with_residual: bool = True, with_matte: bool = True,
                 decomposition: bool = True, tstar: bool = False):
        super().__init__()
        if sh_order < 0 or width < 1 or depth < 1:
            raise ValueError(f"RelightNet: need sh_order >= 0, width >= 1, depth >= 1 "
                             f"(got {sh_order}, {width}, {depth})")
        self.sh_order = int(sh_order)
        self.width = int(width)
        self.depth = int(depth)
        self.with_residual = bool(with_residual) and not tstar
        self.with_matte = bool(with_matte)
        self.decomposition = bool(decomposition)
        self.tstar = bool(tstar)
        self.n = num_coeffs(self.sh_order)
        self.size_multiple = 2 ** self.depth

        channels = [self.width * min(2 ** i, MAX_WIDTH_FACTOR) for i in range(self.depth + 1)]
        c_bottle = channels[-1]
        self.encoder = Encoder(channels)
        n_t = 3 * self.n if self.tstar else self.n
        self.transport_decoder = SignedDecoder(channels, n_t, self.decomposition)
        light_in = 2 * c_bottle  # encoder bottleneck + transport res-block
        if not self.tstar:
            self.albedo_res = ResidualBlock(c_bottle, batch_norm=True)
            self.albedo_gen = Generator(channels, 3, batch_norm=True)
            light_in += c_bottle
        if self.with_residual:
            self.residual_decoder = SignedDecoder(channels, self.n, self.decomposition)
            light_in += c_bottle
        if self.with_matte:
            if self.tstar:  # no albedo decoder to share: a generator of its own
                self.matte_res = ResidualBlock(c_bottle, batch_norm=True)
                self.matte_gen = Generator(channels, 1, batch_norm=True)
            else:
                # a 1x1 head on the albedo generator's full-resolution features: albedo is 0
                # off the person, so they already encode the silhouette; a separate
                # generator would cost 18 of 119 GFLOP at 256x256 (docs/benchmarks/model.md)
                self.matte_head = nn.Conv2d(channels[0], 1, 1)
        self.light_decoder = LightDecoder(light_in, c_bottle, self.n, self.decomposition)

    def config(self) -> dict:
        return {"sh_order": self.sh_order, "width": self.width, "depth": self.depth,
                "with_residual": self.with_residual, "with_matte": self.with_matte,
                "decomposition": self.decomposition, "tstar": self.tstar}

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
