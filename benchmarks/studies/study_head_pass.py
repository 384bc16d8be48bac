"""Issue 37, a second pass of the network on the head, fused into the body's maps (a study, no
runtime change): does seeing the face at a larger scale pay, and how far is it from the ceiling of
any head geometry through the same route? Not run by the tests.

    PYTHONPATH=. .venv/bin/python benchmarks/studies/study_head_pass.py data/heldout37_hs \\
        [--qualities draft,best] [--margins 0.25,0.5] [--sheet out/head_pass/faces_hs.png]

Each scene's light a relights to each other light b (truth: the path-traced render under b), the
true alpha as the mask. Per quality preset (relight.network.quality), five answers:
- baseline: the runtime's decomposition of the person crop, as shipped;
- head pass (per margin): the runtime run again, at the same preset, on the photo cut to the head's
  box (the farm's head mask > 0.5) grown by the margin of its longer side on each side, the true
  alpha of that cut as the mask; its transport resampled into the body's working grid (bilinear,
  photo coordinates, as relight.network.tta brings its runs into the first run's frame) and blended
  over the head: weight 1 on the head mask, ramped out over FEATHER of the head's size; the body's
  light kept; the albedo from the fused transport by the one rule (Decomposition.with_light);
- ceiling, true T: the scene's own transport (the farm's PRT, the network's convention) fused the
  same way; ceiling, true n: the lobe of the true normals with the body's ambient visibility
  (relight.network.face_relight.lobe_transport), fused the same way.
Scores (model.scoring.metrics): relit PSNR and scale-invariant PSNR over the interior (alpha >
0.999) and the face PSNR (the head mask > 0.5 times the interior); paired differences against the
baseline with their standard error over pairs. Time: the head pass's decomposition (the extra
cost) against the body's, per photo, on --threads threads.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

FEATHER = 0.08   # of the head's longer side on the body's grid: the blend's outward ramp
HEAD = 0.5       # head mask threshold (model.scoring.face_region's)


def head_box(head: np.ndarray, margin: float, shape) -> tuple[int, int, int, int] | None:
    """The head mask's box grown by `margin` of its longer side on each side, clipped to the photo."""
    ys, xs = np.nonzero(head > HEAD)
    if ys.size < 16:
        return None
    y0, y1, x0, x1 = int(ys.min()), int(ys.max()) + 1, int(xs.min()), int(xs.max()) + 1
    g = int(round(margin * max(y1 - y0, x1 - x0)))
    return max(0, y0 - g), min(shape[0], y1 + g), max(0, x0 - g), min(shape[1], x1 + g)


def grid_coords(d):
    """Photo coordinates (x, y; pixel centres at +0.5) of the centres of d's working grid [h, w]."""
    y0, y1, x0, x1 = d.box
    h, w = d.working_size
    xs = x0 + (np.arange(w) + 0.5) * (x1 - x0) / w
    ys = y0 + (np.arange(h) + 0.5) * (y1 - y0) / h
    return np.meshgrid(xs, ys)


def head_in_body_frame(body, head_d, origin) -> np.ndarray:
    """The head run's transport resampled onto the body's working grid (zero outside the head run's
    crop): the body grid's photo coordinates -> the cut's -> the head run's grid."""
    from relight.imaging.resample import sample_points

    X, Y = grid_coords(body)
    hy0, hy1, hx0, hx1 = head_d.box
    hh, hw = head_d.working_size
    u = (X - origin[1] - hx0) * hw / (hx1 - hx0)
    v = (Y - origin[0] - hy0) * hh / (hy1 - hy0)
    return sample_points(np.ascontiguousarray(head_d.transport), u, v)


