"""Evaluate a model on scene files: `python -m model.evaluate MODEL --data DIR [--out DIR]`.

MODEL is a .safetensors checkpoint (model.training.checkpoint) or an .onnx file (run
with onnxruntime, I/O of docs/ARCHITECTURE.md: input "image", outputs
"albedo", "transport", "residual", "light", "alpha"). For every pair
(scene, light a -> light b) of path-traced images the paper's metrics are
measured over the person's pixels (model.scoring.metrics): albedo, shading and image
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

from evaluation.sheet import contact_sheet as _contact_sheet
from evaluation.sheet import write_sheet
from relight.files.fileio import atomic_write_text

from model.samples.data import EvaluationPairs
from model.scoring.depth_metrics import depth_markdown, depth_table, pair_depth_rows
from model.scoring.face_region import FaceRows
from model.samples.data_splits import find_scenes, held_out_light_names
from relight.files.dataset import read_sidecar
from model.scoring.geometry_diagnostics import (
    TRUE_LIGHT_ROW, breakdown_images, error_breakdown, geometry_metrics, geometry_table, parametric_transport_error,
    transport_normal,
)
from model.scoring.pair_metrics import (
    MAPS, MASK_MODES, INTERIOR_ALPHA, baseline_identity, channels_last, evaluate_prediction, gain_fitted, oracle_prt,
    render_np, shading_np, with_metric_weight,
)
from model.scoring.metrics import light_response, psnr
from model.scoring.predictor import Predictor
from model.scoring.report_cli import run_report


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
             "(scale-invariant: the pattern, not the colour and level; model/scoring/metrics.py).", ""]
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
    """Tiles linear [H, W, 3] images: one row per pair, sRGB-encoded, 2 px gutters (evaluation.sheet)."""
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


def numpy_sample(item: dict) -> dict:
    """An EvaluationPairs item with its tensors as numpy arrays."""
    return {k: (v.numpy() if isinstance(v, torch.Tensor) else v) for k, v in item.items()}


def framing_of(json_path) -> str:
    """The scene's framing as its sidecar records it ("-" for scenes from before framings)."""
    return str(read_sidecar(json_path).get("camera", {}).get("framing") or "-")


def pair_light_response(sample: dict, pred: dict, tstar: bool) -> dict:
    """The relit PSNR and the light's response (model.scoring.metrics.light_response: slope and
    correlation of the relit log-luminance change against the true one) of one pair."""
    return relit_light_response(sample, render_np(pred, sample["target_light"], tstar))


def relit_light_response(sample: dict, relit: np.ndarray) -> dict:
    """pair_light_response's figures of a relit image [H, W, 3] of the pair made any way (the
    breakdown's rows: parts of the prediction swapped for the truth)."""
    target, weight = channels_last(sample["target_image"]), channels_last(sample["metric_weight"])
    response = light_response(channels_last(sample["input_linear"]), relit, target, weight)
    return {"psnr": psnr(relit, target, weight), "slope": response.slope, "correlation": response.correlation}


def light_response_table(records: dict[str, dict[str, list[dict]]]) -> dict:
    """{method: {framing: {"pairs", "psnr", "slope", "correlation"}}}: means over the pairs (slope and
    correlation over the pairs where the truth changes: light_response's NaN pairs left out)."""
    out: dict = {}
    for method, by_framing in records.items():
        for framing, rows in sorted(by_framing.items()):
            slopes = [r["slope"] for r in rows if np.isfinite(r["slope"])]
            corrs = [r["correlation"] for r in rows if np.isfinite(r["correlation"])]
            out.setdefault(method, {})[framing] = {
                "pairs": len(rows), "psnr": float(np.mean([r["psnr"] for r in rows])),
                "slope": float(np.mean(slopes)) if slopes else float("nan"),
                "correlation": float(np.mean(corrs)) if corrs else float("nan")}
    return out


def light_response_markdown(table: dict) -> str:
    lines = ["\n## The light's response, per framing\n",
             "Relit log-luminance change (relit / photo) against the true change (truth under b / photo), "
             "means removed, over the same pixels: least-squares slope and correlation (1 and 1 = physics; "
             "identity 0; model.scoring.metrics.light_response). The rows of \"Where the error is\" follow "
             "ours: with a part swapped for the truth, how much of the response comes back.\n",
             "| method | framing | pairs | relit PSNR | slope | correlation |", "|---|---|---|---|---|---|"]
    for method, by_framing in table.items():
        for framing, v in by_framing.items():
            lines.append(f"| {method} | {framing} | {v['pairs']} | {v['psnr']:.2f} | {v['slope']:.2f} | "
                         f"{v['correlation']:.2f} |")
    return "\n".join(lines) + "\n"


