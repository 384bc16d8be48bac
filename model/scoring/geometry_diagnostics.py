"""Geometry and light diagnostics of a prediction against the farm's buffers: normals and
visibility read off any model's T, the input light's error, how a turned light moves over
the person, and where the relit error comes from (parts swapped for the truth, physics
ceilings); the tables of docs/EVALUATION.md."""

from __future__ import annotations

import numpy as np

from model.scoring import metrics
from model.scoring.pair_metrics import channels_last, metric_weight, shading_np
from model.networks.physics import UNOCCLUDED_DC  # T_00 of an unoccluded white Lambertian point

QUOTIENT_FLOOR = 0.25  # model.networks.geometry's `reliable` default


def transport_normal(transport: np.ndarray) -> np.ndarray:
    """Unit band-1 direction of T [n, H, W] -> [H, W, 3]: the (bent) normal of a lobe
    (Y_{1,-1} ~ y, Y_{1,0} ~ z, Y_{1,1} ~ x); any model's T has one."""
    d = np.stack([transport[3], transport[1], transport[2]], axis=-1).astype(np.float64)
    return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)


def transport_visibility(transport: np.ndarray) -> np.ndarray:
    """T_00 relative to an unoccluded point, [H, W], clamped to [0, 1]."""
    return np.clip(transport[0] / UNOCCLUDED_DC, 0.0, 1.0)


MOTION_AZIMUTHS = (0.0, 180.0)  # a directional light turned half way round (relight.lighting.light.directional_light)


def light_motion(albedo: np.ndarray, transport: np.ndarray, residual: np.ndarray | None, weight: np.ndarray,
                 order: int) -> float:
    """metrics.spatial_change of albedo * (T . L) + E . L between a directional light at
    MOTION_AZIMUTHS[0] and [1]: how visibly a turned light moves over the person."""
    imgs = turned_light_images(albedo, transport, residual, order)
    return metrics.spatial_change(imgs[0], imgs[1], channels_last(weight))


def backlight_ratio(albedo: np.ndarray, transport: np.ndarray, residual: np.ndarray | None, weight: np.ndarray,
                    order: int) -> float:
    """metrics.luminance_ratio of the person lit from behind (MOTION_AZIMUTHS[1]) to lit from
    the camera's side ([0]): how much a light from behind darkens the front we see."""
    imgs = turned_light_images(albedo, transport, residual, order)
    return metrics.luminance_ratio(imgs[1], imgs[0], channels_last(weight))


def turned_light_images(albedo, transport, residual, order: int) -> list[np.ndarray]:
    """albedo * (T . L) + E . L (>= 0, channels last) under the directional light at each of MOTION_AZIMUTHS."""
    from relight.lighting.light import directional_light

    return [np.maximum(relit_np(albedo, transport, residual, directional_light(az, order)), 0.0)
            for az in MOTION_AZIMUTHS]


def relit_np(albedo, transport, residual, light) -> np.ndarray:
    """albedo * (T . L) + E . L, channels last, from channels-first maps (residual: None for none)."""
    img = channels_last(albedo) * shading_np(transport, light, False)
    if residual is not None:
        img = img + shading_np(residual, light, False)
    return img


def geometry_metrics(pred: dict, sample: dict) -> dict[str, float]:
    """Normal angle (degrees; from T's band 1, against the farm's normal pass),
    visibility L1 (T_00 ratio against the baked T's), and the input light's error
    (|L - L_true| / |L_true| over all coefficients) on the metric's pixels."""
    w = metric_weight(sample)[0] > 0.5
    if not w.any():
        return {}
    gt_n = channels_last(sample["normal"]).astype(np.float64)
    cos = np.clip((transport_normal(pred["transport"]) * gt_n).sum(-1), -1.0, 1.0)
    angle = np.degrees(np.arccos(cos))[w]
    vis = np.abs(transport_visibility(pred["transport"]) - transport_visibility(sample["transport"]))[w]
    light, true = np.asarray(pred["light"], np.float64), np.asarray(sample["light"], np.float64)
    order = int(round(np.sqrt(light.shape[0]))) - 1
    weight = metric_weight(sample)
    return {"normal_mean_deg": float(angle.mean()), "normal_median_deg": float(np.median(angle)),
            "visibility_l1": float(vis.mean()),
            "light_rel_l2": float(np.linalg.norm(light - true) / max(np.linalg.norm(true), 1e-12)),
            "light_colour_deg": metrics.colour_cast_deg(light[:1], true[:1]),
            "relit_level_stops": relit_level_stops(pred, sample),
            "light_motion": light_motion(pred["albedo"], pred["transport"], pred.get("residual"), weight, order),
            "light_motion_gt": light_motion(sample["albedo"], sample["transport"], None, weight, order),
            "backlight_ratio": backlight_ratio(pred["albedo"], pred["transport"], pred.get("residual"), weight, order),
            "backlight_ratio_gt": backlight_ratio(sample["albedo"], sample["transport"], None, weight, order)}


def relit_level_stops(pred: dict, sample: dict) -> float:
    """|log2| of the relit person's mean luminance over the target's (metric weight): how far
    its level is off, whatever its pattern."""
    from relight.imaging.colour import luminance

    w = channels_last(metric_weight(sample))[..., 0].astype(np.float64)
    relit = relit_np(pred["albedo"], pred["transport"], pred.get("residual"), sample["target_light"])
    relit = luminance(np.asarray(relit, np.float64))
    target = luminance(np.asarray(channels_last(sample["target_image"]), np.float64))
    ours, truth = float((w * relit).sum()), float((w * target).sum())
    return abs(float(np.log2(max(ours, 1e-12) / max(truth, 1e-12))))


