"""Evaluate a model on scene files: `python -m model.evaluate MODEL --data DIR [--out DIR]`.

MODEL is a .safetensors checkpoint (model.checkpoint) or an .onnx file (run
with onnxruntime, I/O of docs/ARCHITECTURE.md: input "image", outputs
"albedo", "transport", "residual", "light", "alpha"). For every pair
(scene, light a -> light b) of path-traced images the paper's metrics are
measured over the person's pixels (model.metrics): albedo, shading and image
L1 (x100), L2 (x100), PSNR, for (a) reconstruction under the predicted light
and (b) relighting to light b vs the path-traced image under b. Baselines in
the same run: identity (input as output), exposure-matched identity (input
scaled per channel by L00_b / L00_a), and every --baseline [NAME=]MODEL
(repeatable: e.g. the small model and a Kanamori-Endo-style model trained
with --lambertian --order 2), all rows of one table.
Writes OUT/evaluation.md, OUT/evaluation.json, OUT/contact_sheet.png.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

from relight.sheet import contact_sheet as _contact_sheet
from relight.sheet import write_sheet
from relight.fileio import atomic_write_text
from relight.prt import render

from model import metrics
from model.data import EvaluationPairs, find_scenes, held_out_light_names
from model.physics import UNOCCLUDED_DC  # T_00 of an unoccluded white Lambertian point

MAPS = ("albedo", "shading", "image")
OUTPUTS = ("albedo", "transport", "residual", "light", "alpha")


class Predictor:
    """Runs a checkpoint (torch, eval mode) or an ONNX file on [B,3,H,W] float32 inputs.

    An ONNX file opens through relight.session.ModelSession, as in the runtime: its
    SHA-256 (registry or .sha256 file beside it), metadata and graph names are checked."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        if not self.path.is_file():
            raise ValueError(f"model not found: {self.path}")
        if self.path.suffix == ".onnx":
            from relight.session import ModelSession
            from relight.sh import num_coeffs

            self.session = ModelSession(self.path)
            self.n_coeffs = num_coeffs(self.session.sh_order)
            t = self.session.output_channels("transport")
            # the T* ablation exports 3n transport channels (docs/model.md)
            self.tstar = self.n_coeffs > 1 and t == 3 * self.n_coeffs
            self.model = None
        elif self.path.suffix == ".safetensors":
            from model.checkpoint import load_model

            self.model = load_model(self.path)
            self.tstar = self.model.tstar
            self.n_coeffs = self.model.n
        else:
            raise ValueError(f"model must be a .safetensors checkpoint or an .onnx file, got {self.path.name}")

    @property
    def order(self) -> int | None:
        return None if self.n_coeffs is None else int(round(self.n_coeffs ** 0.5)) - 1

    def __call__(self, image: np.ndarray) -> dict[str, np.ndarray]:
        if self.model is not None:
            x = torch.from_numpy(image)
            self.model.check_input(x)
            with torch.no_grad():
                out = self.model(x)
            return {k: out[k].numpy() for k in OUTPUTS}
        try:
            out = self.session.run(image)
        except Exception as exc:  # onnxruntime raises its own types (e.g. a size the graph rejects)
            raise ValueError(f"{self.path.name} failed on an input of shape {image.shape}: {exc}") from None
        return {k: out[k] for k in OUTPUTS}


def _hwc(x: np.ndarray) -> np.ndarray:
    return np.ascontiguousarray(np.moveaxis(x, 0, -1))


def shading_np(transport: np.ndarray, light: np.ndarray, tstar: bool) -> np.ndarray:
    """T . L [H, W, 3] from transport [n or 3n, H, W] and light [n, 3]."""
    if tstar:
        n = light.shape[0]
        return np.einsum("cnhw,nc->hwc", transport.reshape(3, n, *transport.shape[1:]), light)
    return np.einsum("nhw,nc->hwc", transport, light)


def render_np(pred: dict, light: np.ndarray, tstar: bool) -> np.ndarray:
    """The relit image [H, W, 3] of one prediction (channels first) under `light`:
    relight.prt.render's albedo * (T . L) + E . L, or T* . L for the T* ablation."""
    if tstar:
        return shading_np(pred["transport"], light, True)
    return render(_hwc(pred["albedo"]), _hwc(pred["transport"]), _hwc(pred["residual"]), light)


