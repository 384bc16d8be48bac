"""Issue 18: each hostile case found by probing, as a regression test built from a
generated file. Commands run as a user would (a subprocess) under a 3 GB
address-space limit and must end in one stderr line, a non-zero exit, no
traceback, no signal and no output file, within 60 s."""

from __future__ import annotations

import json
import os
import resource
import signal
import subprocess
import sys
import time

import numpy as np
import pytest
from PIL import Image

from fuzz_support import exr_bytes, jpeg_bytes, png_bytes, radiance_hdr, uniform_rle_hdr
from relight.lighting import envmap, sh_projection
from relight.files import image_limits, photo
from relight.cli import main
from relight.imaging.colour import srgb_encode
from relight.models import write_sidecar
from relight.lighting.light import sh_light
from relight.network.runtime import Relighter
from relight.network.quality import preset

DRAFT_SIZE = preset("draft").working_size  # the Draft preset's working size

LIMIT_AS = 3 * 1024**3  # the goal: within 3 GB
LIMIT_S = 60


def _photo(path, h=40, w=30, seed=0):
    """A noise photo: commands on it use --matte network (the person matte would find no one)."""
    Image.fromarray(np.random.default_rng(seed).integers(30, 220, (h, w, 3), dtype=np.uint8)).save(path)
    return path


def run_cli(*args, file_size_limit: int | None = None):
    """`python -m relight.cli ARGS` under RLIMIT_AS 3 GB (and RLIMIT_FSIZE, a full disk, when given)."""

    def limits():
        resource.setrlimit(resource.RLIMIT_AS, (LIMIT_AS, LIMIT_AS))
        if file_size_limit is not None:
            signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # then a write past the limit fails with EFBIG
            resource.setrlimit(resource.RLIMIT_FSIZE, (file_size_limit, file_size_limit))

    if args[0] == "image":
        args = (*args, "--matte", "network")  # noise photos: the person matte would find no one
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1")
    start = time.monotonic()
    res = subprocess.run([sys.executable, "-m", "relight.cli", *map(str, args)], capture_output=True, text=True,
                         timeout=2 * LIMIT_S, preexec_fn=limits, env=env)
    return res, time.monotonic() - start


def assert_refused(res, elapsed, command: str, *, match: str = ""):
    assert res.returncode == 2, (res.returncode, res.stderr[-2000:])  # > 0: an exit, not a signal
    assert res.stdout == ""
    lines = res.stderr.splitlines()
    assert len(lines) == 1, res.stderr[-3000:]
    assert lines[0].startswith(f"relight {command}: error: ") and "Traceback" not in res.stderr
    assert match in lines[0], lines[0]
    assert elapsed < LIMIT_S


# ------------------------------------------------------------------ 1. Radiance .hdr with a huge declared size


@pytest.mark.parametrize("declared", [("100000", "200000"), ("999999999999", "2")])
@pytest.mark.parametrize("command", ["sh", "image"])
def test_hdr_with_a_forged_size_is_one_line(tmp_path, model, declared, command):
    hdr = tmp_path / "forged.hdr"
    hdr.write_bytes(radiance_hdr(32, 64, declared=declared))  # a valid 64 x 32 body
    out = tmp_path / "out.png"
    if command == "sh":
        res, elapsed = run_cli("sh", hdr)
    else:
        res, elapsed = run_cli("image", _photo(tmp_path / "p.png"), "--light", hdr, "--model", model,
                               "--quality", "draft", "--out", out)
    assert_refused(res, elapsed, command)
    assert not out.exists() and sorted(p.name for p in tmp_path.iterdir()) == sorted(
        ["forged.hdr"] + (["p.png"] if command == "image" else []))


