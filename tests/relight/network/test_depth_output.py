"""A model with the depth head through the runtime (issue 45): the graph's depth reaches the
Decomposition (cropped and resized as the other outputs are) and the cast shadows' depth; a model
without the head keeps the integrated relief."""

from __future__ import annotations

import numpy as np
import pytest

from relight.geometry.relief import depth_from_normals, normals_from_transport, scaled_to_normals
from relight.lighting.lamps import sun_light
from relight.network.runtime import Relighter
from relight.network.shadowing import ShadowCaster

GEOMETRY = dict(arch="geometry", sh_order=4, width=4, depth=2, decoder_width=4)

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")  # torch's TorchScript exporter


@pytest.fixture(scope="module")
def models(tmp_path_factory):
    import subprocess
    import sys
    import textwrap
    from pathlib import Path

    folder = tmp_path_factory.mktemp("depth_models")
    code = textwrap.dedent(f"""
        from export.random_model import export_random_model
        export_random_model({str(folder / 'head.onnx')!r}, seed=4, depth_head=True, **{GEOMETRY!r})
        export_random_model({str(folder / 'plain.onnx')!r}, seed=11, **{GEOMETRY!r})
    """)  # a child process: torch stays out of the runtime's
    subprocess.run([sys.executable, "-c", code], cwd=Path(__file__).resolve().parents[3], check=True,
                   capture_output=True, timeout=300)
    return folder / "head.onnx", folder / "plain.onnx"


def _photo():
    """A 90 x 70 linear photo: a lit disc (the person, its mask given) over a darker ground."""
    rows, cols = np.mgrid[0:90, 0:70]
    disc = ((rows - 45) / 30.0) ** 2 + ((cols - 35) / 22.0) ** 2 < 1
    rng = np.random.default_rng(2)
    photo = np.where(disc[..., None], 0.5, 0.1) * (0.8 + 0.4 * rng.uniform(size=(90, 70, 3)))
    return photo.astype(np.float32), disc.astype(np.float32)


def test_the_networks_depth_flows_to_the_shadow_relief(models):
    head, plain = models
    photo, mask = _photo()
    r = Relighter(head, threads=1, working_size=48)
    d = r.decompose(photo, mask=mask, augment=(), refine=0, ensemble=(), level=False)
    h, w = d.working_size
    assert d.depth is not None and d.depth.shape == (h, w) == d.alpha.shape
    # the graph's own answer on the decomposition's crop (run_crop: padded, run, unpadded)
    direct = r.run_crop(d.photo_working, np.clip(d.alpha, 0, 1))["depth"][..., 0]
    assert np.array_equal(d.depth, direct)
    assert d.shadows.network_depth is d.depth
    inside = d.alpha > 0
    normals = normals_from_transport(d.transport)
    fitted = scaled_to_normals(d.depth, normals, inside)
    want = depth_from_normals(normals, inside) if fitted is None else fitted
    assert np.array_equal(d.shadows.depth, want)
    assert d.shadows.depth_source == ("relief" if fitted is None else "network")
    # random weights: the depth's sign against the normals' slopes is chance (seed 4: 51 % of 2,121
    # pairs agree); one of the depth and its negative runs their way, and the shadows then use it
    flipped = ShadowCaster(d.transport, d.alpha, np.arange(h * w), network_depth=-d.depth)
    flipped.depth  # made on first use, as a relight makes it
    assert "network" in (d.shadows.depth_source, flipped.depth_source)
    for c in (d.shadows, flipped):
        if c.depth_source == "network":
            assert np.array_equal(c.depth, scaled_to_normals(c.network_depth, normals, inside))
            assert not np.array_equal(c.depth, depth_from_normals(normals, inside))
    # a light's change keeps it (with_light: the same crop, another light)
    assert d.with_light(d.light).shadows.network_depth is d.depth
    relit = d.relight(sun_light(90.0, 10.0, 5.0, 4), shadows=True)
    assert np.all(np.isfinite(relit))
    p = Relighter(plain, threads=1, working_size=48).decompose(photo, mask=mask, augment=(), refine=0, ensemble=(),
                                                                level=False)
    assert p.depth is None
    assert np.array_equal(p.shadows.depth, depth_from_normals(normals_from_transport(p.transport), p.alpha > 0))
    assert p.shadows.depth_source == "relief"
