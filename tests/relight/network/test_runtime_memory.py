"""A 24-megapixel photo goes through `relight image` in bounded memory (peak RSS < 2 GB)."""

from __future__ import annotations

import subprocess
import sys

import numpy as np
from PIL import Image

from export.random_model import export_random_model
from peak_memory import CHILD, LIMIT_BYTES

def test_24_megapixel_photo_stays_under_2_gb(tmp_path):
    model, _, _ = export_random_model(tmp_path / "m.onnx", seed=2, sh_order=4, width=4, depth=2)
    h, w = 6000, 4000
    y = np.linspace(40, 200, h, dtype=np.float32)[:, None]
    x = np.linspace(0, 50, w, dtype=np.float32)[None, :]
    rgb = np.empty((h, w, 3), np.uint8)
    for c in range(3):
        rgb[..., c] = (y + x * (c - 1)).clip(0, 255).astype(np.uint8)
    Image.fromarray(rgb).save(tmp_path / "big.jpg", quality=85)
    del rgb
    out = tmp_path / "big_relit.png"
    res = subprocess.run([sys.executable, "-c", CHILD, "image", str(tmp_path / "big.jpg"), "--light", "studio",
                          "--model", str(model), "--out", str(out), "--threads", "2",
                          "--matte", "network"],  # a gradient shows no person; tests/relight/person/test_matte.py: the matte's run
                         capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    peak = int(res.stdout.split("PEAK_RSS_BYTES")[1].split()[0])
    assert peak < LIMIT_BYTES, f"peak RSS {peak / 2**20:.0f} MiB"
    with Image.open(out) as im:
        assert im.size == (w, h)