def test_hdr_size_bound_is_exact(tmp_path):
    """The declared-size test uses the fewest bytes a scanline can take, so the
    smallest legal file (runs of 127) loads and one byte less is refused."""
    data = uniform_rle_hdr(2, 254, value=200, exponent=129)
    (tmp_path / "min.hdr").write_bytes(data)
    img = envmap.read_radiance_hdr(tmp_path / "min.hdr")
    assert img.shape == (2, 254, 3)
    np.testing.assert_array_equal(img, np.float32((200 + 0.5) * 2.0 ** (129 - 136)))
    (tmp_path / "short.hdr").write_bytes(data[:-1])
    with pytest.raises(ValueError, match="at least 40 bytes, the file holds 39"):
        envmap.read_radiance_hdr(tmp_path / "short.hdr")
    # enough bytes but a zero-length literal run: the scanline decoder still refuses it
    (tmp_path / "zero.hdr").write_bytes(b"#?RADIANCE\n\n-Y 1 +X 8\n" + bytes([2, 2, 0, 8, 0]) + bytes(7))
    with pytest.raises(ValueError, match="^[^:]*zero.hdr: Radiance pixel data is truncated or corrupt$"):
        envmap.read_radiance_hdr(tmp_path / "zero.hdr")


def test_hdr_map_over_the_size_limit_is_refused_before_allocating(tmp_path):
    height = 8200  # 16400 x 8200 > MAX_MAP_PIXELS; the file is the smallest legal one (8.6 MB)
    (tmp_path / "huge.hdr").write_bytes(uniform_rle_hdr(height, 2 * height))
    start = time.monotonic()
    with pytest.raises(ValueError, match="over the limit"):
        envmap.load_equirect(tmp_path / "huge.hdr")
    assert time.monotonic() - start < 5


# ------------------------------------------------------------------ 2. maps near float32's maximum


def _overflow_maps(tmp_path):
    plane = np.full((16, 32), 3e38, np.float32)
    (tmp_path / "max.exr").write_bytes(exr_bytes(tmp_path, {c: plane for c in "RGB"}))
    (tmp_path / "e255.hdr").write_bytes(radiance_hdr(16, 32, exponent=255, seed=3))
    return tmp_path / "max.exr", tmp_path / "e255.hdr"


def test_sh_of_maps_near_float32_max_is_finite_and_exact(tmp_path, capsys):
    exr_map, hdr_map = _overflow_maps(tmp_path)
    for path in (exr_map, hdr_map):
        assert main(["sh", str(path), "--order", "2", "--json"]) == 0
        coeffs = np.array(json.loads(capsys.readouterr().out)["coeffs"])
        assert np.all(np.isfinite(coeffs))
        reference = sh_projection.project_equirect(envmap.load_equirect(path).pixels, 2, precision="float64")
        np.testing.assert_allclose(coeffs, reference, rtol=1e-8, atol=1e-12 * np.abs(reference).max())
    # a uniform map of value v: L00 = v * integral of Y00 = v * 4 pi / (2 sqrt(pi)) = 2 sqrt(pi) v
    main(["sh", str(exr_map), "--order", "0", "--json"])
    l00 = json.loads(capsys.readouterr().out)["coeffs"][0]
    np.testing.assert_allclose(l00, [2 * np.sqrt(np.pi) * float(np.float32(3e38))] * 3, rtol=1e-12)


def test_relight_image_agrees_with_relight_sh_on_those_maps(tmp_path, model, capsys):
    for path in _overflow_maps(tmp_path):
        out = tmp_path / f"{path.stem}.png"
        base = ["image", str(_photo(tmp_path / "p.png")), "--light", str(path), "--model", model,
                "--matte", "network", "--quality", "draft", "--out", str(out)]
        assert main(base) == 0, capsys.readouterr().err  # normalized (the default): an ordinary light
        assert out.exists()
        out.unlink()
        # as is, its radiance would overflow float32 in the relit image: one line, nothing written
        assert main([*base, "--no-normalize"]) == 2
        err = capsys.readouterr().err
        assert len(err.splitlines()) == 1 and "too bright" in err and not out.exists()


# ------------------------------------------------------------------ 3. a small JPEG that declares a huge size