def evaluate_prediction(pred: dict, sample: dict, tstar: bool) -> dict[str, dict[str, float]]:
    """Metrics of one prediction: {"reconstruction/albedo": {...}, "relighting/image": {...}, ...}."""
    mask = _hwc(metric_weight(sample))
    gt_albedo, gt_t = _hwc(sample["albedo"]), sample["transport"]
    out = {}
    for setting, light_pred, light_gt, image_gt in (
            ("reconstruction", pred["light"], sample["light"], sample["image"]),
            ("relighting", sample["target_light"], sample["target_light"], sample["target_image"])):
        if not tstar:
            out[f"{setting}/albedo"] = metrics.all_metrics(_hwc(pred["albedo"]), gt_albedo, mask)
            out[f"{setting}/shading"] = metrics.all_metrics(shading_np(pred["transport"], light_pred, False),
                                                            shading_np(gt_t, light_gt, False), mask)
        out[f"{setting}/image"] = metrics.all_metrics(render_np(pred, light_pred, tstar), _hwc(image_gt), mask)
    return out


def gain_fitted(pred: dict, sample: dict, tstar: bool) -> dict[str, dict[str, float]]:
    """Diagnostic: the prediction's albedo and relit image after per-channel gains fitted to the GT.

    Splits the error into a global colour / exposure part (which the gains
    remove, and which single-image relighting cannot fully know) and the rest.
    Uses the ground truth: a diagnostic row, never a method.
    """
    mask = _hwc(metric_weight(sample))
    out = {}
    relit, gt = render_np(pred, sample["target_light"], tstar), _hwc(sample["target_image"])
    out["relighting/image"] = metrics.all_metrics(relit * metrics.fit_channel_gains(relit, gt, mask), gt, mask)
    if not tstar:
        albedo, gt_albedo = _hwc(pred["albedo"]), _hwc(sample["albedo"])
        gains = metrics.fit_channel_gains(albedo, gt_albedo, mask)
        out["relighting/albedo"] = metrics.all_metrics(albedo * gains, gt_albedo, mask)
    return out


def exposure_ratio(light_a: np.ndarray, light_b: np.ndarray) -> np.ndarray:
    """Per-channel L00_b / L00_a (1 where L00_a is 0): exposure-matched identity's gain."""
    la, lb = light_a[0], light_b[0]
    return np.where(np.abs(la) > 1e-12, lb / np.where(np.abs(la) > 1e-12, la, 1.0), 1.0)


def baseline_identity(sample: dict, exposure_matched: bool) -> dict[str, dict[str, float]]:
    """The input image as the relit result (optionally scaled per channel by L00_b / L00_a)."""
    image = _hwc(sample["input_linear"])
    if exposure_matched:
        image = image * exposure_ratio(sample["light"], sample["target_light"])
    mask = _hwc(metric_weight(sample))
    return {"relighting/image": metrics.all_metrics(image, _hwc(sample["target_image"]), mask)}


# "interior": fully covered pixels only (model.metrics.INTERIOR_ALPHA says why);
# "alpha": the GT alpha as the weight.
MASK_MODES = ("interior", "alpha")
INTERIOR_ALPHA = metrics.INTERIOR_ALPHA


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
    mask = _hwc(metric_weight(sample))
    out = {}
    for setting, light, image in (("reconstruction", sample["light"], sample["image"]),
                                  ("relighting", sample["target_light"], sample["target_image"])):
        prt = _hwc(sample["albedo"]) * shading_np(sample["transport"], light, False)
        out[f"{setting}/image"] = metrics.all_metrics(prt, _hwc(image), mask)
    return out


QUOTIENT_FLOOR = 0.25  # model.geometry's `reliable` default


def transport_normal(transport: np.ndarray) -> np.ndarray:
    """Unit band-1 direction of T [n, H, W] -> [H, W, 3]: the (bent) normal of a lobe
    (Y_{1,-1} ~ y, Y_{1,0} ~ z, Y_{1,1} ~ x); any model's T has one."""
    d = np.stack([transport[3], transport[1], transport[2]], axis=-1).astype(np.float64)
    return d / np.maximum(np.linalg.norm(d, axis=-1, keepdims=True), 1e-12)


def transport_visibility(transport: np.ndarray) -> np.ndarray:
    """T_00 relative to an unoccluded point, [H, W], clamped to [0, 1]."""
    return np.clip(transport[0] / UNOCCLUDED_DC, 0.0, 1.0)