def blend_weight(body, head_full: np.ndarray) -> np.ndarray:
    """[h, w] on the body's grid: 1 on the head mask, ramped out over FEATHER of the head's size."""
    from relight.imaging.resample import resize_linear
    from relight.person.mask_ops import box_mean, dilate

    y0, y1, x0, x1 = body.box
    h, w = body.working_size
    inside = resize_linear(np.ascontiguousarray(head_full[y0:y1, x0:x1]), h, w) > HEAD
    if not inside.any():
        return np.zeros((h, w), np.float32)
    ys, xs = np.nonzero(inside)
    r = max(1, int(round(FEATHER * max(np.ptp(ys) + 1, np.ptp(xs) + 1) / 2)))
    grown = dilate(inside, r).astype(np.float32)
    return np.clip(np.maximum(box_mean(grown, r), inside), 0.0, 1.0).astype(np.float32)


def fused(body, transport: np.ndarray, weight: np.ndarray):
    """The body's decomposition with `transport` blended in by `weight`, the body's light kept, the
    albedo following by the one rule."""
    t = body.transport * (1 - weight[..., None]) + transport * weight[..., None]
    return body.with_light(body.light, t.astype(np.float32))


def true_transports(body, scene) -> tuple[np.ndarray, np.ndarray]:
    """The scene's transport and the lobe of its normals (the body's visibility) on the body's grid."""
    from relight.network.face_relight import UNOCCLUDED_DC, lobe_transport
    from relight.imaging.resample import resize_linear

    y0, y1, x0, x1 = body.box
    h, w = body.working_size
    t = resize_linear(np.ascontiguousarray(scene.transport[y0:y1, x0:x1]), h, w)
    n = resize_linear(np.ascontiguousarray(scene.normal[y0:y1, x0:x1]), h, w)
    length = np.linalg.norm(n, axis=-1, keepdims=True)
    n = np.where(length > 0.5, n / np.maximum(length, 1e-9), np.float32([0, -1, 0]))
    v = np.clip(body.transport[..., 0] / UNOCCLUDED_DC, 0.0, 1.0)
    return t.astype(np.float32), lobe_transport(n, v, body.sh_order), n


def angles_deg(transport: np.ndarray, normals: np.ndarray, where: np.ndarray) -> float:
    """Median angle (degrees) over `where` between the direction of the transport's band 1,
    (T_11, T_1-1, T_10) = (x, y, z), and the true normals."""
    t = transport[..., 1:4][..., [2, 0, 1]]
    t = t / np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-9)
    return float(np.median(np.degrees(np.arccos(np.clip((t * normals)[where].sum(-1), -1, 1)))))


def srgb(x: np.ndarray) -> np.ndarray:
    x = np.clip(x, 0.0, 1.0)
    return (np.where(x <= 0.0031308, 12.92 * x, 1.055 * np.power(x, 1 / 2.4) - 0.055) * 255 + 0.5).astype(np.uint8)


