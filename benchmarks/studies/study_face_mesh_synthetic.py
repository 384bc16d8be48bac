"""Issue 37, the face mesh on the farm's held-out renders: the relit face (the farm's head mask)
against the path-traced truth, the network alone, with the face mesh's layer (relight.network.face_relight),
and with the truth's normals in the same layer (the ceiling of any face geometry there).
Not run by the tests.

    .venv/bin/python benchmarks/studies/study_face_mesh_synthetic.py data/heldout37_hs [--quality best]

Each scene's light a relights to each other light b (the truth: the scene's render under b; the
light: its SH). Over the face (head mask > 0.5, alpha > 0.99, inside the layer's box): PSNR of
the linear relit image, and scale-invariant (per-channel gains fitted to the truth); the mesh's
normals against the truth's (median angle, degrees, over the mesh's coverage).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[2]))


def psnr(a, b, w, gains=False) -> float:
    if gains:
        g = (a * b * w[..., None]).sum(axis=(0, 1)) / np.maximum((a * a * w[..., None]).sum(axis=(0, 1)), 1e-12)
        a = a * g
    mse = float((((a - b) ** 2).mean(axis=-1) * w).sum() / max(w.sum(), 1e-9))
    return 10 * np.log10(1.0 / max(mse, 1e-12))


def main(argv=None) -> int:
    p = argparse.ArgumentParser()
    p.add_argument("folder", type=Path)
    p.add_argument("--quality", default="best")
    args = p.parse_args(argv)
    from relight.network import face_mesh, face_relight, quality
    from relight.files.dataset import read_scene
    from relight.imaging.resample import resize_linear
    from relight.network.runtime import Relighter

    preset = quality.preset(args.quality)
    relighter = Relighter(quality.model_path(preset.key), threads=2, working_size=preset.working_size)
    rows, angles, skipped = [], [], []
    for js in sorted(args.folder.glob("scene_*.json")):
        s = read_scene(js)
        alpha = s.alpha[..., 0]
        face = ((s.head[..., 0] > 0.5) & (alpha > 0.99)).astype(np.float32)
        for a in range(len(s.images)):
            photo = np.ascontiguousarray(s.images[a], dtype=np.float32)
            d = relighter.decompose(photo, mask=alpha, **preset.decompose_options())
            mesh = face_mesh.find_face(photo, alpha, threads=2)
            if mesh is None or mesh.width < face_relight.MIN_FACE_PX:
                skipped.append(f"{js.stem} light {a}: " + ("no face found" if mesh is None else
                                                           f"face {mesh.width:.0f} px"))
                continue
            layer = face_relight.face_layer(d, threads=2)
            y0, y1, x0, x1 = layer.box
            shape = layer.weight.shape
            normals, covered = face_mesh.rasterize(mesh, layer.box, shape)
            normals, covered = face_relight.fill_holes(normals, covered)
            truth_n = resize_linear(np.ascontiguousarray(s.normal[y0:y1, x0:x1]), *shape)
            length = np.linalg.norm(truth_n, axis=-1, keepdims=True)
            truth_n = np.where(length > 0.5, truth_n / np.maximum(length, 1e-9), layer.normals)  # off the person: the mesh's
            ok = covered & (resize_linear(face[y0:y1, x0:x1, None], *shape)[..., 0] > 0.5)
            if a == 0 and ok.any():
                cos = np.clip((layer.normals * truth_n)[ok].sum(-1), -1, 1)
                # the network's normals: the direction of its transport's band 1, (T_11, T_1-1, T_10) = (x, y, z)
                t = face_relight.on_grid(d, d.transport[..., 1:4], layer.box, shape)[..., [2, 0, 1]]
                t /= np.maximum(np.linalg.norm(t, axis=-1, keepdims=True), 1e-9)
                cos_net = np.clip((t * truth_n)[ok].sum(-1), -1, 1)
                angles.append((float(np.median(np.degrees(np.arccos(cos)))),
                              float(np.median(np.degrees(np.arccos(cos_net))))))
            truth_layer = face_relight.layer_from_normals(d, mesh, layer.box, truth_n, covered, alpha)
            mesh_plain = face_relight.layer_from_normals(d, mesh, layer.box, layer.normals, covered, alpha,
                                                         refit=False)
            truth_plain = face_relight.layer_from_normals(d, mesh, layer.box, truth_n, covered, alpha, refit=False)
            # the ceiling of a whole-head geometry: the truth's normals over all of the head mask
            # (scalp, hair-covered or not, ears), on a grid of the head's box, the network's light
            hy, hx = np.nonzero(face)
            hb = (int(hy.min()), int(hy.max()) + 1, int(hx.min()), int(hx.max()) + 1)
            hs = min(1.0, face_relight.GRID_MAX / max(hb[1] - hb[0], hb[3] - hb[2]))
            hshape = (max(4, round((hb[1] - hb[0]) * hs)), max(4, round((hb[3] - hb[2]) * hs)))
            head_n = resize_linear(np.ascontiguousarray(s.normal[hb[0]:hb[1], hb[2]:hb[3]]), *hshape)
            hlen = np.linalg.norm(head_n, axis=-1, keepdims=True)
            head_cov = (resize_linear(face[hb[0]:hb[1], hb[2]:hb[3], None], *hshape)[..., 0] > 0.5) & (hlen[..., 0] > 0.5)
            head_n = np.where(hlen > 0.5, head_n / np.maximum(hlen, 1e-9), np.float32([0, -1, 0]))
            head_layer = face_relight.layer_from_normals(d, mesh, hb, head_n, head_cov, alpha, refit=False)
            w = face.copy()
            region = np.zeros_like(w)
            region[y0:y1, x0:x1] = 1
            w *= region
            for b in range(len(s.images)):
                if b == a:
                    continue
                L = np.asarray(s.lights[b]["sh"], np.float32)
                truth = np.asarray(s.images[b], np.float32)
                before = d.relight(L)
                after = layer.apply(d.photo, layer.light, d.fit_light(L), before.copy())
                ceiling = truth_layer.apply(d.photo, truth_layer.light, d.fit_light(L), before.copy())
                plain = mesh_plain.apply(d.photo, d.light, d.fit_light(L), before.copy())
                ceiling_plain = truth_plain.apply(d.photo, d.light, d.fit_light(L), before.copy())
                head = head_layer.apply(d.photo, d.light, d.fit_light(L), before.copy())
                rows.append([psnr(x, truth, w, g) for g in (False, True)
                             for x in (before, after, ceiling, plain, ceiling_plain)]
                            + [psnr(x, truth, face, False) for x in (before, head, plain)])
    r = np.array(rows)
    print(f"{args.folder} ({args.quality}): {len(rows)} relit pairs over the face; skipped: {skipped or 'none'}")
    print("| | network | + face mesh | + truth normals in the mesh's region | + face mesh, network's light "
          "| + truth normals, network's light |")
    print("|---|---|---|---|---|---|")
    print("| face PSNR (dB) | " + " | ".join(f"{v:.2f}" for v in r[:, :5].mean(0)) + " |")
    print("| face SI PSNR (dB) | " + " | ".join(f"{v:.2f}" for v in r[:, 5:10].mean(0)) + " |")
    hd = r[:, 11] - r[:, 10]
    print(f"over the whole head mask (not only the mesh's box): network {r[:, 10].mean():.2f} dB, truth normals over "
          f"the head {r[:, 11].mean():.2f} ({hd.mean():+.2f} +- {hd.std(ddof=1) / np.sqrt(len(hd)):.2f}), "
          f"face mesh (network's light) {r[:, 12].mean():.2f} ({np.mean(r[:, 12] - r[:, 10]):+.2f})")
    for k, label in ((1, "mesh"), (2, "truth normals"), (3, "mesh, network's light"), (4, "truth, network's light")):
        diff = r[:, k] - r[:, 0]
        print(f"{label} - network: {diff.mean():+.2f} dB +- {diff.std(ddof=1) / np.sqrt(len(diff)):.2f} (s.e.), "
              f"better on {(diff > 0).sum()}/{len(diff)}; SI {np.mean(r[:, 5 + k] - r[:, 5]):+.2f}")
    if angles:
        m, n = np.array(angles).T
        print(f"normals against the truth's over the face (median angle per scene, then the median over scenes): "
              f"mesh {np.median(m):.1f} deg ({', '.join(f'{x:.1f}' for x in m)}); network {np.median(n):.1f} deg "
              f"({', '.join(f'{x:.1f}' for x in n)})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