def test_tiny_jpeg_declaring_12000_squared_is_refused_fast(tmp_path, model):
    forged = tmp_path / "forged.jpg"
    forged.write_bytes(jpeg_bytes(declared=(12000, 12000)))
    assert forged.stat().st_size < 7000
    out = tmp_path / "out.png"
    res, elapsed = run_cli("image", forged, "--light", "studio", "--model", model, "--out", out)
    assert_refused(res, elapsed, "image", match="--max-pixels 144000000")
    assert elapsed < 20 and not out.exists()


def test_declared_size_is_weighed_against_the_file(tmp_path):
    forged = tmp_path / "forged.jpg"
    forged.write_bytes(jpeg_bytes(declared=(2000, 2000)))  # 4 MP in < 1 KB: > 4,096 px per byte
    with pytest.raises(ValueError, match="more than such a file can hold"):
        photo.read_photo(forged)
    # --max-pixels is the way to decode it anyway
    img, mask = photo.read_photo(forged, max_pixels=4_000_000)
    assert img.shape == (2000, 2000, 3) and mask is None and np.all(np.isfinite(img))
    # a real file of that size is not refused: a smooth gradient JPEG, the most compressible photo
    real = tmp_path / "real.jpg"
    real.write_bytes(jpeg_bytes(2000, 2000, smooth=True))
    assert photo.read_photo(real)[0].shape == (2000, 2000, 3)


def test_png_chunk_longer_than_the_file_is_refused_before_reading_it(tmp_path):
    """Found by `make fuzz`: an IDAT length byte changed to 0xd1 made Pillow read(3.5 GB)."""
    import struct
    import tracemalloc

    data = bytearray(png_bytes(9, 13))
    idat = data.find(b"IDAT") - 4
    struct.pack_into(">I", data, idat, 0xD1000000 + struct.unpack_from(">I", data, idat)[0])
    (tmp_path / "p.png").write_bytes(bytes(data))
    tracemalloc.start()
    try:
        with pytest.raises(ValueError, match="past the end of the"):
            photo.read_photo(tmp_path / "p.png")
        with pytest.raises(ValueError, match="past the end of the"):
            photo.read_mask(tmp_path / "p.png", (9, 13))
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * 2**20, peak


def test_declared_size_is_weighed_against_free_memory(tmp_path, monkeypatch):
    path = tmp_path / "p.jpg"
    path.write_bytes(jpeg_bytes(300, 200))
    free = 300 * 200 * image_limits.BYTES_PER_PIXEL - 1  # one byte short of what decoding needs
    monkeypatch.setattr(image_limits, "memory_available", lambda: free)
    with pytest.raises(ValueError, match="needs about"):
        photo.read_photo(path)
    monkeypatch.setattr(image_limits, "memory_available", lambda: free + 1)
    assert photo.read_photo(path)[0].shape == (300, 200, 3)
    # maps too: a 64 x 32 map needs MAP_BYTES_PER_PIXEL per texel
    hdr = tmp_path / "m.hdr"
    hdr.write_bytes(radiance_hdr(32, 64))
    monkeypatch.setattr(image_limits, "memory_available", lambda: 64 * 32 * envmap.MAP_BYTES_PER_PIXEL - 1)
    with pytest.raises(ValueError, match="needs about"):
        envmap.load_equirect(hdr)
    monkeypatch.setattr(image_limits, "memory_available", lambda: 64 * 32 * envmap.MAP_BYTES_PER_PIXEL)
    assert envmap.load_equirect(hdr).shape == (32, 64)


