"""The look pools (issue 45): what farm.synthesis.appearance draws for a person's look, split into
what training sees (pool "train": the farm's draws of before, call for call, so its scenes keep
their bytes) and an unfamiliar look it never sees (pool "heldout"), the proxy for photos the farm
did not make. Every category the held-out pool draws from is disjoint from the train pool's:

    category          train (as before)                              heldout
    top               tank tshirt longsleeve loose_shirt              crop turtleneck threequarter
                      loose_longsleeve; dresses                       loose_threequarter; no dresses
    bottom            trousers capri shorts skirt                     bermuda cropped maxi_skirt
    outer, hood       jacket coat; hoods                              vest; no hoods
    shoes             shoes boots barefoot                            knee_boots slip_ons
    fabric colour     neutral (s 0), chromatic s >= 0.2, v >= 0.2     muted (s 0.06-0.15) or deep (v < 0.18)
    pattern           stripes checks noise (scale 4-30) denim knit    dots plaid; stripes 45-80; checks 40-70
    print             logo text band number                           floral chevron rings
    hair style        bald buzz short medium long ponytail bun afro   bob pigtails space_buns
    hair colour       grey, dyed (s >= 0.5), natural (v <= 0.8)       pastel, platinum
    hair streaks      amount 0.1-0.3, scale 20-60                     amount 0.32-0.45, scale 70-120
    skin tone         G/R 0.48-0.79 (farm.synthesis.material_specs)    olive (G/R 0.80-0.87) or rosy (0.40-0.46)
    skin mottle       amount 0.03-0.1, scale 30-90                    amount 0.12-0.2, scale 110-200
    iris              brown, blue-grey                                green (hue 0.22-0.38)
    accessories       none                                            scarf (40 %), belt (35 %)

(colours in sRGB HSV.) Lips, brows' shapes, nails and the face's detail parts are shared. A
held-out person is first drawn as a training person from the scene's stream (body, pose, turn
and the train look, whose draws are discarded), then dressed again with the held-out pool from
its own stream (`look_rng`), so a held-out scene has the body, pose, camera and lights of the
train scene of the same seed and index: a paired comparison.
"""

from __future__ import annotations

import numpy as np

from farm.synthesis import garments
from farm.synthesis import hair as hair_mod
from farm.synthesis.material_specs import hsv_linear, sample_fabric_colour, sample_hair_colour, sample_skin
from farm.synthesis.meshops import submesh

LOOK_POOLS = ("train", "heldout")
LOOK_STREAM = 5  # default_rng([seed, index, LOOK_STREAM, person]): a held-out person's look


def look_rng(pool: str, seed: int, index: int, person: int) -> np.random.Generator | None:
    """The stream a held-out person's look draws from; None under the train pool (nothing new drawn)."""
    if pool not in LOOK_POOLS:
        raise ValueError(f"look_pool must be 'train' or 'heldout', got {pool!r}")
    return np.random.default_rng([int(seed), int(index), LOOK_STREAM, int(person)]) if pool == "heldout" else None