def study(folder: Path, qualities, margins, threads: int, sheet: Path | None, sheet_quality: str,
          limit: int | None = None):
    from model.scoring import face_region, metrics
    from relight.files.dataset import read_scene
    from relight.network import quality
    from relight.network.runtime import Relighter

    methods = ["baseline"] + [f"head pass, margin {m:g}" for m in margins] + ["ceiling: true T", "ceiling: true n"]
    scores = {q: {k: [] for k in methods} for q in qualities}
    times = {q: {"body": [], **{m: [] for m in margins}} for q in qualities}
    diag = {q: {m: [] for m in ("body", *margins)} for q in qualities}  # (level T_00, normals angle) on the head
    faces, skipped = [], []
    for q in qualities:
        preset = quality.preset(q)
        relighter = Relighter(quality.model_path(preset.key), threads=threads, working_size=preset.working_size)
        options = preset.decompose_options()
        options.pop("matte_method", None)  # the true alpha is the mask: no segmenter
        relighter.decompose(np.full((64, 64, 3), 0.2, np.float32), mask=np.ones((64, 64), np.float32),
                            **options)   # warm the session: the first run's cost is not the pass's
        for js in sorted(folder.glob("scene_*.json"))[:limit]:
            s = read_scene(js)
            alpha = s.alpha[..., 0]
            head = s.head[..., 0]
            weight = metrics.interior_weight(alpha)
            face = face_region.face_weight(weight, head)
            boxes = {m: head_box(head, m, alpha.shape) for m in margins}
            if any(b is None for b in boxes.values()) or (face > 0.5).sum() < face_region.MIN_FACE_PIXELS:
                skipped.append(js.stem)
                continue
            for a in range(len(s.images)):
                photo = np.ascontiguousarray(s.images[a], dtype=np.float32)
                t0 = time.perf_counter()
                body = relighter.decompose(photo, mask=alpha, **options)
                times[q]["body"].append(time.perf_counter() - t0)
                w = blend_weight(body, head)
                true_t, true_n, normals = true_transports(body, s)
                on_head = (w > 0.999) & (body.alpha > 0.999)
                level = lambda t: float(np.median(t[..., 0][on_head] / np.maximum(true_t[..., 0][on_head], 1e-6)))
                diag[q]["body"].append((level(body.transport), angles_deg(body.transport, normals, on_head)))
                answers = {"baseline": body}
                for m in margins:
                    y0, y1, x0, x1 = boxes[m]
                    t0 = time.perf_counter()
                    hd = relighter.decompose(np.ascontiguousarray(photo[y0:y1, x0:x1]),
                                             mask=np.ascontiguousarray(alpha[y0:y1, x0:x1]), **options)
                    times[q][m].append(time.perf_counter() - t0)
                    t = head_in_body_frame(body, hd, (y0, x0))
                    covered = head_in_body_frame(body, _Ones(hd), (y0, x0))[..., 0] > 0.999
                    answers[f"head pass, margin {m:g}"] = fused(body, t, w * covered)
                    diag[q][m].append((level(t), angles_deg(t, normals, on_head & covered)))
                answers["ceiling: true T"] = fused(body, true_t, w)
                answers["ceiling: true n"] = fused(body, true_n, w)
                for b in range(len(s.images)):
                    if b == a:
                        continue
                    L = np.asarray(s.lights[b]["sh"], np.float64)
                    truth = np.asarray(s.images[b], np.float32)
                    relit = {k: d.relight(L) for k, d in answers.items()}
                    for k, x in relit.items():
                        scores[q][k].append((metrics.psnr(x, truth, weight),
                                             metrics.scale_invariant_psnr(x, truth, weight),
                                             metrics.psnr(x, truth, face)))
                    if sheet is not None and q == sheet_quality and b == (a + 1) % len(s.images) and a == 0:
                        faces.append((boxes[margins[0]], photo, truth, [relit[k] for k in methods]))
    if sheet is not None and faces:
        contact_sheet(faces, sheet, ["photo (light a)", "truth (light b)"] + methods + ["4x (head - base)"])
    return methods, scores, times, diag, skipped


class _Ones:
    """A stand-in for a head run whose transport is all ones: where the head run's crop covers."""

    def __init__(self, d):
        self.box, self.working_size = d.box, d.working_size
        self.transport = np.ones((*d.working_size, 1), np.float32)