MOTION_AZIMUTHS = (0.0, 180.0)  # a directional light turned half way round (relight.sh.directional_light)


def light_motion(albedo: np.ndarray, transport: np.ndarray, residual: np.ndarray | None, weight: np.ndarray,
                 order: int) -> float:
    """metrics.spatial_change of albedo * (T . L) + E . L between a directional light at
    MOTION_AZIMUTHS[0] and [1]: how visibly a turned light moves over the person."""
    from relight.sh import directional_light

    imgs = []
    for az in MOTION_AZIMUTHS:
        L = directional_light(az, order)
        img = _hwc(albedo) * shading_np(transport, L, False)
        if residual is not None:
            img = img + shading_np(residual, L, False)
        imgs.append(np.maximum(img, 0.0))
    return metrics.spatial_change(imgs[0], imgs[1], _hwc(weight))


def geometry_metrics(pred: dict, sample: dict) -> dict[str, float]:
    """Normal angle (degrees; from T's band 1, against the farm's normal pass),
    visibility L1 (T_00 ratio against the baked T's), and the input light's error
    (|L - L_true| / |L_true| over all coefficients) on the metric's pixels."""
    w = metric_weight(sample)[0] > 0.5
    if not w.any():
        return {}
    gt_n = _hwc(sample["normal"]).astype(np.float64)
    cos = np.clip((transport_normal(pred["transport"]) * gt_n).sum(-1), -1.0, 1.0)
    angle = np.degrees(np.arccos(cos))[w]
    vis = np.abs(transport_visibility(pred["transport"]) - transport_visibility(sample["transport"]))[w]
    light, true = np.asarray(pred["light"], np.float64), np.asarray(sample["light"], np.float64)
    order = int(round(np.sqrt(light.shape[0]))) - 1
    weight = metric_weight(sample)
    return {"normal_mean_deg": float(angle.mean()), "normal_median_deg": float(np.median(angle)),
            "visibility_l1": float(vis.mean()),
            "light_rel_l2": float(np.linalg.norm(light - true) / max(np.linalg.norm(true), 1e-12)),
            "light_motion": light_motion(pred["albedo"], pred["transport"], pred.get("residual"), weight, order),
            "light_motion_gt": light_motion(sample["albedo"], sample["transport"], None, weight, order)}


BREAKDOWN_ROWS = (
    "true albedo x our shading",
    "our albedo x true shading",
    "ours with the true input light (quotient)",
    "physics: quotient, true normals, true input light",
    "physics: true albedo x Lambert of true normals",
    "physics: true albedo x lobe of true normal and visibility",
)


def error_breakdown(pred: dict, sample: dict, order: int) -> dict[str, dict[str, float]]:
    """Relit-image metrics with parts of the prediction replaced by the truth, and the
    physics ceilings (rows of docs/EVALUATION.md's breakdown table):

    * true albedo x our shading; our albedo x true shading (T_gt . L_b);
    * ours with the true input light: quotient photo * (T . L_b) / (T . L_a,true);
    * quotient with true normals (unoccluded lobe) and the true input light;
    * true albedo x unoccluded Lambert of the true normals (order `order`);
    * true albedo x lobe of the true normal and visibility (the parametric ceiling).
    """
    from relight.prt import lambert_transport

    mask = _hwc(metric_weight(sample))
    gt = _hwc(sample["target_image"])
    photo = _hwc(sample["input_linear"])
    la, lb = sample["light"], sample["target_light"]
    albedo_gt = _hwc(sample["albedo"])
    normal_gt = _hwc(sample["normal"]).astype(np.float64)
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
        _hwc(pred["albedo"]) * shading_np(sample["transport"], lb, False),
        quotient(pred["transport"]),
        quotient(lambert),
        albedo_gt * shading_np(lambert, lb, False),
        albedo_gt * shading_np(lobe, lb, False),
    )
    return {name: {"relighting/image": metrics.all_metrics(img, gt, mask)}
            for name, img in zip(BREAKDOWN_ROWS, images)}