class TrainLooks:
    """The farm's looks of before: each method makes exactly the draws appearance.dress made."""

    name = "train"
    dress_p = 0.18  # of the scenes whose pose allows a skirt
    hood_p = 0.3
    print_p = 0.5
    pattern_scales = None  # material_specs.material's own scales
    top_kinds = ("tank", "tshirt", "longsleeve", "loose_shirt", "loose_longsleeve")
    top_p = (0.12, 0.28, 0.2, 0.24, 0.16)

    def skin_colour(self, rng):
        return sample_skin(rng)

    def mottle(self, rng):
        return {"amount": float(rng.uniform(0.03, 0.1)), "scale": float(rng.uniform(30.0, 90.0))}

    def streaks(self, rng):
        return {"amount": float(rng.uniform(0.1, 0.3)), "scale": float(rng.uniform(20.0, 60.0))}

    def shoe_kind(self, rng):
        return str(rng.choice(["shoes", "boots", "barefoot"], p=[0.7, 0.2, 0.1]))

    def hair_style(self, rng):
        return str(rng.choice(hair_mod.STYLES, p=hair_mod.STYLE_P))

    def hair_colour(self, rng):
        return sample_hair_colour(rng)

    def iris(self, rng):
        if rng.random() < 0.6:
            return hsv_linear(rng.uniform(0.05, 0.1), rng.uniform(0.5, 0.8), rng.uniform(0.12, 0.4))
        return hsv_linear(rng.uniform(0.45, 0.62), rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6))

    def fabric_colour(self, rng):
        return sample_fabric_colour(rng)

    def top_kind(self, rng):
        return str(rng.choice(self.top_kinds, p=self.top_p))

    def top_hem(self, rng, kind):
        return rng.uniform(0.47, 0.52) if kind.startswith("loose") else rng.uniform(0.5, 0.57)

    def top_region(self, kind, body, groups, h, hem):
        mask = groups["torso"] & (h > hem)
        if kind != "tank":
            mask |= groups["upperarm"]
        if kind in ("longsleeve", "loose_longsleeve"):
            mask |= groups["forearm"]
        return mask

    def outer_kind(self, rng, skirt_allowed):
        if rng.random() < 0.3:
            return "coat" if (skirt_allowed and rng.random() < 0.4) else "jacket"
        return "none"

    def bottom_kind(self, rng, skirt_allowed):
        kind = str(rng.choice(["trousers", "capri", "shorts", "skirt"], p=[0.45, 0.15, 0.25, 0.15]))
        return "shorts" if kind == "skirt" and not skirt_allowed else kind  # legs apart or bent cut a skirt

    def bottom_cut(self, rng, kind):
        cuts = {"trousers": rng.uniform(0.035, 0.06), "capri": rng.uniform(0.15, 0.22),
                "shorts": rng.uniform(0.33, 0.42), "skirt": rng.uniform(0.25, 0.42)}
        return cuts[kind]

    def cloth_patterns(self, slot):
        return ("stripes", "checks", "noise", "denim", "knit") if slot != "bottom" else \
            ("stripes", "checks", "noise", "denim", "denim")

    def shoe_region(self, kind, groups, h):
        return groups["foot"] | (groups["shin"] & (h < (0.12 if kind == "boots" else 0.045)))

    def print_kinds(self):
        return None  # farm.synthesis.prints' own

    def accessories(self, rng, body, normals, groups, h, layout, torso_frame, outfit):
        return []