def pair_record(sample: dict, ours: dict, breakdown: dict | None, geometry: dict | None) -> dict:
    """One pair's maps and our relit scores (plain, SI; with the true input light and the light's
    colour error where the geometry is known): the means of evaluation.json, split any way a study
    needs (for example by whether the pair's input map was trained on)."""
    record = {"scene": int(sample["scene_index"]), "light_a": sample["light_a"], "light_b": sample["light_b"],
              "relit_psnr": ours["relighting/image"]["psnr"], "relit_si_psnr": ours["relighting/image"]["si_psnr"]}
    if breakdown and geometry:
        record["true_light_psnr"] = breakdown[TRUE_LIGHT_ROW]["relighting/image"]["psnr"]
        record["light_colour_deg"] = geometry.get("light_colour_deg")
    return record


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
                               held_out=held_out_light_names(), max_pairs_per_scene=max_pairs_per_scene,
                               body_prior=ours.body_prior or any(b.body_prior for _, _, b in bases),
                               depth=ours.has_depth)  # the depth pass, scored when the model has the head

    # one pair list per SH order: the same (scene, a, b) pairs, light coefficients cut to that order
    pairs_by_order = {order: make_pairs(order)}
    for _, _, b in bases:
        b_order = b.order if b.order is not None else order
        if b_order not in pairs_by_order:
            pairs_by_order[b_order] = make_pairs(b_order)
    pairs = pairs_by_order[order]
    rows = defaultdict(list)
    geometry, breakdown, transport_err = defaultdict(list), defaultdict(list), []
    sheet, per_pair = [], []
    face = FaceRows(size)
    responses: dict = defaultdict(lambda: defaultdict(list))
    depths: dict = defaultdict(list)  # framing -> pair_depth_rows' answers (models with the depth head)
    framings = [framing_of(path) for path in pairs.paths]
    seeds = [read_sidecar(path).get("seed") for path in pairs.paths]  # with the index: the scene's pair in another set
    for i in range(len(pairs)):
        sample = with_metric_weight(numpy_sample(pairs[i]), mask)
        framing = framings[pairs.pairs[i][0]]
        pred = {k: v[0] for k, v in ours(sample["input"][None]).items()}
        face_rows(face, pred, sample, pairs.paths[pairs.pairs[i][0]], ours.tstar, order)
        rows["ours"].append(evaluate_prediction(pred, sample, ours.tstar))
        rows["identity"].append(baseline_identity(sample, exposure_matched=False))
        rows["identity, exposure-matched"].append(baseline_identity(sample, exposure_matched=True))
        rows[ORACLE_ROW].append(oracle_prt(sample))
        rows[GAIN_ROW].append(gain_fitted(pred, sample, ours.tstar))
        pair_geometry, pair_breakdown = None, None
        response = pair_light_response(sample, pred, ours.tstar)
        responses["ours"][framing].append(response)
        if "normal" in sample and not ours.tstar:
            images = breakdown_images(pred, sample, order)
            pair_geometry, pair_breakdown = geometry_metrics(pred, sample), error_breakdown(pred, sample, order, images)
            geometry["ours"].append(pair_geometry)
            for name, value in pair_breakdown.items():
                breakdown[name].append(value)
                # where the light's response is lost: the same swaps' slope and correlation
                responses[name][framing].append(relit_light_response(sample, images[name]))
            transport_err.append(parametric_transport_error(sample, order))
        pair_depth = pair_depth_rows(pred, sample, sample["metric_weight"][0])
        if pair_depth is not None:
            depths[framing].append(pair_depth)
        per_pair.append({**pair_record(sample, rows["ours"][-1], pair_breakdown, pair_geometry), "framing": framing,
                         "seed": seeds[pairs.pairs[i][0]],
                         "matched_photo_psnr": rows["identity, exposure-matched"][-1]["relighting/image"]["psnr"],
                         "light_slope": response["slope"], "light_correlation": response["correlation"]})
        for name, _, b in bases:
            b_order = b.order if b.order is not None else order
            bs = sample if b_order == order else with_metric_weight(
                numpy_sample(pairs_by_order[b_order][i]), mask)
            bpred = {k: v[0] for k, v in b(bs["input"][None]).items()}
            rows[name].append(evaluate_prediction(bpred, bs, b.tstar))
            responses[name][framing].append(pair_light_response(bs, bpred, b.tstar))
            if "normal" in bs and not b.tstar:
                geometry[name].append(geometry_metrics(bpred, bs))
        if len(sheet) < sheet_rows:
            # person maps shown over black (times the GT alpha); ours relit over the GT's background
            a = channels_last(sample["alpha"])
            relit = render_np(pred, sample["target_light"], ours.tstar)
            gt = channels_last(sample["target_image"])
            error = a * np.abs(relit - gt).mean(axis=-1, keepdims=True) * 4.0
            residual = a * np.abs(shading_np(pred["residual"], sample["target_light"], False)) * 10.0
            shading = relit if ours.tstar else shading_np(pred["transport"], sample["target_light"], False)
            sheet.append([channels_last(sample["input_linear"]), a * relit + (1 - a) * gt, gt, error.repeat(3, -1),
                          a * channels_last(pred["albedo"]), a * shading, residual])
    results = {method: _mean_table(r) for method, r in rows.items()}
    geo = {method: {k: float(np.mean([r[k] for r in rs if r])) for k in rs[0]}
           for method, rs in geometry.items() if rs and rs[0]}
    broken = {method: _mean_table(r) for method, r in breakdown.items()}
    ceiling = float(np.nanmean(transport_err)) if transport_err else float("nan")
    response_table = light_response_table(responses)
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
    text += light_response_markdown(response_table)
    depth_tab = depth_table(depths) if depths else None
    if depth_tab:
        text += depth_markdown(depth_tab)
    text += face.markdown()
    atomic_write_text(out / "evaluation.md", text +
                       "\nContact sheet columns: input, ours relit (over the GT background), GT, "
                       "|error| x4, albedo, shading, |residual| x10 (person maps times the GT alpha).\n")
    atomic_write_text(out / "evaluation.json", json.dumps(
        {"model": str(model_path), "baselines": {name: str(path) for name, path, _ in bases},
         "pairs": len(pairs), "geometry": geo, "breakdown": broken, "parametric_transport_rel_l2": ceiling,
         "size": size, "mask": mask, "methods": results, "pair_list": [list(map(int, p)) for p in pairs.pairs],
         "per_pair": per_pair, "face": face.summary(), "light_response": response_table,
         "depth": depth_tab}, indent=1) + "\n")
    write_sheet(out / "contact_sheet.png", contact_sheet(sheet))
    return {"methods": results, "pairs": len(pairs), "geometry": geo, "breakdown": broken,
            "parametric_transport_rel_l2": ceiling, "face": face.summary(), "light_response": response_table,
            "depth": depth_tab}