def test_pixel_limit_and_max_pixels_option(tmp_path, model, capsys):
    path = _photo(tmp_path / "p.png", h=40, w=30)
    with pytest.raises(ValueError, match=r"over the limit of 0.001 MP \(--max-pixels 1200 allows it\)"):
        photo.read_photo(path, max_pixels=1000)
    assert photo.read_photo(path, max_pixels=1200)[0].shape == (40, 30, 3)
    with pytest.raises(ValueError, match="max_pixels"):
        photo.read_photo(path, max_pixels=image_limits.MAX_PIXELS + 1)
    base = ["image", str(path), "--light", "studio", "--model", model, "--matte", "network", "--quality", "draft",
            "--out", str(tmp_path / "o.png")]
    assert main([*base, "--max-pixels", "1199"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and "--max-pixels 1200 allows it" in err
    assert main([*base, "--max-pixels", "1200"]) == 0


# ------------------------------------------------------------------ 4. full disk, and the EXR library's own messages


@pytest.mark.parametrize("suffix", [".exr", ".png"])
def test_full_disk_is_one_line_and_keeps_the_old_output(tmp_path, model, suffix):
    src = _photo(tmp_path / "p.png", h=300, w=200, seed=4)
    out = tmp_path / f"out{suffix}"
    out.write_bytes(b"previous result")
    res, elapsed = run_cli("image", src, "--light", "studio", "--model", model, "--quality", "draft",
                           "--out", out, file_size_limit=64 * 1024)  # both outputs are > 64 KiB
    # issue 48: the line names the output and the cause (a PNG's was "[Errno 27] File too large")
    assert_refused(res, elapsed, "image", match="File too large")
    assert str(out) in res.stderr and "Errno" not in res.stderr, res.stderr
    assert out.read_bytes() == b"previous result"
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted(["p.png", out.name])  # no temp file left


@pytest.mark.parametrize("command", ["sh", "image-photo", "image-light"])
def test_damaged_exr_gives_exactly_one_stderr_line(tmp_path, model, command):
    rng = np.random.default_rng(1)
    data = exr_bytes(tmp_path, {c: rng.random((32, 64)).astype(np.float32) for c in "RGB"})
    bad = tmp_path / "bad.exr"
    bad.write_bytes(data[: len(data) // 2])  # the library prints a C-level message on this one
    if command == "sh":
        res, elapsed = run_cli("sh", bad)
    elif command == "image-photo":
        res, elapsed = run_cli("image", bad, "--light", "studio", "--model", model, "--quality", "draft",
                               "--out", tmp_path / "o.png")
    else:
        res, elapsed = run_cli("image", _photo(tmp_path / "p.png"), "--light", bad, "--model", model,
                               "--quality", "draft", "--out", tmp_path / "o.png")
    assert_refused(res, elapsed, command.split("-")[0], match="bad.exr")
    assert not (tmp_path / "o.png").exists()


# ------------------------------------------------------------------ 5. argument bounds


@pytest.mark.parametrize("args, match", [
    (["--threads", "100000"], "argument --threads: must be an integer in [1, "),
    (["--threads", "0"], "argument --threads"),
    (["--rotate", "1e308"], "argument --rotate: must be a finite angle"),
    (["--rotate", "-inf"], "argument --rotate: must be a finite angle"),
    (["--exposure", "-1e9"], "exposure must be a finite number of EV within +-64, got -1000000000.0"),
    (["--exposure", "nan"], "exposure must be a finite number of EV"),
    (["--exposure", "bright"], "argument --exposure: invalid float value: 'bright'"),
    (["--max-pixels", "-5"], "argument --max-pixels"),
])
def test_out_of_range_arguments_are_one_line(tmp_path, model, args, match, capsys):
    code = main(["image", str(_photo(tmp_path / "p.png")), "--light", "studio", "--model", model,
                 "--out", str(tmp_path / "o.png"), *args])
    out, err = capsys.readouterr()
    assert code == 2 and out == "" and len(err.splitlines()) == 1 and match in err, err
    assert not (tmp_path / "o.png").exists()


def test_huge_thread_count_is_refused_at_once(tmp_path, model):
    res, elapsed = run_cli("image", _photo(tmp_path / "p.png"), "--light", "studio", "--model", model,
                           "--out", tmp_path / "o.png", "--threads", "100000")
    assert_refused(res, elapsed, "image", match="argument --threads")
    assert elapsed < 20 and not (tmp_path / "o.png").exists()


def test_negative_numbers_are_values(tmp_path, model, capsys):
    assert main(["sh", "studio", "--rotate", "-90", "--json"]) == 0
    minus = np.array(json.loads(capsys.readouterr().out)["coeffs"])
    assert main(["sh", "studio", "--rotate", "2.7e2", "--json"]) == 0
    plus = np.array(json.loads(capsys.readouterr().out)["coeffs"])
    np.testing.assert_allclose(minus, plus, atol=1e-8)  # -90 and 270 degrees are one rotation
    path = _photo(tmp_path / "p.png")
    out = tmp_path / "o.png"
    assert main(["image", str(path), "--light", "studio", "--exposure", "-1e0", "--model", model, "--matte", "network",
                 "--quality", "draft", "--out", str(out)]) == 0, capsys.readouterr().err
    d = Relighter(model, working_size=DRAFT_SIZE).decompose(photo.read_photo(path)[0], matte="network",
                                                          **preset("draft").decompose_options(working_size=False))
    expect = d.relight(sh_light("studio", d.sh_order), -1.0)
    got = np.asarray(Image.open(out)) / 255.0
    assert np.max(np.abs(got - srgb_encode(expect))) <= 0.5 / 255 + 1e-6  # half an 8-bit step


# ------------------------------------------------------------------ 6. registry entries outside relight/models/


def test_model_named_by_absolute_path_is_checked_against_the_registry(tmp_path, model):
    outside = tmp_path / "elsewhere" / "m.onnx"
    outside.parent.mkdir()
    outside.write_bytes(open(model, "rb").read())
    digest = write_sidecar(outside).read_text().split()[0]
    registry = tmp_path / "registry" / "models.json"
    registry.parent.mkdir()
    registry.write_text(json.dumps({"format": "relight-models/1", "default": "m",
                                    "models": {"m": {"file": str(outside), "sha256": digest, "metadata": {}}}}))
    assert Relighter(None, registry_path=registry).sha256 == digest
    # tamper with the model and rewrite the sidecar to match: the registry's hash still refuses it
    tampered = bytearray(outside.read_bytes())
    tampered[len(tampered) // 2] ^= 0xFF
    outside.write_bytes(bytes(tampered))
    write_sidecar(outside)
    with pytest.raises(ValueError, match="SHA-256 mismatch"):
        Relighter(outside, registry_path=registry)
    with pytest.raises(ValueError, match="SHA-256 mismatch"):
        Relighter(None, registry_path=registry)
    # an entry for it that records no usable hash is refused, not skipped over to the sidecar
    registry.write_text(json.dumps({"format": "relight-models/1", "default": "m",
                                    "models": {"m": {"file": str(outside), "sha256": "", "metadata": {}}}}))
    with pytest.raises(ValueError, match="records no valid SHA-256"):
        Relighter(outside, registry_path=registry)


# ------------------------------------------------------------------ 7. one output by two names (issue 48)


def test_relight_video_into_a_folder_by_its_alias_is_refused_while_it_is_written(tmp_path, capsys):
    """Two runs into one folder, one through a symlink to it: the second waits for nothing and
    writes nothing (relight image's and relight light's cases: tests/relight/command/test_cli_image.py,
    tests/relight/lighting/test_light_map.py; the lock: tests/relight/files/test_fileio.py)."""
    from clip_support import person_clip, write_frames
    from fuzz_support import writer_holding

    src = write_frames(tmp_path / "in", person_clip(2))
    real = tmp_path / "outA"
    real.mkdir()
    (tmp_path / "alias").symlink_to(real, target_is_directory=True)
    with writer_holding(real) as other:
        code = main(["video", str(src), "--light", "studio", "--out", str(tmp_path / "alias"), "--quality", "draft",
                     "--threads", "1"])
        err = capsys.readouterr().err
        assert code == 2 and err.count("\n") == 1, err
        assert f"another relight run (process {other.pid}) is writing {tmp_path / 'alias'}" in err, err
    assert list(real.iterdir()) == []
