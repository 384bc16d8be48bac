"""A photo mirrored left-right and relit under the mirrored light must give the mirror image of
the photo relit (issue 37), through the shipped ONNX model and the runtime as a user runs them.

The mirrored light: x -> -x in the photo-camera frame (docs/conventions.md) flips the sign of
the real SH coefficients odd in x, (l, m) = (1, 1), (2, -2), (2, 1), (3, -2), (3, 1), (3, 3),
(4, -4), (4, -2), (4, 1), (4, 3) at order 4: m > 0 odd, and m < 0 even (relight.network.tta.mirror_x).
A white directional light from 90 degrees mirrors to the one from 270.

Asymmetry: the relative RMS difference over the person (matte > 0.5) between the photo relit and
the mirrored photo relit under the mirrored light, mirrored back. The same person matte (the
segmenter's, mirrored for the mirrored photo) is given to both runs, so the crop boxes are mirror
images and only the network can break the symmetry.

Measured on the shipped model (2026-11-27, docs/EVALUATION.md "Issue 37"; photos at 384 px):
- the network once (Draft): 0.29-0.82 under a light from the side (90 or 270 degrees;
  astronaut 0.82 / 0.65), 0.13-0.31 under a light from the front or behind. The network is not mirror-equivariant (its convolutions and its training
  do not make it so), and under a side light the relit person differs by most of its own level:
  the failure the issue describes. The bound asserted is the measured worst case plus a margin, so
  that it catches a change for the worse; it is NOT the goal. The every-framing model (issue 37,
  later the same day) is less asymmetric: 0.22-0.50 from the side (astronaut 0.50 / 0.48),
  0.11-0.22 from the front or behind; the bounds (0.6 from 90 degrees, 0.2 from 0) are its worst
  case plus about a fifth, as the release's were.
- averaged with its run on the mirrored crop (Balanced since 2026-11-27, and the first of Best's
  augmentations: relight.network.tta, the one code path): at most 0.0007 over 0/90/180/270 degrees
  (0.013 with the astronaut at 512 px). The average is equivariant by construction (the mirrored
  run of the mirrored photo is the first run, mirrored); what is left comes from resampling the
  crop and the full-resolution detail, so the tolerance is 0.02.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from relight.person import matte as segmenter
from relight.files import photo as photo_io
from relight.network import quality, tta
from relight.lighting.light import directional_light
from relight.imaging.resample import resize_linear
from relight.network.runtime import Relighter

ROOT = Path(__file__).resolve().parents[3]
PHOTOS = (ROOT / "relight" / "data" / "examples" / "astronaut.jpg",
          ROOT / "relight" / "data" / "examples" / "grace_hopper.jpg",
          ROOT / "evaluation" / "data" / "matte_eval" / "obama_standing.jpg")
LONGEST = 384  # px: the photos are shrunk first (the network works at 128 px; the test stays quick)
PLAIN_BOUND = {90.0: 0.6, 0.0: 0.2}  # measured 0.50 / 0.15 at worst (see the docstring): a regression guard
AUGMENTED_BOUND = 0.02


def _photo(path: Path):
    image, _ = photo_io.read_photo(path)
    h, w = image.shape[:2]
    s = LONGEST / max(h, w)
    image = resize_linear(image, max(int(h * s), 32), max(int(w * s), 32))
    return image, segmenter.person_matte(image).alpha


def asymmetry(relighter: Relighter, image, mask, azimuth: float, augment=()) -> float:
    signs = tta.mirror_x(relighter.sh_order)
    light = directional_light(azimuth, relighter.sh_order)
    relit = relighter.decompose(image, mask=mask, augment=augment).relight(light)
    mirrored = relighter.decompose(image[:, ::-1].copy(), mask=mask[:, ::-1].copy(), augment=augment)
    back = mirrored.relight(light * signs[:, None])[:, ::-1]
    person = mask > 0.5
    return float(np.sqrt(((relit - back)[person] ** 2).mean() / (relit[person] ** 2).mean()))


@pytest.fixture(scope="module")
def relighter():
    return Relighter(working_size=128, threads=1)


@pytest.fixture(scope="module")
def photos():
    return {p.stem: _photo(p) for p in PHOTOS}


def test_the_mirrored_directional_light_is_the_light_with_odd_coefficients_negated():
    signs = tta.mirror_x(4)
    odd = [(l, m) for l in range(5) for m in range(-l, l + 1) if signs[l * l + l + m] < 0]
    assert odd == [(1, 1), (2, -2), (2, 1), (3, -2), (3, 1), (3, 3), (4, -4), (4, -2), (4, 1), (4, 3)]
    assert np.allclose(directional_light(90.0, 4) * signs[:, None], directional_light(270.0, 4), atol=1e-12)
    assert np.allclose(directional_light(0.0, 4) * signs[:, None], directional_light(0.0, 4), atol=1e-12)


@pytest.mark.parametrize("azimuth", [90.0, 0.0])
def test_the_network_once_is_within_its_measured_asymmetry(relighter, photos, azimuth):
    draft = quality.preset("draft").augment
    assert draft == ()  # Draft: the network once
    values = {name: asymmetry(relighter, image, mask, azimuth, augment=draft)
              for name, (image, mask) in photos.items()}
    assert max(values.values()) < PLAIN_BOUND[azimuth], values


@pytest.mark.parametrize("azimuth", [90.0, 0.0])
def test_balanced_averaged_with_the_mirrored_run_relights_to_the_mirror_image(relighter, photos, azimuth):
    balanced = quality.preset("balanced")
    assert balanced.augment == ((1.0, True),) and balanced.working_size == 128  # the relighter's size
    values = {name: asymmetry(relighter, image, mask, azimuth, augment=balanced.augment)
              for name, (image, mask) in photos.items()}
    assert max(values.values()) < AUGMENTED_BOUND, values
