"""Garment prints: where a print sits (drawn in rest space by farm.synthesis.appearance) and its
image (Pillow), which farm.rendering.materials puts on the garment."""

from __future__ import annotations

import numpy as np

from farm.synthesis.material_specs import sample_fabric_colour

PRINT_KINDS = ("logo", "text", "band", "number")


PRINT_KIND_P = (0.35, 0.3, 0.2, 0.15)


def sample_print(rng: np.random.Generator, layout: dict, base: list[float]) -> dict:
    """A print placed in rest space: logo, text, chest band or a number on the back."""
    kind = str(rng.choice(PRINT_KINDS, p=PRINT_KIND_P))
    colours = [sample_fabric_colour(rng) for _ in range(2)]
    chest = layout["chest"]
    spec = {"kind": kind, "side": "back" if kind == "number" else "front", "split_y": layout["torso_y"],
            "seed": int(rng.integers(2**31)), "colours": colours}
    if kind == "logo":
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
