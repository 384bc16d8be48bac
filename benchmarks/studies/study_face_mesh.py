"""Issue 37, the face mesh: how much the face's own mesh (relight.network.face_mesh, relight.network.face_relight)
changes the relit faces of the bundled real photos. Not run by the tests.

    .venv/bin/python benchmarks/studies/study_face_mesh.py [--quality best] [--out out/face_mesh]

Per photo: the decomposition at the preset, the face layer, and
* recon: PSNR (dB) over the face (the layer's weight > 0.5) of the photo re-rendered under its own
  light, network alone against with the face layer (the albedo rule makes both near the photo;
  they differ where the albedo clips at 1);
* skin: PSNR over the face of the photo against one albedo per channel (least squares) times the
  shading T . L, network against mesh: how well each geometry explains the photo's shading with a
  uniform skin (eyes, brows, lips and shadows count against both alike);
* the relit faces under a white directional light from 90 and 270 degrees, before and after, in
  OUT/faces_<quality>.png (zooms), and the mirror check: a face under 90 against the mirrored
  photo's face under 270, mirrored back (relative RMS over the face box).
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))

PHOTOS = ("relight/data/examples/astronaut.jpg", "evaluation/data/matte_eval/grace_hopper.jpg",
          "evaluation/data/matte_eval/obama_standing.jpg", "evaluation/data/matte_eval/obama.jpg",
          "evaluation/data/matte_eval/biden.jpg")
ANGLES = (90.0, 270.0)


def psnr(a, b, w) -> float:
    mse = float((((a - b) ** 2).mean(axis=-1) * w).sum() / max(w.sum(), 1e-9))
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def grid_of(layer, full: np.ndarray) -> np.ndarray:
    from relight.imaging.resample import resize_linear

    y0, y1, x0, x1 = layer.box
    return resize_linear(np.ascontiguousarray(full[y0:y1, x0:x1]), *layer.weight.shape)


def skin_psnr(photo_g, shading_g, w) -> float:
    a = (photo_g * shading_g * w[..., None]).sum(axis=(0, 1)) / np.maximum(
        (shading_g ** 2 * w[..., None]).sum(axis=(0, 1)), 1e-12)
    return psnr(photo_g, shading_g * a, w)


def zoom(img, box, side=160):
    from PIL import Image

    from relight.imaging.colour import srgb_encode

    y0, y1, x0, x1 = box
    cut = srgb_encode(np.clip(img[y0:y1, x0:x1], 0, 1))
    im = Image.fromarray((cut * 255 + 0.5).astype(np.uint8)).resize((side, round(side * (y1 - y0) / (x1 - x0))))
    return np.asarray(im)


def write_crops(folder: Path) -> int:
    """The landmark network's input for each photo's face (tools/check_matte_onnx.py compares the
    ONNX network with the TFLite original on them)."""
    from PIL import Image

    from relight.network import face_mesh
    from relight.person import matte
    from relight.files import photo as photo_io
    from relight.imaging.colour import srgb_encode

    folder.mkdir(parents=True, exist_ok=True)
    for path in PHOTOS:
        photo, _ = photo_io.read_photo(path)
        mesh = face_mesh.find_face(photo, matte.person_matte(photo, threads=2).alpha, threads=2)
        crop = face_mesh.crop(srgb_encode(np.clip(photo, 0, 1)).astype(np.float32), mesh.roi)
        Image.fromarray((crop * 255 + 0.5).astype(np.uint8)).save(folder / f"{Path(path).stem}.png")
    return 0


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("--quality", default="best")
    p.add_argument("--out", type=Path, default=Path("out/face_mesh"))
    p.add_argument("--visibility", default="network", choices=("network", "none"))
    p.add_argument("--light", default="face", choices=("face", "network"),
                   help="the photo's light in the face: refitted to it with the mesh (face) or the network's")
    p.add_argument("--crops", type=Path, default=None,
                   help="only write each photo's last face crop (the landmark network's input) as PNG here")
    args = p.parse_args(argv)
    if args.crops is not None:
        return write_crops(args.crops)
    from PIL import Image

    from relight.network import face_relight
    from relight.files import photo as photo_io
    from relight.network import quality
    from relight.lighting.light import directional_light
    from relight.network.runtime import Relighter

    preset = quality.preset(args.quality)
    relighter = Relighter(quality.model_path(preset.key), threads=2, working_size=preset.working_size)
    rows, sheet = [], []
    for path in PHOTOS:
        name = Path(path).stem
        photo, _ = photo_io.read_photo(path)
        rowimgs = []
        mirror_rms = []
        for mirrored in (False, True):
            img = np.ascontiguousarray(photo[:, ::-1]) if mirrored else photo
            d = relighter.decompose(img, **preset.decompose_options())
            t = time.perf_counter()
            layer = face_relight.face_layer(d, threads=2, visibility=args.visibility, refit=args.light == "face")
            ms = (time.perf_counter() - t) * 1e3
            if layer is None:
                print(f"{name}: no face layer")
                break
            w = (layer.weight > 0.5).astype(np.float32)
            pg = grid_of(layer, d.photo)
            own = d.relight(d.light)
            after = layer.apply(d.photo, layer.light, layer.light, own.copy())
            recon = (psnr(grid_of(layer, own), pg, w), psnr(grid_of(layer, after), pg, w))
            net = face_relight.on_grid(d, d.transport @ d.light, layer.box, layer.weight.shape)
            skin = (skin_psnr(pg, net, w), skin_psnr(pg, layer.shading(d.light), w), skin_psnr(pg, layer.shading(layer.light), w))
            y0, y1, x0, x1 = layer.box
            pad = (y1 - y0) // 4
            zbox = (max(y0 - pad, 0), min(y1 + pad // 2, photo.shape[0]), max(x0 - pad, 0), min(x1 + pad, photo.shape[1]))
            relit = {}
            for a in ANGLES:
                L = directional_light(a, d.sh_order)
                before = d.relight(L)
                relit[a] = (before, layer.apply(d.photo, layer.light, d.fit_light(L), before.copy()))
            if not mirrored:
                rows.append((name, d.choices.get("augment"), round(layer.mesh.width), ms, *recon, *skin))
                rowimgs = [zoom(d.photo, zbox)] + [zoom(relit[a][k], zbox) for a in ANGLES for k in (0, 1)]
                keep = (zbox, relit)
            else:
                zb = keep[0]
                for k in (0, 1):  # face under 90 against the mirrored photo's under 270, mirrored back
                    a0 = keep[1][90.0][k][zb[0]:zb[1], zb[2]:zb[3]]
                    b0 = relit[270.0][k][:, ::-1][zb[0]:zb[1], zb[2]:zb[3]]
                    mirror_rms.append(float(np.sqrt(((a0 - b0) ** 2).mean() / max((a0 ** 2).mean(), 1e-12))))
                rows[-1] = rows[-1] + tuple(mirror_rms)
        if rowimgs:
            hh = max(i.shape[0] for i in rowimgs)
            sheet.append(np.concatenate([np.pad(i, ((0, hh - i.shape[0]), (0, 4), (0, 0))) for i in rowimgs], 1))
    args.out.mkdir(parents=True, exist_ok=True)
    wmax = max(s.shape[1] for s in sheet)
    pic = np.concatenate([np.pad(s, ((0, 4), (0, wmax - s.shape[1]), (0, 0))) for s in sheet], 0)
    out = args.out / f"faces_{args.quality}_{args.light}_light.png"
    Image.fromarray(pic).save(out)
    print(f"{out}: columns photo | 90 before | 90 after | 270 before | 270 after")
    print("| photo | face px | layer ms | recon net | recon mesh | skin net | skin mesh, network's light | skin mesh, face light | mirror net | mirror mesh |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        name, _aug, width, ms, *vals = r
        print(f"| {name} | {width} | {ms:.0f} | " + " | ".join(f"{v:.2f}" for v in vals[:5]) + " | "
              + " | ".join(f"{v:.3f}" for v in vals[5:]) + " |")
    return 0


if __name__ == "__main__":
    sys.exit(main())
