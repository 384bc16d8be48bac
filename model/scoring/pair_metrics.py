"""The paper's metrics of one prediction on one evaluation pair (scene, light a -> light b),
and the rows that need no model: identity baselines and the ground-truth PRT oracle.

Arrays are channels first as model.samples.data.EvaluationPairs yields them; the metrics
(model.scoring.metrics) run channels last over the pair's metric weight.
"""

from __future__ import annotations

import numpy as np

from model.scoring import metrics
from relight.network.prt import render

MAPS = ("albedo", "shading", "image")
# "interior": fully covered pixels only (model.scoring.metrics.INTERIOR_ALPHA says why);
# "alpha": the GT alpha as the weight.
MASK_MODES = ("interior", "alpha")
INTERIOR_ALPHA = metrics.INTERIOR_ALPHA


def channels_last(x: np.ndarray) -> np.ndarray:
    """[C, H, W] -> [H, W, C], contiguous."""
    return np.ascontiguousarray(np.moveaxis(x, 0, -1))


def shading_np(transport: np.ndarray, light: np.ndarray, tstar: bool) -> np.ndarray:
    """T . L [H, W, 3] from transport [n or 3n, H, W] and light [n, 3]."""
    if tstar:
        n = light.shape[0]
        return np.einsum("cnhw,nc->hwc", transport.reshape(3, n, *transport.shape[1:]), light)
    return np.einsum("nhw,nc->hwc", transport, light)


def render_np(pred: dict, light: np.ndarray, tstar: bool) -> np.ndarray:
    """The relit image [H, W, 3] of one prediction (channels first) under `light`:
    relight.network.prt.render's albedo * (T . L) + E . L, or T* . L for the T* ablation."""
    if tstar:
        return shading_np(pred["transport"], light, True)
    return render(channels_last(pred["albedo"]), channels_last(pred["transport"]), channels_last(pred["residual"]), light)


def evaluate_prediction(pred: dict, sample: dict, tstar: bool) -> dict[str, dict[str, float]]:
    """Metrics of one prediction: {"reconstruction/albedo": {...}, "relighting/image": {...}, ...}."""
    mask = channels_last(metric_weight(sample))
    gt_albedo, gt_t = channels_last(sample["albedo"]), sample["transport"]
    out = {}
    for setting, light_pred, light_gt, image_gt in (
            ("reconstruction", pred["light"], sample["light"], sample["image"]),
            ("relighting", sample["target_light"], sample["target_light"], sample["target_image"])):
        if not tstar:
            out[f"{setting}/albedo"] = metrics.all_metrics(channels_last(pred["albedo"]), gt_albedo, mask)
            out[f"{setting}/shading"] = metrics.all_metrics(shading_np(pred["transport"], light_pred, False),
                                                            shading_np(gt_t, light_gt, False), mask)
        out[f"{setting}/image"] = metrics.all_metrics(render_np(pred, light_pred, tstar), channels_last(image_gt), mask)
    return out


def gain_fitted(pred: dict, sample: dict, tstar: bool) -> dict[str, dict[str, float]]:
    """Diagnostic: the prediction's albedo and relit image after per-channel gains fitted to the GT.

    Splits the error into a global colour / exposure part (which the gains
    remove, and which single-image relighting cannot fully know) and the rest.
    Uses the ground truth: a diagnostic row, never a method.
    """
    mask = channels_last(metric_weight(sample))
    out = {}
    relit, gt = render_np(pred, sample["target_light"], tstar), channels_last(sample["target_image"])
    out["relighting/image"] = metrics.all_metrics(relit * metrics.fit_channel_gains(relit, gt, mask), gt, mask)
    if not tstar:
        albedo, gt_albedo = channels_last(pred["albedo"]), channels_last(sample["albedo"])
        gains = metrics.fit_channel_gains(albedo, gt_albedo, mask)
        out["relighting/albedo"] = metrics.all_metrics(albedo * gains, gt_albedo, mask)
    return out


def exposure_ratio(light_a: np.ndarray, light_b: np.ndarray) -> np.ndarray:
    """Per-channel L00_b / L00_a (1 where L00_a is 0): exposure-matched identity's gain."""
    la, lb = light_a[0], light_b[0]
    return np.where(np.abs(la) > 1e-12, lb / np.where(np.abs(la) > 1e-12, la, 1.0), 1.0)


def baseline_identity(sample: dict, exposure_matched: bool) -> dict[str, dict[str, float]]:
    """The input image as the relit result (optionally scaled per channel by L00_b / L00_a)."""
    image = channels_last(sample["input_linear"])
    if exposure_matched:
        image = image * exposure_ratio(sample["light"], sample["target_light"])
    mask = channels_last(metric_weight(sample))
    return {"relighting/image": metrics.all_metrics(image, channels_last(sample["target_image"]), mask)}


def metric_weight(sample: dict) -> np.ndarray:
    """Per-pixel weight of the metrics: sample["metric_weight"] when set (evaluate), else the GT alpha."""
    return sample.get("metric_weight", sample["alpha"])


def with_metric_weight(sample: dict, mask: str) -> dict:
    if mask not in MASK_MODES:
        raise ValueError(f"mask must be one of {MASK_MODES}, got {mask!r}")
    alpha = np.asarray(sample["alpha"], np.float32)
    sample["metric_weight"] = metrics.interior_weight(alpha) if mask == "interior" else alpha
    return sample


def oracle_prt(sample: dict) -> dict[str, dict[str, float]]:
    """Ground-truth albedo * (T . L) at the data's SH order, no residual: the best any E-free PRT model can do.

    Its gap to the path-traced image is what the residual E has to learn
    (specular, interreflection, light above order N).
    """
    mask = channels_last(metric_weight(sample))
    out = {}
    for setting, light, image in (("reconstruction", sample["light"], sample["image"]),
                                  ("relighting", sample["target_light"], sample["target_image"])):
        prt = channels_last(sample["albedo"]) * shading_np(sample["transport"], light, False)
        out[f"{setting}/image"] = metrics.all_metrics(prt, channels_last(image), mask)
    return out