def parametric_transport_error(sample: dict, order: int) -> float:
    """|T_lobe(true n, true v) - T_baked| / |T_baked| on the metric's pixels."""
    from relight.prt import lambert_transport

    w = metric_weight(sample)[0] > 0.5
    normal_gt = _hwc(sample["normal"]).astype(np.float64)
    ok = w & (np.linalg.norm(normal_gt, axis=-1) > 0.5)
    if not ok.any():
        return float("nan")
    lobe = lambert_transport(normal_gt[ok], order) * transport_visibility(sample["transport"])[ok][:, None]
    baked = np.moveaxis(sample["transport"], 0, -1)[ok]
    return float(np.linalg.norm(lobe - baked) / max(np.linalg.norm(baked), 1e-12))


def geometry_table(results: dict[str, dict[str, float]], ceiling: float) -> str:
    lines = ["| method | normal mean (deg) | normal median (deg) | visibility L1 | input light rel. L2 | "
             "light motion 0->180 deg (GT renders) |",
             "|---|---|---|---|---|---|"]
    for method, m in results.items():
        lines.append(f"| {method} | {m['normal_mean_deg']:.1f} | {m['normal_median_deg']:.1f} | "
                     f"{m['visibility_l1']:.3f} | {m['light_rel_l2']:.3f} | "
                     f"{m['light_motion']:.3f} ({m['light_motion_gt']:.3f}) |")
    lines += ["", f"Parametric ceiling: the lobe of the true normal and visibility reproduces the baked T "
                  f"to a relative L2 error of {ceiling:.3f}.",
              "Light motion: model.metrics.spatial_change of the person relit by a directional light "
              "(relight.sh.directional_light) at 0 and at 180 degrees, after per-channel gains; in brackets "
              "the same for the ground truth, albedo * (T . L) from the farm's buffers."]
    return "\n".join(lines) + "\n"


def _mean_table(rows: list[dict]) -> dict[str, dict[str, float]]:
    acc: dict[str, dict[str, list[float]]] = defaultdict(lambda: defaultdict(list))
    for row in rows:
        for key, m in row.items():
            for name, value in m.items():
                acc[key][name].append(value)
    return {key: {name: float(np.mean(v)) for name, v in m.items()} for key, m in acc.items()}


