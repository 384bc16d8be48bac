"""Golden outputs: the shipped model's relit photos must not change under refactoring,
on any x86-64 CPU.

tests/data/relit_golden.npz is written by this file (`.venv/bin/python
tests/relight/network/test_relit_golden.py --write`). For the two bundled photos it holds the
person matte, and, with that matte as the mask, the photo's estimated light, the
relit frames under two lights (a preset turned and exposed, and the other photo's
estimated light turned: every 4th pixel plus the whole frame's mean) and the
--layers maps (every 4th pixel).

Why tolerances, not hashes: onnxruntime and numpy choose kernels by instruction set
(AVX2, AVX-512, Intel or AMD), so the last bits of float32 results differ between
machines. Two parts of the pipeline behave differently under such rounding:

- Network, physics and relighting, given a mask, are continuous. Each convolution
  or matrix product of fan-in n is computed with an error of at most gamma_n = n u / (1 - n u)
  (u = 2^-24) times the scale of its operands (the standard dot-product bound); to
  first order the graph's error is the sum over its layers, and two implementations
  differ by at most twice that. `graph_rounding_bound` sums the fan-ins of the shipped
  graph's Conv/Gemm/MatMul weights (20,026: bound 2.4e-3 of each array's peak), plus
  gamma_26 for the 25-term SH dot product of the relight. Measured across kernel
  paths here (numpy without AVX/AVX2/AVX-512, onnxruntime without graph fusions,
  Python 3.13 with numpy 2): at most 4e-6 of the peak.
- The person matte is piecewise continuous: a probability compared with 0.5 and a
  binary dilation flip whole pixels when rounding moves a value across the threshold
  (measured here: up to 145 pixels of a 512 x 512 matte, 0.13% of the person, change
  by up to 0.24 between kernel paths). So the matte is compared by what such flips
  can change: its box, its IoU at 0.5, and the share of pixels off by more than one
  8-bit level; and the rest of the pipeline takes the stored matte as its mask.

8-bit outputs are not exact either: their float source is only known within the bound.
sRGB encoding and rounding are monotone, so the 8-bit value must lie between the 8-bit
values of (reference - bound) and (reference + bound): that interval test is exact.
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[3]
GOLDEN = ROOT / "tests" / "data" / "relit_golden.npz"
PHOTOS = ("astronaut.jpg", "grace_hopper.jpg")
STEP = 4                  # every 4th pixel of the full-resolution frames is kept
U = 2.0 ** -24            # float32 unit roundoff
SH_TERMS = 25             # order-4 SH dot product of the relight, plus the residual's term
# the matte's flips (module docstring): 4x the largest share measured across kernel paths
MATTE_FLIP_SHARE = 0.005
MATTE_IOU = 0.999
MATTE_BOX_SLACK = 2       # px: a flip at the person's extremity moves the box edge


def _gamma(n: int) -> float:
    return n * U / (1 - n * U)


def graph_fan_ins(onnx_path: Path) -> list[int]:
    """Fan-in (inputs summed per output value) of every Conv, Gemm and MatMul with a weight tensor."""
    import onnx

    graph = onnx.load(str(onnx_path)).graph
    weights = {t.name: list(t.dims) for t in graph.initializer}
    fan_ins = []
    for node in graph.node:
        if node.op_type not in ("Conv", "Gemm", "MatMul") or len(node.input) < 2 or node.input[1] not in weights:
            continue
        dims = weights[node.input[1]]
        fan_ins.append(int(np.prod(dims[1:])) if node.op_type == "Conv" else dims[0])
    return fan_ins


def graph_rounding_bound(fan_ins: list[int]) -> float:
    """Norm-wise relative difference two float32 implementations of the pipeline may show."""
    return 2.0 * (sum(_gamma(n) for n in fan_ins) + _gamma(SH_TERMS + 1))


def _srgb8(linear: np.ndarray) -> np.ndarray:
    from relight.imaging.colour import srgb_encode

    return np.round(np.clip(srgb_encode(np.clip(linear, 0.0, 1.0)), 0.0, 1.0) * 255).astype(np.int16)


def compute_mattes(threads: int = 1) -> dict[str, np.ndarray]:
    from relight.person.matte import person_matte
    from relight.files.photo import read_photo

    out = {}
    for name in PHOTOS:
        m = person_matte(read_photo(ROOT / "relight" / "data" / "examples" / name)[0], threads=threads)
        out[f"{Path(name).stem}_matte"] = m.alpha
        b = m.box  # stored in the golden file as (x0, y0, x1, y1)
        out[f"{Path(name).stem}_matte_box"] = np.array([b.x0, b.y0, b.x1, b.y1])
    return out


def compute(mattes: dict[str, np.ndarray], threads: int = 1) -> dict[str, np.ndarray]:
    """{name: array} of the outputs compared, with `mattes` as the masks."""
    from relight.lighting import light
    from relight.files.photo import read_photo
    from relight.network.quality import preset
    from relight.network.runtime import Relighter

    r = Relighter(threads=threads, working_size=preset("balanced").working_size)
    decs = {}
    for name in PHOTOS:
        photo, _ = read_photo(ROOT / "relight" / "data" / "examples" / name)
        decs[name] = r.decompose(photo, mattes[f"{Path(name).stem}_matte"], augment=())  # the network once, as recorded
    out = {}
    for i, name in enumerate(PHOTOS):
        d, stem = decs[name], Path(name).stem
        other = decs[PHOTOS[1 - i]]
        out[f"{stem}_light"] = d.light
        cases = {
            "studio": (light.sh_light("studio", d.sh_order, rotation_deg=90.0), 0.5),
            "transfer": (light.sh_light(other, d.sh_order, rotation_deg=30.0), 0.0),
        }
        for case, (L, ev) in cases.items():
            relit = d.relight(L, exposure_ev=ev)
            out[f"{stem}_{case}"] = relit[::STEP, ::STEP]
            out[f"{stem}_{case}_mean"] = relit.mean(axis=(0, 1), dtype=np.float64)
        layers = d.layers(cases["studio"][0], exposure_ev=0.5)
        for layer in ("albedo", "shading", "residual", "alpha"):
            out[f"{stem}_layer_{layer}"] = layers[layer][::STEP, ::STEP]
    return out


def _golden():
    golden = np.load(GOLDEN)
    mattes = {k: golden[k] for k in golden.files if "_matte" in k}
    return golden, mattes


def _check_outputs(now: dict, golden, bound: float) -> None:
    assert sorted(now) == sorted(k for k in golden.files if "_matte" not in k and k != "fan_ins")
    for key in sorted(now):
        ref = golden[key].astype(np.float64)
        tol = bound * np.abs(ref).max()
        diff = np.abs(now[key] - ref).max()
        assert diff <= tol, f"{key}: differs by {diff:.3g}, more than float32 rounding allows ({tol:.3g})"
        if key.endswith(("_studio", "_transfer")):  # the 8-bit output a user sees
            lo, hi, got = _srgb8(ref - tol), _srgb8(ref + tol), _srgb8(now[key])
            assert np.all((lo <= got) & (got <= hi)), f"{key}: an 8-bit value outside its float interval"


def _check_mattes(now: dict, golden) -> None:
    for name in PHOTOS:
        key = f"{Path(name).stem}_matte"
        ref, got = golden[key], now[key]
        assert got.shape == ref.shape
        box_shift = np.abs(now[key + "_box"] - golden[key + "_box"]).max()
        assert box_shift <= MATTE_BOX_SLACK, f"{key}: box moved by {box_shift} px"
        a, b = got > 0.5, ref > 0.5
        iou = np.count_nonzero(a & b) / np.count_nonzero(a | b)
        assert iou >= MATTE_IOU, f"{key}: IoU {iou:.5f} with the golden matte"
        flipped = np.count_nonzero(np.abs(got - ref) > 1.0 / 255) / np.count_nonzero(b)
        assert flipped <= MATTE_FLIP_SHARE, f"{key}: {flipped:.2%} of the person's pixels changed"


def test_stored_bound_is_the_shipped_graphs():
    """The bound the comparisons use is the shipped ONNX graph's, recomputed here."""
    golden, _ = _golden()
    fan_ins = graph_fan_ins(ROOT / "relight" / "models" / "geometry.onnx")
    assert fan_ins == golden["fan_ins"].tolist()
    assert 1e-3 < graph_rounding_bound(fan_ins) < 1e-2  # 20,026 inputs summed in all: 2.4e-3