TRUE_LIGHT_ROW = "ours with the true input light (quotient)"
BREAKDOWN_ROWS = (
    "true albedo x our shading",
    "our albedo x true shading",
    TRUE_LIGHT_ROW,
    "physics: quotient, true normals, true input light",
    "physics: true albedo x Lambert of true normals",
    "physics: true albedo x lobe of true normal and visibility",
)


def breakdown_images(pred: dict, sample: dict, order: int) -> dict[str, np.ndarray]:
    """The relit images [H, W, 3] of BREAKDOWN_ROWS, made once for error_breakdown's metrics and
    model.evaluate's light response (parts of the prediction replaced by the truth, and the
    physics ceilings):

    * true albedo x our shading; our albedo x true shading (T_gt . L_b);
    * ours with the true input light: quotient photo * (T . L_b) / (T . L_a,true);
    * quotient with true normals (unoccluded lobe) and the true input light;
    * true albedo x unoccluded Lambert of the true normals (order `order`);
    * true albedo x lobe of the true normal and visibility (the parametric ceiling).
    """
    from relight.network.prt import lambert_transport

    mask = channels_last(metric_weight(sample))
    photo = channels_last(sample["input_linear"])
    la, lb = sample["light"], sample["target_light"]
    albedo_gt = channels_last(sample["albedo"])
    normal_gt = channels_last(sample["normal"]).astype(np.float64)
    on = np.linalg.norm(normal_gt, axis=-1) > 0.5
    normal_gt = np.where(on[..., None], normal_gt, np.array([0.0, -1.0, 0.0]))
    lambert = np.moveaxis(lambert_transport(normal_gt, order), -1, 0)
    lobe = lambert * transport_visibility(sample["transport"])[None]

    def quotient(transport):
        # the input shading floored at a quarter of its mean over the person (as the
        # geometry-first model's reliability rule): where a lobe sees no light but the
        # photo does (interreflection), an unfloored ratio would explode
        shade_a = shading_np(transport, la, False)
        floor = QUOTIENT_FLOOR * max(float((shade_a * mask).sum() / max(mask.sum() * 3, 1e-8)), 1e-6)
        return photo * shading_np(transport, lb, False) / np.maximum(shade_a, floor)

    images = (
        albedo_gt * shading_np(pred["transport"], lb, False),
        channels_last(pred["albedo"]) * shading_np(sample["transport"], lb, False),
        quotient(pred["transport"]),
        quotient(lambert),
        albedo_gt * shading_np(lambert, lb, False),
        albedo_gt * shading_np(lobe, lb, False),
    )
    return dict(zip(BREAKDOWN_ROWS, images))


def error_breakdown(pred: dict, sample: dict, order: int,
                    images: dict | None = None) -> dict[str, dict[str, float]]:
    """Relit-image metrics of breakdown_images (`images`: its answer for this pair, when made
    already), the rows of docs/EVALUATION.md's breakdown table."""
    images = breakdown_images(pred, sample, order) if images is None else images
    mask = channels_last(metric_weight(sample))
    gt = channels_last(sample["target_image"])
    return {name: {"relighting/image": metrics.all_metrics(img, gt, mask)} for name, img in images.items()}


def parametric_transport_error(sample: dict, order: int) -> float:
    """|T_lobe(true n, true v) - T_baked| / |T_baked| on the metric's pixels."""
    from relight.network.prt import lambert_transport

    w = metric_weight(sample)[0] > 0.5
    normal_gt = channels_last(sample["normal"]).astype(np.float64)
    ok = w & (np.linalg.norm(normal_gt, axis=-1) > 0.5)
    if not ok.any():
        return float("nan")
    lobe = lambert_transport(normal_gt[ok], order) * transport_visibility(sample["transport"])[ok][:, None]
    baked = np.moveaxis(sample["transport"], 0, -1)[ok]
    return float(np.linalg.norm(lobe - baked) / max(np.linalg.norm(baked), 1e-12))


def geometry_table(results: dict[str, dict[str, float]], ceiling: float) -> str:
    lines = ["| method | normal mean (deg) | normal median (deg) | visibility L1 | input light rel. L2 | "
             "input light colour (deg) | relit level (stops) | "
             "light motion 0->180 deg (GT renders) | backlight ratio (GT renders) |",
             "|---|---|---|---|---|---|---|---|---|"]
    for method, m in results.items():
        lines.append(f"| {method} | {m['normal_mean_deg']:.1f} | {m['normal_median_deg']:.1f} | "
                     f"{m['visibility_l1']:.3f} | {m['light_rel_l2']:.3f} | "
                     f"{m['light_colour_deg']:.1f} | {m['relit_level_stops']:.2f} | "
                     f"{m['light_motion']:.3f} ({m['light_motion_gt']:.3f}) | "
                     f"{m['backlight_ratio']:.3f} ({m['backlight_ratio_gt']:.3f}) |")
    lines += ["", f"Parametric ceiling: the lobe of the true normal and visibility reproduces the baked T "
                  f"to a relative L2 error of {ceiling:.3f}.",
              "Light motion: model.scoring.metrics.spatial_change of the person relit by a directional light "
              "(relight.lighting.light.directional_light) at 0 and at 180 degrees, after per-channel gains; in brackets "
              "the same for the ground truth, albedo * (T . L) from the farm's buffers. Backlight ratio: "
              "model.scoring.metrics.luminance_ratio of the person lit from behind (180 degrees) to lit from the "
              "camera's side (0 degrees): how much a light from behind darkens the front we see. Input light "
              "colour: degrees between the estimated and the true input light's DC colour; relit level: "
              "|log2| of the relit person's mean luminance over the target's (means over the pairs)."]
    return "\n".join(lines) + "\n"