def markdown_table(results: dict[str, dict], n_pairs: int, data: str, mask: str = "alpha") -> str:
    where = (f"fully covered pixels, GT alpha > {INTERIOR_ALPHA}" if mask == "interior" else "GT alpha-weighted")
    lines = [f"# Evaluation ({n_pairs} image pairs from `{data}`)", "",
             f"Over the person's pixels ({where}), linear values; L1 and L2 x100, "
             "PSNR in dB with peak 1.0; SI PSNR after per-channel gains fitted to the truth "
             "(scale-invariant: the pattern, not the colour and level; model/metrics.py).", ""]
    header = "| method | setting | " + " | ".join(f"{m} L1 | {m} L2 | {m} PSNR | {m} SI PSNR" for m in MAPS) + " |"
    lines += [header, "|" + "---|" * (2 + 4 * len(MAPS))]
    for method, table in results.items():
        for setting in ("reconstruction", "relighting"):
            if not any(k.startswith(setting) for k in table):
                continue
            cells = []
            for m in MAPS:
                v = table.get(f"{setting}/{m}")
                cells += (["-"] * 4 if v is None else
                          [f"{100 * v['l1']:.2f}", f"{100 * v['l2']:.3f}", f"{v['psnr']:.2f}", f"{v['si_psnr']:.2f}"])
            lines.append(f"| {method} | {setting} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def contact_sheet(rows: list[list[np.ndarray]]) -> np.ndarray:
    """Tiles linear [H, W, 3] images: one row per pair, sRGB-encoded, 2 px gutters (relight.sheet)."""
    return _contact_sheet(rows)


ORACLE_ROW = "ground-truth PRT, no E (oracle)"
GAIN_ROW = "ours, per-channel gains fitted to GT (diagnostic)"
RESERVED_ROWS = ("ours", "identity", "identity, exposure-matched", ORACLE_ROW, GAIN_ROW)


def baseline_label(path) -> str:
    """Row name of a baseline given without a name: "baseline (folder/file)"."""
    path = Path(path)
    return f"baseline ({path.parent.name}/{path.name})"


def parse_baselines(specs) -> list[tuple[str, Path]]:
    """(name, path) per baseline. `specs`: None, one path, or a list whose items are
    paths, (name, path) pairs or "NAME=PATH" strings; names must be unique."""
    if specs is None:
        return []
    if isinstance(specs, (str, os.PathLike)):
        specs = [specs]
    out: list[tuple[str, Path]] = []
    for spec in specs:
        if isinstance(spec, tuple):
            name, path = spec
        elif isinstance(spec, str) and "=" in spec and not Path(spec).is_file() \
                and not any(c in spec.split("=", 1)[0] for c in "/\\"):
            # NAME=PATH; an existing file, or a path with "=" in a folder name, stays a path
            name, path = spec.split("=", 1)
            name = name.strip()
            if not name or not path:
                raise ValueError(f"--baseline {spec!r}: expected NAME=PATH or PATH")
        else:
            name, path = None, spec
        path = Path(path)
        name = baseline_label(path) if name is None else str(name)
        if "|" in name or "\n" in name:
            raise ValueError(f"baseline name {name!r}: '|' and line breaks would break the markdown table")
        if name in RESERVED_ROWS or name in {n for n, _ in out}:
            raise ValueError(f"baseline name {name!r} is used twice or by a built-in row; "
                             "give each --baseline its own NAME=PATH")
        out.append((name, path))
    return out


def _numpy_sample(item: dict) -> dict:
    return {k: (v.numpy() if isinstance(v, torch.Tensor) else v) for k, v in item.items()}


def evaluate(model_path, data, out, *, size: int = 256, baseline=None, held_out_only: bool = False,
             sheet_rows: int = 4, max_pairs_per_scene: int = 4, order: int | None = None,
             mask: str = "interior") -> dict:
    """Run the evaluation and write its files; returns {"methods": ..., "pairs": n}.

    `baseline`: None, a model path, or a list of paths / (name, path) / "NAME=PATH"
    (parse_baselines); each becomes a row under its name."""
    ours = Predictor(model_path)
    bases = [(name, path, Predictor(path)) for name, path in parse_baselines(baseline)]
    order = ours.order if ours.order is not None else order
    if order is None:
        raise ValueError("ONNX model with a dynamic coefficient count: pass --order")
    if ours.model is not None and size % ours.model.size_multiple:
        raise ValueError(f"--size {size} must be a multiple of {ours.model.size_multiple}")
    for name, path, b in bases:
        if b.model is not None and size % b.model.size_multiple:
            raise ValueError(f"--size {size} must be a multiple of {b.model.size_multiple} (baseline {name})")
    scenes = find_scenes(data)

    def make_pairs(sh_order: int) -> EvaluationPairs:
        return EvaluationPairs(scenes, size, sh_order, held_out_only=held_out_only,
                               held_out=held_out_light_names(), max_pairs_per_scene=max_pairs_per_scene)

    # one pair list per SH order: the same (scene, a, b) pairs, light coefficients cut to that order
    pairs_by_order = {order: make_pairs(order)}
    for _, _, b in bases:
        b_order = b.order if b.order is not None else order
        if b_order not in pairs_by_order:
            pairs_by_order[b_order] = make_pairs(b_order)
    pairs = pairs_by_order[order]
    rows = defaultdict(list)
    geometry, breakdown, transport_err = defaultdict(list), defaultdict(list), []
    sheet = []
    for i in range(len(pairs)):
        sample = with_metric_weight(_numpy_sample(pairs[i]), mask)
        pred = {k: v[0] for k, v in ours(sample["input"][None]).items()}
        rows["ours"].append(evaluate_prediction(pred, sample, ours.tstar))
        rows["identity"].append(baseline_identity(sample, exposure_matched=False))
        rows["identity, exposure-matched"].append(baseline_identity(sample, exposure_matched=True))
        rows[ORACLE_ROW].append(oracle_prt(sample))
        rows[GAIN_ROW].append(gain_fitted(pred, sample, ours.tstar))
        if "normal" in sample and not ours.tstar:
            geometry["ours"].append(geometry_metrics(pred, sample))
            for name, value in error_breakdown(pred, sample, order).items():
                breakdown[name].append(value)
            transport_err.append(parametric_transport_error(sample, order))
        for name, _, b in bases:
            b_order = b.order if b.order is not None else order
            bs = sample if b_order == order else with_metric_weight(
                _numpy_sample(pairs_by_order[b_order][i]), mask)
            bpred = {k: v[0] for k, v in b(bs["input"][None]).items()}
            rows[name].append(evaluate_prediction(bpred, bs, b.tstar))
            if "normal" in bs and not b.tstar:
                geometry[name].append(geometry_metrics(bpred, bs))
        if len(sheet) < sheet_rows:
            # person maps shown over black (times the GT alpha); ours relit over the GT's background
            a = _hwc(sample["alpha"])
            relit = render_np(pred, sample["target_light"], ours.tstar)
            gt = _hwc(sample["target_image"])
            error = a * np.abs(relit - gt).mean(axis=-1, keepdims=True) * 4.0
            residual = a * np.abs(shading_np(pred["residual"], sample["target_light"], False)) * 10.0
            shading = relit if ours.tstar else shading_np(pred["transport"], sample["target_light"], False)
            sheet.append([_hwc(sample["input_linear"]), a * relit + (1 - a) * gt, gt, error.repeat(3, -1),
                          a * _hwc(pred["albedo"]), a * shading, residual])
    results = {method: _mean_table(r) for method, r in rows.items()}
    geo = {method: {k: float(np.mean([r[k] for r in rs if r])) for k in rs[0]}
           for method, rs in geometry.items() if rs and rs[0]}
    broken = {method: _mean_table(r) for method, r in breakdown.items()}
    ceiling = float(np.nanmean(transport_err)) if transport_err else float("nan")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    text = markdown_table(results, len(pairs), str(data), mask)
    if broken:
        text += ("\n## Where the error is (relighting, image)\n\n"
                 + markdown_table({"ours": {k: v for k, v in results["ours"].items()
                                            if k == "relighting/image"}, **broken}, len(pairs), str(data), mask)
                 .split("\n\n", 2)[2])
    if geo:
        text += "\n## Geometry and light\n\n" + geometry_table(geo, ceiling)
    atomic_write_text(out / "evaluation.md", text +
                       "\nContact sheet columns: input, ours relit (over the GT background), GT, "
                       "|error| x4, albedo, shading, |residual| x10 (person maps times the GT alpha).\n")
    atomic_write_text(out / "evaluation.json", json.dumps(
        {"model": str(model_path), "baselines": {name: str(path) for name, path, _ in bases},
         "pairs": len(pairs), "geometry": geo, "breakdown": broken, "parametric_transport_rel_l2": ceiling,
         "size": size, "mask": mask, "methods": results, "pair_list": [list(map(int, p)) for p in pairs.pairs]}, indent=1) + "\n")
    write_sheet(out / "contact_sheet.png", contact_sheet(sheet))
    return {"methods": results, "pairs": len(pairs), "geometry": geo, "breakdown": broken,
            "parametric_transport_rel_l2": ceiling}


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m model.evaluate", description=__doc__.splitlines()[0])
    p.add_argument("model", help=".safetensors checkpoint or .onnx file")
    p.add_argument("--data", required=True, help="dataset folder of finished scenes")
    p.add_argument("--out", default="evaluation", help="output folder (default: ./evaluation)")
    p.add_argument("--size", type=int, default=256)
    p.add_argument("--mask", choices=MASK_MODES, default="interior",
                   help="metric weight: fully covered person pixels (default) or the GT alpha")
    p.add_argument("--baseline", action="append", metavar="[NAME=]MODEL",
                   help="another model to compare, .safetensors or .onnx (repeatable; NAME labels its "
                        "row, default 'baseline (folder/file)'), e.g. small=runs/small/model.safetensors")
    p.add_argument("--held-out-only", action="store_true", help="relight only towards held-out lights")
    p.add_argument("--order", type=int, help="SH order, only for ONNX models with dynamic shapes")
    p.add_argument("--sheet-rows", type=int, default=4)
    p.add_argument("--threads", type=int, default=0, help="torch CPU threads (0: torch's default)")
    args = p.parse_args(argv)
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    try:
        result = evaluate(args.model, args.data, args.out, size=args.size, baseline=args.baseline,
                          held_out_only=args.held_out_only, sheet_rows=args.sheet_rows, order=args.order,
                          mask=args.mask)
    except ValueError as exc:
        print(f"model.evaluate: error: {exc}", file=sys.stderr)
        return 2
    print((Path(args.out) / "evaluation.md").read_text(encoding="utf-8"), end="")
    print(f"{result['pairs']} pairs; wrote {args.out}/evaluation.md, evaluation.json, contact_sheet.png")
    return 0


if __name__ == "__main__":
    sys.exit(main())
