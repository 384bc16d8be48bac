"""Everyone in the photo for the add-on: a relight.network.group.Group seen as one decomposition.

The add-on's outputs, dials, preview and Save Layers take one decomposition (relight, layer,
shadow_layer, size, photo, mask, light); `People` gives them the group's: the relit image is
everyone relit under the photo's one light (Group.relight), a layer is the sum of the
people's (each is zero outside its own matte, the mattes sum to at most 1), the shadow layer the
product of theirs (each is 1 outside its person), the mask the mattes' sum. What only one
decomposition has (the working-resolution maps Compositing Setup's person proxy reads) is the
largest person's. Plain Python, no bpy.
"""

from __future__ import annotations

import numpy as np


class People:
    """Decomposition-like view of everyone relit: `people` the Decompositions (largest first, one
    light), `count` everyone the person matte found, `left` those too small to relight."""

    def __init__(self, group, mask: np.ndarray | None = None):
        self.group = group
        self.people = group.people
        self.count = group.count
        self.left = group.left
        self.photo = self.people[0].photo
        if mask is None:  # the cut-out '.matte' and the preview show everyone found
            mask = np.zeros(self.people[0].size, np.float32)
            for d in self.people:
                mask += d.mask
            np.minimum(mask, 1.0, out=mask)  # the mattes sum to at most 1 already: round-off only
        self.mask = mask

    def __getattr__(self, name):
        # the working-resolution maps (alpha, box, shadows, transport, ...): the largest person's
        return getattr(self.__dict__["people"][0], name)

    @property
    def size(self) -> tuple[int, int]:
        return self.people[0].size

    @property
    def has_residual(self) -> bool:
        return any(d.has_residual for d in self.people)

    def relight(self, coeffs, exposure_ev: float = 0.0, out: np.ndarray | None = None,
                shadows: bool = False) -> np.ndarray:
        """Everyone relit by `coeffs` over the untouched photo, [H, W, 3] (into `out` when given)."""
        return self.group.relight(coeffs, exposure_ev, shadows=shadows, out=out)

    def layer(self, name: str, coeffs=None, exposure_ev: float = 0.0, out: np.ndarray | None = None) -> np.ndarray:
        """Decomposition.layer summed over the people: each is zero outside its person's matte."""
        total = self.people[0].layer(name, coeffs, exposure_ev, out=out)
        scratch = np.empty(total.shape, np.float32)
        for d in self.people[1:]:
            total += d.layer(name, coeffs, exposure_ev, out=scratch)
        return total

    def shadow_layer(self, coeffs=None, exposure_ev: float = 0.0, out: np.ndarray | None = None) -> np.ndarray:
        """The people's shadow layers multiplied: each is 1 outside its person, so a pixel keeps the
        share of the key its own person's body leaves it."""
        total = self.people[0].shadow_layer(coeffs, exposure_ev, out=out)
        scratch = np.empty(total.shape, np.float32)
        for d in self.people[1:]:
            total *= d.shadow_layer(coeffs, exposure_ev, out=scratch)
        return total

    def person_alpha(self, index: int, out: np.ndarray | None = None) -> np.ndarray:
        """Person `index`'s (0 = the largest) matte at full size [H, W]: Save Layers' Person<k>.A."""
        return self.people[index].full_alpha(out)

    def record(self) -> dict:
        return self.group.record()


def people_of(decomposition) -> list:
    """The decompositions a session's decomposition holds: everyone of a People, else itself."""
    return decomposition.people if isinstance(decomposition, People) else [decomposition]


def people_note(found: int, relit: int) -> str:
    """What Relight says of the people ('' for one person alone): ' (2 people, one light)',
    ' (2 of 3 people; the others too small)'."""
    if relit <= 1 and found <= 1:
        return ""
    if relit == found:
        return f" ({relit} people, one light)"
    return f" ({relit} of {found} people; the others too small to relight)" if relit > 1 else \
        f" (1 of {found} people; the others too small to relight)"
