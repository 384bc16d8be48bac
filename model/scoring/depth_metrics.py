"""The depth head's error against the farm's depth pass (issue 45), as model.evaluate reports it.

A single photo fixes depth only up to scale and shift, so a depth d is first aligned to the true
depth t (metres along the view axis) by least squares over the person's pixels (weight w > 0):
a d + b with a >= 0 (a depth turned inside out is not credited: it is scored as a flat one).
Then, per pair:

  absrel      mean_w |a d + b - t| / t       (the usual relative absolute error; small for a person
                                              2-5 m away whatever the shape: read with `shape`)
  absrel_med  its weighted median
  shape       mean_w |a d + b - t| / mean_w |t - mean_w t|: the error as a share of the person's own
              depth relief (0: exact; 1: no better than a flat depth)

Rows: the network's depth, and the relief integrated from its normals (relight.geometry.relief:
what the cast shadows use without the head), aligned alike. numpy, float64.
"""

from __future__ import annotations

import numpy as np

from relight.geometry.relief import depth_from_normals, normals_from_transport

KEYS = ("absrel", "absrel_med", "shape")
ROWS = ("network depth", "relief of its normals")


def _weighted_median(x: np.ndarray, w: np.ndarray) -> float:
    order = np.argsort(x)
    cum = np.cumsum(w[order])
    return float(x[order][np.searchsorted(cum, 0.5 * cum[-1])])


def depth_errors(depth: np.ndarray, truth: np.ndarray, weight: np.ndarray) -> dict | None:
    """The module docstring's errors of `depth` [h, w] against `truth` [h, w] (> 0 on the person)
    over `weight` [h, w]; None when fewer than 3 pixels count."""
    d, t, w = (np.asarray(a, np.float64).reshape(-1) for a in (depth, truth, weight))
    keep = (w > 0) & (t > 0) & np.isfinite(d)
    if keep.sum() < 3:
        return None
    d, t, w = d[keep], t[keep], w[keep]
    dm, tm = (d * w).sum() / w.sum(), (t * w).sum() / w.sum()
    var = ((d - dm) ** 2 * w).sum()
    a = max(((d - dm) * (t - tm) * w).sum() / var, 0.0) if var > 0 else 0.0
    err = np.abs(a * (d - dm) + tm - t)
    spread = (np.abs(t - tm) * w).sum() / w.sum()
    return {"absrel": float((err / t * w).sum() / w.sum()), "absrel_med": _weighted_median(err / t, w),
            "shape": float((err * w).sum() / w.sum() / spread) if spread > 0 else float("nan")}


def pair_depth_rows(pred: dict, sample: dict, weight: np.ndarray) -> dict[str, dict] | None:
    """{row: errors} of one pair (pred["depth"] [1, h, w], pred["transport"] [n, h, w]; the sample's
    "depth" [1, h, w] and "alpha"), or None when the model has no depth or the sample no truth."""
    if "depth" not in pred or "depth" not in sample:
        return None
    truth = sample["depth"][0]
    inside = sample["alpha"][0] > 0
    relief = depth_from_normals(normals_from_transport(np.moveaxis(pred["transport"], 0, -1)), inside)
    rows = {ROWS[0]: depth_errors(pred["depth"][0], truth, weight),
            ROWS[1]: depth_errors(relief, truth, weight)}
    return None if any(v is None for v in rows.values()) else rows


def depth_table(records: dict[str, list[dict]]) -> dict:
    """{framing: {row: {"pairs", key: mean over the pairs}}} of pair_depth_rows' answers by framing."""
    out: dict = {}
    for framing, pairs in sorted(records.items()):
        for row in ROWS:
            values = [p[row] for p in pairs]
            out.setdefault(framing, {})[row] = {"pairs": len(values),
                                                **{k: float(np.mean([v[k] for v in values])) for k in KEYS}}
    return out


def depth_markdown(table: dict) -> str:
    lines = ["\n## Depth, per framing\n",
             "The network's depth against the farm's depth pass, each aligned by least squares (scale >= 0, "
             "shift) over the person's pixels: mean and median relative absolute error, and the error as a "
             "share of the person's own depth relief (1 = a flat depth; model.scoring.depth_metrics).\n",
             "| framing | depth | pairs | AbsRel | AbsRel median | share of the relief |", "|---|---|---|---|---|---|"]
    for framing, rows in table.items():
        for row, v in rows.items():
            lines.append(f"| {framing} | {row} | {v['pairs']} | {v['absrel']:.4f} | {v['absrel_med']:.4f} | "
                         f"{v['shape']:.3f} |")
    return "\n".join(lines) + "\n"