def test_person_matte_matches_the_golden_matte():
    golden, _ = _golden()
    _check_mattes(compute_mattes(), golden)


def test_relit_outputs_match_the_golden_file_within_float32_rounding():
    golden, mattes = _golden()
    _check_outputs(compute(mattes), golden, graph_rounding_bound(golden["fan_ins"].tolist()))


def _other_kernel_environment() -> dict[str, str]:
    """numpy without its AVX-class kernels: every SIMD extension this numpy dispatches to
    beyond its compiled baseline, so this machine runs the path an older CPU would."""
    try:
        from numpy._core import _multiarray_umath as umath
    except ImportError:  # numpy 1.x
        from numpy.core import _multiarray_umath as umath
    baseline = set(umath.__cpu_baseline__)
    extra = [f for f in umath.__cpu_dispatch__ if umath.__cpu_features__.get(f) and f not in baseline]
    return dict(os.environ, NPY_DISABLE_CPU_FEATURES=" ".join(extra))


_OTHER_PATH = """
import sys
import numpy as np
import onnxruntime as ort
sys.path[:0] = [{root!r}, {tests!r}, {support!r}]
_session = ort.InferenceSession
def _unfused(data, opts=None, **kw):  # onnxruntime without graph fusions: other kernels, other rounding
    opts.graph_optimization_level = ort.GraphOptimizationLevel.ORT_DISABLE_ALL
    return _session(data, opts, **kw)
ort.InferenceSession = _unfused
import test_relit_golden as g
golden, mattes = g._golden()
np.savez(sys.argv[1], **g.compute(mattes), **g.compute_mattes())
"""


def test_golden_holds_on_another_kernel_path(tmp_path):
    """The same comparisons on the kernels another CPU would run: numpy's SIMD dispatch
    off, onnxruntime's fusions off (its own AVX-512/AVX2 choice has no switch)."""
    out = tmp_path / "other.npz"
    code = _OTHER_PATH.format(root=str(ROOT), tests=str(Path(__file__).resolve().parent),
                              support=str(ROOT / "tests" / "support"))
    done = subprocess.run([sys.executable, "-c", code, str(out)], env=_other_kernel_environment(),
                          capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-2000:]
    golden, _ = _golden()
    now = dict(np.load(out))
    _check_mattes(now, golden)
    _check_outputs({k: v for k, v in now.items() if "_matte" not in k}, golden,
                   graph_rounding_bound(golden["fan_ins"].tolist()))


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        raise SystemExit("usage: tests/relight/network/test_relit_golden.py --write")
    sys.path.insert(0, str(ROOT))
    GOLDEN.parent.mkdir(exist_ok=True)
    mattes = compute_mattes()
    np.savez_compressed(GOLDEN, **mattes, **compute(mattes),
                        fan_ins=np.array(graph_fan_ins(ROOT / "relight" / "models" / "geometry.onnx")))
    print(f"wrote {GOLDEN} ({GOLDEN.stat().st_size:,} bytes)")
