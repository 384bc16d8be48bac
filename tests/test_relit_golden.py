"""Golden outputs: the shipped model's relit photos must not change under refactoring.

tests/data/relit_golden.npz was written by this file's `compute()` from the code
before issue 19's refactor (`.venv/bin/python tests/test_relit_golden.py --write`).
For the two bundled photos x two lights (a preset turned and exposed, and the other
photo's estimated light turned) it holds the SHA-256 of the full float32 relit frame
and of the --layers maps, and every 16th pixel of the 8-bit sRGB output (to see where
a difference is when a hash no longer matches). The hashes are exact: one thread,
the shipped geometry model, the installed onnxruntime and numpy.
"""

from __future__ import annotations

import hashlib
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
GOLDEN = ROOT / "tests" / "data" / "relit_golden.npz"
PHOTOS = ("astronaut.jpg", "grace_hopper.jpg")


def _sha(a: np.ndarray) -> str:
    return hashlib.sha256(np.ascontiguousarray(a).tobytes()).hexdigest()


def _srgb8(linear: np.ndarray) -> np.ndarray:
    from relight.colour import srgb_encode

    return np.round(np.clip(srgb_encode(np.clip(linear, 0.0, 1.0)), 0.0, 1.0) * 255).astype(np.uint8)


def compute() -> dict[str, np.ndarray]:
    """{name: array} of the relit outputs (hashes as 0-d string arrays)."""
    from relight import light
    from relight.photo import read_photo
    from relight.runtime import Relighter

    r = Relighter(threads=1, working_size="balanced")
    decs = {}
    for name in PHOTOS:
        photo, _ = read_photo(ROOT / "relight" / "data" / "examples" / name)
        decs[name] = r.decompose(photo, matte="person")
    out = {}
    for i, name in enumerate(PHOTOS):
        d = decs[name]
        other = decs[PHOTOS[1 - i]]
        cases = {
            "studio": (light.sh_light("studio", d.sh_order, rotation_deg=90.0), 0.5),
            "transfer": (light.sh_light(other, d.sh_order, rotation_deg=30.0), 0.0),
        }
        for case, (L, ev) in cases.items():
            relit = d.relight(L, exposure_ev=ev)
            key = f"{Path(name).stem}_{case}"
            out[key + "_sha"] = np.array(_sha(relit))
            out[key + "_srgb8"] = _srgb8(relit)[::16, ::16]
        layers = d.layers(cases["studio"][0], exposure_ev=0.5)
        for layer in ("albedo", "shading", "residual", "alpha"):
            out[f"{Path(name).stem}_layer_{layer}_sha"] = np.array(_sha(layers[layer]))
    return out


def test_relit_outputs_are_bit_identical_to_the_golden_file():
    golden = np.load(GOLDEN)
    now = compute()
    assert sorted(now) == sorted(golden.files)
    for key in sorted(now):
        if key.endswith("_srgb8"):
            diff = np.abs(now[key].astype(int) - golden[key].astype(int))
            assert diff.max() == 0, f"{key}: {np.count_nonzero(diff)} sRGB values differ, up to {diff.max()}"
    for key in sorted(now):
        if key.endswith("_sha"):
            assert str(now[key]) == str(golden[key]), f"{key}: the float32 output changed"


if __name__ == "__main__":
    if sys.argv[1:] != ["--write"]:
        raise SystemExit("usage: tests/test_relit_golden.py --write")
    sys.path.insert(0, str(ROOT))
    GOLDEN.parent.mkdir(exist_ok=True)
    np.savez_compressed(GOLDEN, **compute())
    print(f"wrote {GOLDEN} ({GOLDEN.stat().st_size:,} bytes)")
