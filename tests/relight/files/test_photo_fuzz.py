"""Fuzzing the photo and EXR loaders: whatever the bytes, only ValueError escapes."""

from __future__ import annotations

import io

import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st
from PIL import Image

from fuzz_support import accepted_share, record
from relight.files import photo as ph
from relight.files.exr import write_exr

FUZZ = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _valid_files(tmp) -> dict[str, bytes]:
    rng = np.random.default_rng(0)
    out = {}
    for fmt in ("PNG", "JPEG"):
        buf = io.BytesIO()
        Image.fromarray(rng.integers(0, 256, (12, 10, 3), dtype=np.uint8)).save(buf, format=fmt)
        out[fmt] = buf.getvalue()
    path = tmp / "v.exr"
    write_exr(path, {c: rng.uniform(0, 1, (12, 10)).astype(np.float32) for c in "RGBA"})
    out["EXR"] = path.read_bytes()
    return out


@pytest.fixture(scope="module")
def valid(tmp_path_factory):
    return _valid_files(tmp_path_factory.mktemp("fuzz"))


def _load(tmp_path, data: bytes, name: str, prop: str) -> None:
    path = tmp_path / name
    path.write_bytes(data)
    try:
        img, mask = ph.read_photo(path)
    except ValueError:
        record(prop, "ValueError")
        return
    record(prop, "ok")
    # anything that loads is a finite linear image with a matching mask
    assert img.ndim == 3 and img.shape[2] == 3 and img.dtype == np.float32
    assert np.all(np.isfinite(img))
    assert mask is None or mask.shape == img.shape[:2]


@FUZZ
@given(data=st.binary(min_size=0, max_size=512))
def test_random_bytes(tmp_path, data):
    _load(tmp_path, data, "r.png", "photo_fuzz.random")  # refusing is right here: no floor


def test_truncated_valid_files(tmp_path, valid):
    # the whole file (cut 1.0) of each format is among the cases: at least 3 accepted
    @FUZZ
    @example(fmt="PNG", cut=1.0)
    @example(fmt="JPEG", cut=1.0)
    @example(fmt="EXR", cut=1.0)
    @given(fmt=st.sampled_from(["PNG", "JPEG", "EXR"]), cut=st.floats(0.0, 1.0))
    def case(fmt, cut):
        data = valid[fmt]
        _load(tmp_path, data[: int(len(data) * cut)], "t." + fmt.lower(), "photo_fuzz.truncated")

    with accepted_share("photo_fuzz.truncated", 3 / (3 + FUZZ.max_examples)):
        case()


def test_mutated_headers(tmp_path, valid):
    # an edit that writes the byte already there leaves the file valid: one such case per
    # format is added; edits elsewhere may hit pixels only, so more load (no floor beyond those)
    @FUZZ
    @example(fmt="PNG", edits=[(0, valid["PNG"][0])])
    @example(fmt="JPEG", edits=[(0, valid["JPEG"][0])])
    @example(fmt="EXR", edits=[(0, valid["EXR"][0])])
    @given(fmt=st.sampled_from(["PNG", "JPEG", "EXR"]),
           edits=st.lists(st.tuples(st.integers(0, 399), st.integers(0, 255)), min_size=1, max_size=6))
    def case(fmt, edits):
        data = bytearray(valid[fmt])
        for pos, value in edits:  # headers live in the first few hundred bytes
            data[pos % len(data)] = value
        _load(tmp_path, bytes(data), "m." + fmt.lower(), "photo_fuzz.mutated")

    with accepted_share("photo_fuzz.mutated", 3 / (3 + FUZZ.max_examples)):
        case()