def face_rows(face: FaceRows, pred: dict, sample: dict, json_path, tstar: bool, order: int) -> None:
    """The pair's rows over its face (model.scoring.face_region), when it has one: ours, the identity
    baselines, the oracle, the breakdown's ceilings and the normals' angle."""
    fs = face.face_sample(sample, json_path)
    if fs is None:
        return
    face.add("ours", evaluate_prediction(pred, fs, tstar))
    face.add("identity", baseline_identity(fs, exposure_matched=False))
    face.add("identity, exposure-matched", baseline_identity(fs, exposure_matched=True))
    face.add(ORACLE_ROW, oracle_prt(fs))
    face.add(GAIN_ROW, gain_fitted(pred, fs, tstar))
    if "normal" in fs and not tstar:
        for name, row in error_breakdown(pred, fs, order).items():
            face.add(name, row)
        face.add_normals(transport_normal(pred["transport"]), channels_last(fs["normal"]), fs["metric_weight"])


def main(argv=None) -> int:
    p = argparse.ArgumentParser(prog="python -m model.evaluate", description=__doc__.splitlines()[0])
    p.add_argument("model", help=".safetensors checkpoint or .onnx file")
    p.add_argument("--data", required=True, help="dataset folder of finished scenes")
    p.add_argument("--out", default=None,
                   help="output folder (default: runs/evaluate-MODEL_NAME, never the repository's evaluation/ package)")
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
    if args.out is None:  # ./evaluation was the default: inside a checkout, the evaluation/ package itself
        args.out = str(Path("runs") / f"evaluate-{Path(args.model).stem}")
    if args.threads > 0:
        torch.set_num_threads(args.threads)
    return run_report(
        "model.evaluate",
        lambda: evaluate(args.model, args.data, args.out, size=args.size, baseline=args.baseline,
                         held_out_only=args.held_out_only, sheet_rows=args.sheet_rows, order=args.order,
                         mask=args.mask),
        Path(args.out) / "evaluation.md",
        lambda result: f"{result['pairs']} pairs; wrote {args.out}/evaluation.md, evaluation.json, contact_sheet.png")


if __name__ == "__main__":
    sys.exit(main())
