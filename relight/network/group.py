"""Everyone in the photo: each person decomposed at their own crop, one light for all, relit together.

A group photo holds more of its one light than any single person in it: more surfaces facing more
ways. Each person's decomposition fits the light to its own pixels (the graph's least squares
albedo x (T . L) = photo, then the level prior and the refinement); the photo's one light is the mean
of those estimates, each person counted once, and every person's albedo then follows from it
(Decomposition.with_light). The mean, not the least-squares answer over all the pixels at once
((sum_i N_i)^-1 sum_i N_i L_i, N_i person i's normal matrix): the people's errors are the network's
biases more than noise, and the pixels' weighting let the brightest person's bias win (on farm group
scenes: +0.47 dB against +0.27 over each person's own light; docs/EVALUATION.md, "Group photos"). The people are composited over the photo one after the other,
each adding alpha_i (person_i - photo) within its own box; their mattes sum to at most 1
(relight.person.matte.mattes_of_checked_photo). A person too small to relight (MIN_PERSON_PX) beside a
larger one is left as they are and the record says so; the largest is always relit. One person found: the one-person path, unchanged.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from relight.lighting.light import checked_light
from relight.network.decomposition import Decomposition
from relight.person import matte as segmenter
from relight.person.linear_photo import check_photo

__all__ = ["MIN_PERSON_PX", "Group", "decompose_people", "joint_light"]

MIN_PERSON_PX = 48     # a person's longest side below this is left as they are: under half of the
                       # smallest working size the network ever runs at (Draft's 128 px is 2.7x this)


@dataclass
class Group:
    """The people of one photo: `people` the decompositions relit (largest first), `left` those left as
    they are ({"person": k, "px": longest side, "why": ...}), `count` everyone found."""

    people: list[Decomposition]
    left: list[dict] = field(default_factory=list)
    count: int = 0
    mattes: list = field(default_factory=list, repr=False)   # everyone's PersonMatte, found or given

    def record(self) -> dict:
        """What was done, for the output's metadata: people found, relit (1 = the largest), left."""
        return {"found": self.count, "relit": [d.choices["person"] for d in self.people], "left": self.left,
                "light": "one for the photo, from everyone relit" if len(self.people) > 1 else "the person's own"}

    def relight(self, coeffs, exposure_ev: float = 0.0, *, shadows: bool = False,
                out: np.ndarray | None = None) -> np.ndarray:
        """The photo with every person relit by the light `coeffs` (as Decomposition.relight takes it:
        SH coefficients, checked here once, or a CheckedLight), float32 [H, W, 3]; one person: that
        person's relight, bit for bit."""
        if len(self.people) == 1:
            return self.people[0].relight(coeffs, exposure_ev, out=out, shadows=shadows)
        light = checked_light(coeffs, exposure_ev)
        photo = self.people[0].photo
        if out is None:
            out = photo.copy()
        else:
            np.copyto(out, photo)
        for d in self.people:
            d.relight(light, out=out, shadows=shadows, accumulate=True)
        return out


def joint_light(people: list[Decomposition]) -> np.ndarray:
    """The one light [n, 3] of the module docstring: the mean of each person's own estimate."""
    return np.mean([np.asarray(d.light, np.float64) for d in people], axis=0).astype(np.float32)


def decompose_people(relighter, photo, *, matte_method: str = "ensemble", mattes: list | None = None,
                     **options) -> Group:
    """Every person in `photo` (linear float32 [H, W, 3]) decomposed at their own crop and working size
    (Relighter.decompose's `options`, as for one person), the photo's one light fitted from all of
    them; NoPersonError when there is nobody. `mattes`: the people's PersonMattes of this photo found
    before (a Group's `mattes`: the add-on's next press on the same photo), not looked for again."""
    photo = check_photo(photo, segmenter.MIN_SIDE, finite=False, purpose="a person matte")
    if mattes is None:
        mattes = segmenter.mattes_of_checked_photo(photo, method=matte_method, threads=relighter._open["threads"])
    people, left = [], []
    for m in mattes:
        y0, y1, x0, x1 = m.box
        side = max(y1 - y0, x1 - x0)
        if side < MIN_PERSON_PX and m.index > 1:  # the largest is always relit, as one person alone is
            left.append({"person": m.index, "px": int(side), "why": f"too small to relight ({side} < {MIN_PERSON_PX} px)"})
            continue
        # the photo and each matte checked once, here and by the matte: decompose takes them as they are
        d = relighter.decompose(photo, matte_method=matte_method, person_matte=m, **options)
        d.choices.update(person=m.index)
        people.append(d)
    if len(people) > 1:
        light = joint_light(people)
        people = [d.with_light(light) for d in people]
    return Group(people=people, left=left, count=len(mattes), mattes=list(mattes))