def contact_sheet(faces, path: Path, labels, tile: int = 112) -> None:
    """Rows: scenes (light a -> the next light); columns: the photo, the truth, each answer, and the
    first head pass minus the baseline (x4 about 0.5 grey, linear); each tile the head's box (the
    first margin), sRGB, nearest-neighbour to `tile` px."""
    from PIL import Image, ImageDraw

    rows = []
    for (y0, y1, x0, x1), photo, truth, relit in faces:
        tiles = []
        change = 0.5 + 4 * (relit[1] - relit[0])  # the first head pass against the baseline, x4 about grey
        for img in [photo, truth, *relit, change]:
            crop = Image.fromarray(srgb(img[y0:y1, x0:x1]))
            s = tile / max(y1 - y0, x1 - x0)
            crop = crop.resize((max(1, round((x1 - x0) * s)), max(1, round((y1 - y0) * s))), Image.NEAREST)
            canvas = Image.new("RGB", (tile, tile))
            canvas.paste(crop, ((tile - crop.width) // 2, (tile - crop.height) // 2))
            tiles.append(np.asarray(canvas))
        rows.append(np.concatenate(tiles, axis=1))
    grid = np.concatenate(rows, axis=0)
    head = Image.new("RGB", (grid.shape[1], 14), (255, 255, 255))
    draw = ImageDraw.Draw(head)
    for i, label in enumerate(labels):
        draw.text((i * tile + 2, 1), label.replace("head pass, margin", "head").replace("ceiling: ", "")[:18],
                  fill=(0, 0, 0))
    path.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(np.concatenate([np.asarray(head), grid], axis=0)).save(path)
    print(f"contact sheet: {path}")


def table(folder: Path, methods, scores, times) -> str:
    lines = [f"{folder.name}: relit / SI / face PSNR (dB, mean over pairs); the difference to the baseline "
             "(paired, +- SE over pairs)", "",
             "| quality | answer | pairs | relit | SI | face | relit - baseline | SI - baseline | face - baseline |",
             "|---|---|---|---|---|---|---|---|---|"]
    for q, per in scores.items():
        base = np.array(per["baseline"])
        for k in methods:
            r = np.array(per[k])
            if not len(r):
                continue
            cells = []
            for j in range(3):
                diff = r[:, j] - base[:, j]
                se = diff.std(ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else float("nan")
                cells.append("-" if k == "baseline" else f"{diff.mean():+.2f} +- {se:.2f}")
            lines.append(f"| {q} | {k} | {len(r)} | {r[:, 0].mean():.2f} | {r[:, 1].mean():.2f} | "
                         f"{r[:, 2].mean():.2f} | " + " | ".join(cells) + " |")
    lines.append("")
    for q, t in times.items():
        body = 1000 * np.median(t["body"]) if t["body"] else float("nan")
        extra = ", ".join(f"margin {m:g}: {1000 * np.median(v):.0f} ms" for m, v in t.items() if m != "body" and v)
        lines.append(f"- {q}: the body's decomposition {body:.0f} ms per photo (median); the head pass {extra}")
    return "\n".join(lines)


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("folder", type=Path, help="a farm held-out set with head masks (data/heldout37_hs)")
    p.add_argument("--qualities", default="draft,best", help="quality presets, comma-separated")
    p.add_argument("--margins", default="0.25,0.5", help="head box margins (of its longer side), comma-separated")
    p.add_argument("--threads", type=int, default=2)
    p.add_argument("--sheet", type=Path, default=None, help="PNG contact sheet of the faces (light 0 -> 1)")
    p.add_argument("--sheet-quality", default="best")
    p.add_argument("--scenes", type=int, default=None, help="only the first N scenes (a quick look)")
    a = p.parse_args(argv)
    qualities = [q.strip() for q in a.qualities.split(",")]
    margins = [float(m) for m in a.margins.split(",")]
    methods, scores, times, diag, skipped = study(a.folder, qualities, margins, a.threads, a.sheet,
                                             a.sheet_quality, a.scenes)
    print(table(a.folder, methods, scores, times))
    for q, per in diag.items():
        print(f"- {q}, over the head (median per photo, then mean): T_00 / true T_00 and the normals' angle "
              "(band 1 of T) to the truth: " + "; ".join(
                  f"{'body' if m == 'body' else f'head pass {m:g}'} {np.mean([x[0] for x in v]):.2f}, "
                  f"{np.mean([x[1] for x in v]):.1f} deg" for m, v in per.items()))
    print(f"skipped (no head mask or no face pixels): {skipped or 'none'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