class HeldoutLooks(TrainLooks):
    """Looks the train pool never draws (the table in this module's docstring)."""

    name = "heldout"
    dress_p = 0.0
    hood_p = 0.0
    print_p = 0.6
    top_kinds = ("crop", "turtleneck", "threequarter", "loose_threequarter")
    top_p = (0.25, 0.25, 0.25, 0.25)
    # pattern -> scale range: pinstripes and gingham finer than the train pool's 4-30
    pattern_scales = {"stripes": (45.0, 80.0), "checks": (40.0, 70.0), "dots": (12.0, 30.0), "plaid": (4.0, 12.0)}
    scarf_p = 0.4
    belt_p = 0.35

    def skin_colour(self, rng):
        rgb = np.array(sample_skin(rng))
        # the train pool's G/R lies in 0.48-0.79 (anchors 0.53-0.71, the hue jitter +-5 % per channel)
        rgb[1] = rgb[0] * (rng.uniform(0.8, 0.87) if rng.random() < 0.5 else rng.uniform(0.4, 0.46))
        return np.clip(rgb, 0.01, 0.9).tolist()

    def mottle(self, rng):
        return {"amount": float(rng.uniform(0.12, 0.2)), "scale": float(rng.uniform(110.0, 200.0))}

    def streaks(self, rng):
        return {"amount": float(rng.uniform(0.32, 0.45)), "scale": float(rng.uniform(70.0, 120.0))}

    def shoe_kind(self, rng):
        return str(rng.choice(["knee_boots", "slip_ons"]))

    def hair_style(self, rng):
        return str(rng.choice(hair_mod.HELDOUT_STYLES))

    def hair_colour(self, rng):
        if rng.random() < 0.5:  # pastel dye: not a natural hue, paler than the train pool's dyes
            return hsv_linear(rng.uniform(0.2, 0.95), rng.uniform(0.2, 0.4), rng.uniform(0.82, 0.95))
        return hsv_linear(rng.uniform(0.1, 0.14), rng.uniform(0.12, 0.3), rng.uniform(0.86, 0.95))  # platinum

    def iris(self, rng):
        return hsv_linear(rng.uniform(0.22, 0.38), rng.uniform(0.3, 0.6), rng.uniform(0.3, 0.6))

    def fabric_colour(self, rng):
        if rng.random() < 0.5:  # muted tints: greige, dusty rose, sage
            return hsv_linear(rng.uniform(0, 1), rng.uniform(0.06, 0.15), rng.uniform(0.3, 0.95))
        return hsv_linear(rng.uniform(0, 1), rng.uniform(0.45, 0.9), rng.uniform(0.08, 0.17))  # navy, burgundy

    def top_hem(self, rng, kind):
        return rng.uniform(0.61, 0.64) if kind == "crop" else super().top_hem(rng, kind)

    def top_region(self, kind, body, groups, h, hem):
        mask = groups["torso"] & (h > hem) | groups["upperarm"]
        forearm = groups["forearm"]
        if kind == "turtleneck":
            head = groups["head"] & ~groups["eyes"]
            mask |= forearm | (head & (h < h[head].min() + 0.04))
        elif kind.endswith("threequarter"):
            mask |= forearm & (h > np.median(h[forearm]))  # the A-pose's upper half of the forearm
        return mask

    def outer_kind(self, rng, skirt_allowed):
        return "vest" if rng.random() < 0.3 else "none"

    def bottom_kind(self, rng, skirt_allowed):
        kind = str(rng.choice(["bermuda", "cropped", "maxi_skirt"], p=[0.4, 0.3, 0.3]))
        return "bermuda" if kind == "maxi_skirt" and not skirt_allowed else kind

    def bottom_cut(self, rng, kind):
        return {"bermuda": rng.uniform(0.25, 0.31), "cropped": rng.uniform(0.07, 0.12),
                "maxi_skirt": rng.uniform(0.1, 0.16)}[kind]

    def cloth_patterns(self, slot):
        return ("dots", "plaid", "stripes", "checks")

    def shoe_region(self, kind, groups, h):
        return groups["foot"] | (groups["shin"] & (h < 0.27)) if kind == "knee_boots" else groups["foot"]

    def print_kinds(self):
        return ("floral", "chevron", "rings"), (0.4, 0.3, 0.3)

    def accessories(self, rng, body, normals, groups, h, layout, torso_frame, outfit):
        """[(slot, kind, vertices, rest, faces, info)]: a scarf round the neck, a belt at the waist."""
        out = []
        if rng.random() < self.scarf_p:
            c = layout["neck"]
            ring = layout["neck_radius"] + float(rng.uniform(0.03, 0.045))
            tube_r = float(rng.uniform(0.014, 0.022))
            t = np.linspace(0.0, 2 * np.pi, 25)[:-1]
            path = np.stack([c[0] + ring * np.sin(t), c[1] + ring * np.cos(t), c[2] - 0.01 - 0.03 * (1 - np.cos(t))], 1)
            path = np.concatenate([path, path[:1]])  # closed: the tube's two caps meet
            v, f = garments.tube(path, np.full(len(path), tube_r), segments=10, squash=0.7)
            posed = v @ torso_frame[0].T + torso_frame[1]
            out.append(("scarf", "scarf", posed, v, f, {"ring_m": ring, "radius_m": tube_r}))
        if outfit["belt_ok"] and rng.random() < self.belt_p:
            waist = outfit["waist"]
            mask = groups["torso"] & (h < waist + 0.006) & (h > waist - 0.018)
            faces, ids = submesh(body.faces, mask)
            offset = outfit["under_m"] + float(rng.uniform(0.003, 0.006))
            verts = body.vertices[ids] + offset * normals[ids]
            v, r, f, _ = garments.thick(verts, body.rest_vertices[ids], faces, 0.003)
            out.append(("belt", "belt", v, r, f, {"offset_m": offset}))
        return out


TRAIN = TrainLooks()
HELDOUT = HeldoutLooks()


def pool(name: str) -> TrainLooks:
    if name not in LOOK_POOLS:
        raise ValueError(f"look_pool must be 'train' or 'heldout', got {name!r}")
    return TRAIN if name == "train" else HELDOUT

