"""Training losses (Lagunas et al. 2021, Section "Loss Functions"), plus matte and cross-light terms.

Every term is an unweighted scalar; `total` is the weighted sum with the
weights of `LossWeights`. Per-pixel terms are averaged over the person's
pixels, weighted by the ground-truth alpha (coverage), so the background never
drives albedo/transport/shading; the matte term covers every pixel.

Terms (names as returned by `relight_losses`):
  albedo      L1(rho, rho_gt)
  transport   L1(T), L1(T+, relu(T_gt)), L1(|T-|, relu(-T_gt))
  light       L1(L), L1(L+, relu(L_gt)), L1(|L-|, relu(-L_gt))   (over coefficients)
  log         squared log loss (log(|x|+1) - log(|x_gt|+1))^2 on T, T+-, L, L+-
  shading     L1(T_a . L_b, S_gt) for every (a, b) in {pred, gt}^2 except (gt, gt)
  image       L1(rho_a (T_b . L_c) + E . L_c, I_gt) for all (a, b, c) in {pred, gt}^3
              (E is always predicted: it has no ground truth)
  matte       L1(alpha, alpha_gt) over all pixels
  relight     L1(rho (T . L'_gt) + E . L'_gt, I'_gt): same scene, another light
"""

from __future__ import annotations

import itertools
from dataclasses import asdict, dataclass, fields

import torch
from torch.nn import functional as F

from model.networks import sh_torch

EPS = 1e-8  # keeps the masked mean finite when a crop holds no person pixels


@dataclass
class LossWeights:
    albedo: float = 1.0
    transport: float = 1.0
    light: float = 1.0
    log: float = 1.0
    shading: float = 1.0
    image: float = 1.0
    matte: float = 1.0
    relight: float = 1.0

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, d: dict) -> "LossWeights":
        names = {f.name for f in fields(cls)}
        unknown = set(d) - names
        if unknown:
            raise ValueError(f"unknown loss weights: {sorted(unknown)} (known: {sorted(names)})")
        return cls(**{k: float(v) for k, v in d.items()})


def masked_l1(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    """sum(w |pred - target|) / (sum(w) * C): mean absolute error over weighted pixels."""
    c = pred.shape[1]
    w = weight.expand_as(pred[:, :1])
    return (torch.abs(pred - target) * w).sum() / (w.sum() * c + EPS)


def masked_mean(values: torch.Tensor, weight: torch.Tensor) -> torch.Tensor:
    c = values.shape[1]
    w = weight.expand_as(values[:, :1])
    return (values * w).sum() / (w.sum() * c + EPS)


def log_compress(x: torch.Tensor) -> torch.Tensor:
    """log(|x| + 1): compresses the unbounded range of T and L (log1p keeps it exact near 0)."""
    return torch.log1p(torch.abs(x))


def log_loss(pred: torch.Tensor, target: torch.Tensor, weight: torch.Tensor | None = None) -> torch.Tensor:
    """Mean of (log(|x|+1) - log(|x_gt|+1))^2, masked per pixel when `weight` is given."""
    sq = (log_compress(pred) - log_compress(target)) ** 2
    return sq.mean() if weight is None else masked_mean(sq, weight)


def _parts(x: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    return F.relu(x), F.relu(-x)


def relight_losses(pred: dict, batch: dict, weights: LossWeights, *, decomposition: bool = True,
                   tstar: bool = False) -> dict[str, torch.Tensor]:
    """All loss terms and their weighted `total`.

    pred: RelightNet output. batch: "albedo" [B,3,H,W], "transport" [B,n,H,W],
    "light" [B,n,3], "alpha" [B,1,H,W], "image" [B,3,H,W] (linear radiance of
    the input), and "target_light" [B,n,3], "target_image" [B,3,H,W] for the
    cross-light term. `decomposition=False` drops the positive/negative part
    terms (the network has no parts); `tstar` supervises T* = rho_gt * T_gt.
    """
    w = batch["alpha"]
    t_gt, l_gt, rho_gt, img_gt = batch["transport"], batch["light"], batch["albedo"], batch["image"]
    t_pred, l_pred, e_pred = pred["transport"], pred["light"], pred["residual"]
    zero = t_pred.new_zeros(())
    terms: dict[str, torch.Tensor] = {}

    if tstar:
        b, n, h, wd = t_gt.shape
        t_gt = (rho_gt[:, :, None] * t_gt[:, None]).reshape(b, 3 * n, h, wd)
        terms["albedo"] = zero
    else:
        terms["albedo"] = masked_l1(pred["albedo"], rho_gt, w)

    t_gt_pos, t_gt_neg = _parts(t_gt)
    l_gt_pos, l_gt_neg = _parts(l_gt)
    terms["transport"] = masked_l1(t_pred, t_gt, w)
    terms["light"] = torch.abs(l_pred - l_gt).mean()
    terms["log"] = log_loss(t_pred, t_gt, w) + log_loss(l_pred, l_gt)
    if decomposition:
        terms["transport"] = (terms["transport"] + masked_l1(pred["transport_pos"], t_gt_pos, w)
                              + masked_l1(pred["transport_neg"], t_gt_neg, w))
        terms["light"] = (terms["light"] + torch.abs(pred["light_pos"] - l_gt_pos).mean()
                          + torch.abs(pred["light_neg"] - l_gt_neg).mean())
        terms["log"] = (terms["log"]
                        + log_loss(pred["transport_pos"], t_gt_pos, w)
                        + log_loss(pred["transport_neg"], t_gt_neg, w)
                        + log_loss(pred["light_pos"], l_gt_pos)
                        + log_loss(pred["light_neg"], l_gt_neg))

    if tstar:
        # T*.L is the whole image: shading terms fold into the image terms
        terms["shading"] = zero
        image_terms = [masked_l1(sh_torch.shading_tstar(t, l), img_gt, w)
                       for t, l in itertools.product((t_pred, t_gt), (l_pred, l_gt))]
        terms["image"] = torch.stack(image_terms).sum()
        relit = sh_torch.shading_tstar(t_pred, batch["target_light"])
    else:
        s_gt = sh_torch.shading(t_gt, l_gt)
        shading_terms = [masked_l1(sh_torch.shading(t, l), s_gt, w)
                         for t, l in itertools.product((t_pred, t_gt), (l_pred, l_gt))
                         if not (t is t_gt and l is l_gt)]
        terms["shading"] = torch.stack(shading_terms).sum()
        image_terms = [masked_l1(sh_torch.render(rho, t, e_pred, l), img_gt, w)
                       for rho, t, l in itertools.product((pred["albedo"], rho_gt), (t_pred, t_gt),
                                                          (l_pred, l_gt))]
        terms["image"] = torch.stack(image_terms).sum()
        relit = sh_torch.render(pred["albedo"], t_pred, e_pred, batch["target_light"])

    terms["matte"] = torch.abs(pred["alpha"] - w).mean()
    terms["relight"] = masked_l1(relit, batch["target_image"], w)

    weight_of = weights.to_dict()
    terms["total"] = sum(weight_of[name] * value for name, value in terms.items())
    return terms
