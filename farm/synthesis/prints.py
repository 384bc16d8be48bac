"""Garment prints: where a print sits (drawn in rest space by farm.synthesis.appearance) and its
image (Pillow), which farm.rendering.materials puts on the garment."""

from __future__ import annotations

import numpy as np

from farm.synthesis.material_specs import sample_fabric_colour

PRINT_KINDS = ("logo", "text", "band", "number")


PRINT_KIND_P = (0.35, 0.3, 0.2, 0.15)
HELDOUT_KINDS = ("floral", "chevron", "rings")  # only farm.synthesis.looks' held-out pool draws these


def sample_print(rng: np.random.Generator, layout: dict, base: list[float], kinds=None,
                 palette=sample_fabric_colour) -> dict:
    """A print placed in rest space: logo, text, chest band or a number on the back; or, with
    `kinds` = (HELDOUT_KINDS, their shares) (farm.synthesis.looks' held-out pool), a floral
    panel, a chevron or rings on the front."""
    names, shares = (PRINT_KINDS, PRINT_KIND_P) if kinds is None else kinds
    kind = str(rng.choice(names, p=shares))
    colours = [palette(rng) for _ in range(2)]
    chest = layout["chest"]
    spec = {"kind": kind, "side": "back" if kind == "number" else "front", "split_y": layout["torso_y"],
            "seed": int(rng.integers(2**31)), "colours": colours}
    if kind in HELDOUT_KINDS:
        spec.update(centre=[float(chest[0] + rng.uniform(-0.03, 0.03)), float(chest[2] + rng.uniform(-0.07, 0.02))],
                    size_m=float({"floral": rng.uniform(0.22, 0.34), "chevron": rng.uniform(0.18, 0.28),
                                  "rings": rng.uniform(0.1, 0.2)}[kind]))
    elif kind == "logo":
        spec.update(centre=[float(chest[0] + rng.uniform(-0.06, 0.06)), float(chest[2] + rng.uniform(-0.06, 0.03))],
                    size_m=float(rng.uniform(0.05, 0.2)), shapes=int(rng.integers(1, 4)))
    elif kind == "text":
        letters = "ABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789"
        text = "".join(rng.choice(list(letters), size=int(rng.integers(2, 8))))
        spec.update(centre=[float(chest[0]), float(chest[2] + rng.uniform(-0.05, 0.03))],
                    size_m=float(rng.uniform(0.12, 0.26)), text=text)
    elif kind == "band":
        spec.update(centre=[float(chest[0]), float(chest[2] + rng.uniform(-0.08, 0.04))],
                    size_m=float(rng.uniform(0.02, 0.1)), side="all")
    else:
        spec.update(centre=[float(chest[0]), float(layout["back_z"])], size_m=float(rng.uniform(0.14, 0.24)),
                    text=str(int(rng.integers(0, 100))))
    return spec


def print_image(spec: dict, size: int = 96) -> np.ndarray:
    """The print's linear RGBA [size, size, 4] (row 0 = top); alpha is 0 or 1, colours from the spec."""
    from PIL import Image, ImageDraw, ImageFont

    rng = np.random.default_rng(spec["seed"])
    layers = [Image.new("L", (size, size), 0) for _ in spec["colours"]]
    if spec["kind"] == "logo":
        for k in range(spec["shapes"]):
            d = ImageDraw.Draw(layers[k % len(layers)])
            r = rng.uniform(0.2, 0.48) * size
            cx, cy = rng.uniform(size / 2 - 0.5 * (size / 2 - r), size / 2 + 0.5 * (size / 2 - r), 2)
            shape = rng.integers(4)
            box = [cx - r, cy - r, cx + r, cy + r]
            if shape == 0:
                d.ellipse(box, fill=255)
            elif shape == 1:
                d.ellipse(box, outline=255, width=max(2, int(r * rng.uniform(0.15, 0.4))))
            elif shape == 2:
                d.rectangle([cx - r, cy - r * 0.5, cx + r, cy + r * 0.5], fill=255)
            else:
                n = int(rng.integers(3, 7)) * 2
                ang = np.linspace(0, 2 * np.pi, n, endpoint=False) + rng.uniform(0, np.pi)
                rad = np.where(np.arange(n) % 2 == 0, r, r * rng.uniform(0.4, 0.8))
                d.polygon([(cx + a * np.cos(t), cy + a * np.sin(t)) for a, t in zip(rad, ang)], fill=255)
    elif spec["kind"] == "floral":  # scattered five-petal flowers with a centre in the second colour
        d0, d1 = ImageDraw.Draw(layers[0]), ImageDraw.Draw(layers[1])
        for _ in range(int(rng.integers(5, 10))):
            cx, cy = rng.uniform(0.12, 0.88, 2) * size
            r = rng.uniform(0.06, 0.13) * size
            turn = rng.uniform(0, 2 * np.pi)
            for k in range(5):
                a = turn + 2 * np.pi * k / 5
                px, py = cx + 0.6 * r * np.cos(a), cy + 0.6 * r * np.sin(a)
                d0.ellipse([px - 0.45 * r, py - 0.45 * r, px + 0.45 * r, py + 0.45 * r], fill=255)
            d1.ellipse([cx - 0.3 * r, cy - 0.3 * r, cx + 0.3 * r, cy + 0.3 * r], fill=255)
    elif spec["kind"] == "chevron":  # two zigzag bands across the panel
        for k, layer in enumerate(layers):
            d = ImageDraw.Draw(layer)
            teeth = int(rng.integers(3, 6))
            xs = np.linspace(0, size, 2 * teeth + 1)
            y0 = size * (0.3 + 0.35 * k)
            amp = size * rng.uniform(0.06, 0.12)
            line = [(float(x), float(y0 + (amp if i % 2 else -amp))) for i, x in enumerate(xs)]
            d.line(line, fill=255, width=max(3, int(size * rng.uniform(0.07, 0.12))))
    elif spec["kind"] == "rings":  # concentric rings, alternating the two colours
        n = int(rng.integers(3, 6))
        for k in range(n):
            r = size / 2 * (1 - k / n) - 1
            d = ImageDraw.Draw(layers[k % 2])
            d.ellipse([size / 2 - r, size / 2 - r, size / 2 + r, size / 2 + r], fill=255)
            ImageDraw.Draw(layers[1 - k % 2]).ellipse([size / 2 - r, size / 2 - r, size / 2 + r, size / 2 + r], fill=0)
    elif spec["kind"] in ("text", "number"):
        text = spec["text"]
        font = ImageFont.load_default(size=max(8, int(1.6 * size / max(len(text), 1))))
        d = ImageDraw.Draw(layers[0])
        box = d.textbbox((0, 0), text, font=font)
        x = (size - (box[2] - box[0])) / 2 - box[0]
        y = (size - (box[3] - box[1])) / 2 - box[1]
        d.text((x, y), text, fill=255, font=font)
    out = np.zeros((size, size, 4), dtype=np.float32)
    for layer, colour in zip(layers, spec["colours"]):
        m = np.asarray(layer) > 127
        out[m, :3] = colour
        out[m, 3] = 1.0
    return out
