"""`relight image`: single photo, layers, folders, and every bad-input path."""

from __future__ import annotations

import numpy as np
from PIL import Image

from relight.cli import main
from relight.imaging.colour import srgb_encode
from relight.files.exr import read_exr, write_exr
from relight.files.photo import read_photo
from relight.lighting.light import sh_light
from relight.network.runtime import Relighter
from relight.network.quality import preset

DRAFT_SIZE = preset("draft").working_size  # the Draft preset's working size
DRAFT = preset("draft").decompose_options(working_size=False)  # what --quality draft decomposes with


def _save_photo(path, h=40, w=30, seed=0, alpha=False):
    rng = np.random.default_rng(seed)
    u8 = rng.integers(30, 220, (h, w, 4 if alpha else 3), dtype=np.uint8)
    if alpha:
        u8[..., 3] = 0
        u8[5:35, 5:25, 3] = 255
    Image.fromarray(u8).save(path)
    return path


def _run(capsys, *argv):
    if "--quality" not in argv:
        argv = (*argv, "--quality", "draft")  # the smallest working size: keeps the tests fast
    if "--matte" not in argv:
        # these synthetic photos show no person: here the relighting is tested, with the
        # network's own matte; the person matte has its tests in tests/relight/person/test_matte.py
        argv = (*argv, "--matte", "network")
    code = main(["image", *map(str, argv)])
    out, err = capsys.readouterr()
    return code, out, err


def test_single_photo_matches_the_api(model, tmp_path, capsys):
    photo = _save_photo(tmp_path / "p.png")
    out = tmp_path / "o.png"
    code, stdout, err = _run(capsys, photo, "--light", "studio", "--rotate", 30, "--exposure", 0.5,
                             "--model", model, "--out", out, "--quality", "draft")
    assert code == 0, err
    assert f"wrote {out}" in stdout
    img, _ = read_photo(photo)
    d = Relighter(model, working_size=DRAFT_SIZE).decompose(img, matte="network", **DRAFT)
    expect = d.relight(sh_light("studio", d.sh_order, rotation_deg=30), 0.5)
    got = np.asarray(Image.open(out)) / 255.0
    # 8-bit sRGB output: within half a code value of the encoded API result
    assert np.max(np.abs(got - srgb_encode(expect))) <= 0.5 / 255 + 1e-6


def test_the_light_and_the_exposure_are_checked_once_on_the_commands_path(model, tmp_path, capsys, monkeypatch):
    # issue 39: the light where relight.lighting.light resolves it, --exposure by its argparse type; the
    # decomposition trusts both (the command hands it a relight.lighting.light.CheckedLight), its public
    # relight checks raw coefficients
    from relight.lighting import light, sh

    calls = {"light": 0, "exposure": 0}

    def counted(fn, key):
        def wrapped(*args, **kwargs):
            calls[key] += 1
            return fn(*args, **kwargs)
        return wrapped

    monkeypatch.setattr(sh, "validate_coeffs", counted(sh.validate_coeffs, "light"))
    monkeypatch.setattr(light, "exposure_scale", counted(light.exposure_scale, "exposure"))
    photo = _save_photo(tmp_path / "p.png")
    for out, extra in ((tmp_path / "o.png", ()), (tmp_path / "o.exr", ("--layers",))):
        calls.update(light=0, exposure=0)
        code, _, err = _run(capsys, photo, "--light", "studio", "--exposure", 0.5, "--model", model, "--out", out,
                            *extra)
        assert code == 0, err
        assert calls == {"light": 1, "exposure": 1}, extra


def test_the_sh_order_is_checked_where_the_light_and_the_decomposition_are_made(model, tmp_path, capsys):
    # issue 49: relight image checked the SH order 11 times on its way (each SH helper again); now once
    # where the light is made (the map's projection) and once where the decomposition is (the model's
    # order), with --layers too; everything after trusts them
    import sys
    import threading

    from relight.files.sh_sizes import check_order

    photo = _save_photo(tmp_path / "p.png")
    for out, extra in ((tmp_path / "o.png", ()), (tmp_path / "o.exr", ("--layers",))):
        runs = []

        def profile(frame, event, arg):
            if event == "call" and frame.f_code is check_order.__code__:
                runs.append(frame.f_locals["order"])

        threading.setprofile(profile)
        sys.setprofile(profile)
        try:
            code, _, err = _run(capsys, photo, "--light", "studio", "--model", model, "--out", out, *extra)
        finally:
            sys.setprofile(None)
            threading.setprofile(None)
        assert code == 0, err
        assert runs == [4, 4], extra  # the light's projection, the decomposition: the tiny model's order 4


def test_the_working_size_is_given_once_to_the_relighter(model, tmp_path, capsys, monkeypatch):
    # issue 39: relight image opens its Relighter at --quality's working size; its decompose is not told again
    import json

    seen = []
    decompose = Relighter.decompose

    def recorded(self, *args, **kwargs):
        seen.append((self.working_size, kwargs))
        return decompose(self, *args, **kwargs)

    monkeypatch.setattr(Relighter, "decompose", recorded)
    code, stdout, err = _run(capsys, _save_photo(tmp_path / "p.png"), "--light", "studio", "--model", model,
                             "--out", tmp_path / "o.png", "--json")
    assert code == 0, err
    assert [(size, "working_size" in kwargs) for size, kwargs in seen] == [(DRAFT_SIZE, False)]
    assert json.loads(stdout.splitlines()[0])["working_size"] == DRAFT_SIZE


def test_default_output_name_and_exr_output(model, tmp_path, capsys):
    photo = _save_photo(tmp_path / "p.png", alpha=True)
    code, _, err = _run(capsys, photo, "--light", "city", "--model", model)
    assert code == 0, err
    assert (tmp_path / "p_relit.png").is_file()
    code, _, err = _run(capsys, photo, "--light", "city", "--model", model, "--out", tmp_path / "o.exr")
    assert code == 0, err
    img, _ = read_photo(photo)
    got, _ = read_photo(tmp_path / "o.exr")
    # the photo's alpha is the mask: transparent pixels are the untouched photo
    np.testing.assert_array_equal(got[:5], img[:5])


def test_light_transfer_from_another_photo(model, tmp_path, capsys):
    photo = _save_photo(tmp_path / "p.png", seed=1)
    donor = _save_photo(tmp_path / "donor.png", seed=2)
    out = tmp_path / "t.exr"
    code, _, err = _run(capsys, photo, "--light-from", donor, "--model", model, "--out", out)
    assert code == 0, err
    r = Relighter(model, working_size=DRAFT_SIZE)
    d = r.decompose(read_photo(photo)[0], matte="network", **DRAFT)
    expect = d.relight(r.decompose(read_photo(donor)[0], matte="network", **DRAFT).light)
    # (reading an EXR photo clamps negative radiance, which a random network can produce)
    np.testing.assert_array_equal(read_photo(out)[0], np.maximum(expect, 0))
    code, _, err = _run(capsys, photo, "--light", "studio", "--light-from", donor, "--model", model)
    assert code == 2 and "not allowed with" in err


def test_layers_exr(model, tmp_path, capsys):
    photo = _save_photo(tmp_path / "p.png")
    out = tmp_path / "l.exr"
    code, _, err = _run(capsys, photo, "--light", "city", "--model", model, "--out", out, "--layers")
    assert code == 0, err
    ch = read_exr(out)
    assert {"Relight.Relit.R", "Relight.Albedo.G", "Relight.Shading.B", "Relight.Residual.R",
            "Relight.Alpha.A"} <= set(ch)
    assert ch["Relight.Relit.R"].shape == (40, 30)


def test_folder_goes_on_after_a_failure(model, tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    for i in range(2):
        _save_photo(src / f"p{i}.png", seed=i)
    (src / "broken.jpg").write_bytes(b"\xff\xd8\xff\xe0 not really a jpeg")
    (src / "notes.txt").write_text("ignored: not a photo suffix")
    out = tmp_path / "out"
    code, stdout, err = _run(capsys, src, "--light", "studio", "--model", model, "--out", out)
    assert code == 1
    assert sorted(p.name for p in out.iterdir()) == ["p0.png", "p1.png"]
    assert "relit 2 of 3 photos" in stdout
    assert "broken.jpg" in err.strip().splitlines()[-1]


def _bad_cases(tmp_path, model):
    photo = _save_photo(tmp_path / "p.png")
    cases = {}
    (tmp_path / "empty.png").write_bytes(b"")
    cases["empty"] = ([tmp_path / "empty.png"], "empty")
    data = (tmp_path / "p.png").read_bytes()
    (tmp_path / "trunc.png").write_bytes(data[: len(data) // 2])
    cases["truncated"] = ([tmp_path / "trunc.png"], "truncated|corrupt")
    (tmp_path / "text.png").write_text("hello")
    cases["non-image"] = ([tmp_path / "text.png"], "not a readable image")
    cases["missing"] = ([tmp_path / "nope.png"], "no such file")
    import struct
    import zlib

    def chunk(kind, body):
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))
    (tmp_path / "huge.png").write_bytes(
        b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 45000, 45000, 8, 2, 0, 0, 0))
        + chunk(b"IDAT", zlib.compress(bytes(100))) + chunk(b"IEND", b""))
    cases["huge header"] = ([tmp_path / "huge.png"], "too large")
    Image.fromarray(np.full((10, 10), 255, np.uint8)).save(tmp_path / "small_mask.png")
    cases["mask size"] = ([photo, "--mask", tmp_path / "small_mask.png"], "mask is 10x10")
    Image.fromarray(np.zeros((40, 30), np.uint8)).save(tmp_path / "zero_mask.png")
    cases["mask all zero"] = ([photo, "--mask", tmp_path / "zero_mask.png"], "empty")
    nan = np.full((8, 16), np.nan, np.float32)
    write_exr(tmp_path / "nan.exr", {"R": nan, "G": nan, "B": nan})
    cases["hdr nan"] = ([photo, "--light", tmp_path / "nan.exr"], "NaN")
    cases["unknown preset"] = ([photo, "--light", "nowhere"], "neither a file nor a preset")
    cases["layers png"] = ([photo, "--layers", "--out", tmp_path / "x.png"], "--layers")
    cases["bad suffix"] = ([photo, "--out", tmp_path / "x.jpg"], ".png or .exr")
    tampered = tmp_path / "t.onnx"
    raw = bytearray(open(model, "rb").read())
    raw[100] ^= 1
    tampered.write_bytes(bytes(raw))
    (tmp_path / "t.onnx.sha256").write_text(open(f"{model}.sha256").read())
    cases["tampered model"] = ([photo, "--model", tampered], "SHA-256 mismatch")
    return cases


def test_every_bad_input_is_one_line_and_writes_nothing(model, tmp_path, capsys):
    for name, (args, message) in _bad_cases(tmp_path, model).items():
        argv = list(args)
        if "--light" not in argv:
            argv += ["--light", "studio"]
        if "--model" not in argv:
            argv += ["--model", model]
        if "--out" not in argv:
            argv += ["--out", tmp_path / "result.png"]
        before = sorted(p.name for p in tmp_path.iterdir())
        code, _, err = _run(capsys, *argv)
        assert code != 0, name
        lines = err.strip().splitlines()
        assert len(lines) == 1 and lines[0].startswith("relight image: error:"), (name, err)
        import re

        assert re.search(message, lines[0]), (name, lines[0])
        assert sorted(p.name for p in tmp_path.iterdir()) == before, name


def test_folder_mode_usage_errors(model, tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    code, _, err = _run(capsys, src, "--light", "studio", "--model", model)
    assert code == 2 and "needs --out" in err
    code, _, err = _run(capsys, src, "--light", "studio", "--model", model, "--out", tmp_path / "o")
    assert code == 2 and "no photos" in err
    assert not (tmp_path / "o").exists()


# ------------------------------------------------------------------ issue 40: outputs


def test_an_output_that_is_one_of_the_inputs_is_refused_and_the_input_kept(model, tmp_path, capsys):
    photo = _save_photo(tmp_path / "p.png")
    (tmp_path / "link.png").symlink_to(photo)
    (tmp_path / "sub").mkdir()
    light = tmp_path / "map.exr"
    ones = np.ones((8, 16), np.float32)
    write_exr(light, {"R": ones, "G": ones, "B": ones})
    Image.fromarray(np.full((40, 30), 255, np.uint8)).save(tmp_path / "m.png")
    kept = {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()}
    cases = [[photo, "--out", photo],                                   # the photo itself
             [photo, "--out", tmp_path / "link.png"],                   # through a symlink
             [tmp_path / "link.png", "--out", tmp_path / "sub" / ".." / "p.png"],
             [photo, "--out", tmp_path / "m.png", "--mask", tmp_path / "m.png"],
             [photo, "--out", light, "--light", light]]
    for argv in cases:
        if "--light" not in argv:
            argv += ["--light", "studio"]
        code, _, err = _run(capsys, *argv, "--model", model)
        assert code == 2 and err.count("\n") == 1 and "writing would replace it" in err, (argv, err)
        assert {p.name: p.read_bytes() for p in tmp_path.iterdir() if p.is_file()} == kept, argv


def test_a_second_writer_of_one_output_is_refused_and_kill_9_leftovers_are_cleared(model, tmp_path, capsys):
    from fuzz_support import writer_holding

    src = tmp_path / "in"
    src.mkdir()
    _save_photo(src / "p0.png")
    out = tmp_path / "out"
    for target, argv in ((out, [src, "--out", out]), (tmp_path / "o.png", [src / "p0.png", "--out", tmp_path / "o.png"])):
        # what a run killed with -9 leaves: its temporary beside the output
        leftover = (out if target == out else tmp_path) / ".o.png.abcd_123.tmp.png"
        if target == out:
            out.mkdir()
            leftover = out / ".p0.png.abcd_123.tmp.png"
        leftover.write_bytes(b"half a png")
        with writer_holding(target) as other:
            code, _, err = _run(capsys, *argv, "--light", "studio", "--model", model)
            assert code == 2 and err.count("\n") == 1, err
            assert f"(process {other.pid}) is writing {target}" in err and "wait for it" in err
            assert leftover.exists()  # a live writer's temporaries are its own
            assert not (target / "p0.png").exists() if target == out else not target.exists()
        code, _, err = _run(capsys, *argv, "--light", "studio", "--model", model)
        assert code == 0, err
        assert not leftover.exists()
        assert [p.name for p in tmp_path.iterdir() if p.name.startswith(".")] == []  # no lock file left
    assert sorted(p.name for p in out.iterdir()) == ["p0.png"]


def test_an_output_reached_through_a_symlink_shares_the_lock_of_its_real_path(model, tmp_path, capsys):
    # issue 48: `--out outA` and `--out alias` (alias -> outA) both ran and the folder mixed both lights
    from fuzz_support import writer_holding

    src = tmp_path / "in"
    src.mkdir()
    _save_photo(src / "p0.png")
    real = tmp_path / "outA"
    real.mkdir()
    (tmp_path / "alias").symlink_to(real, target_is_directory=True)
    (tmp_path / "links").symlink_to(tmp_path, target_is_directory=True)  # an alias of the parent folder
    _save_photo(tmp_path / "p.png")
    cases = [(real, [src, "--out", tmp_path / "alias"]),
             (real, [src, "--out", tmp_path / "links" / "outA"]),
             (tmp_path / "o.png", [tmp_path / "p.png", "--out", tmp_path / "links" / "o.png"])]
    for held, argv in cases:
        with writer_holding(held) as other:
            code, _, err = _run(capsys, *argv, "--light", "studio", "--model", model)
            assert code == 2 and err.count("\n") == 1, (argv, err)
            assert f"(process {other.pid}) is writing" in err and "wait for it" in err, err
        assert list(real.iterdir()) == [] and not (tmp_path / "o.png").exists()


def test_a_planted_symlink_at_the_lock_path_is_refused_and_never_followed(model, tmp_path, capsys):
    # issue 48: a symlink planted as .o.png.lock was followed: the file it names was truncated
    # and overwritten with a process id
    import os

    _save_photo(tmp_path / "p.png")
    victim = tmp_path / "victim.txt"
    victim.write_text("the user's data\n")
    for out in (tmp_path / "o.png", tmp_path / "out"):
        argv = [tmp_path / "p.png" if out.suffix else _folder_of_one(tmp_path), "--out", out]
        planted = tmp_path / f".{out.name}.lock"
        for target in (victim, tmp_path / "nowhere"):  # to a file, and dangling (O_CREAT would make it)
            planted.symlink_to(target)
            code, _, err = _run(capsys, *argv, "--light", "studio", "--model", model)
            assert code == 2 and err.count("\n") == 1, err
            assert str(planted) in err and "symbolic link" in err, err
            assert victim.read_text() == "the user's data\n" and not (tmp_path / "nowhere").exists()
            assert not out.exists() and os.path.islink(planted)  # refused, not removed: the user decides
            planted.unlink()
        fifo = tmp_path / f".{out.name}.lock"
        os.mkfifo(fifo)  # not a regular file: refused too (opening it must not block)
        code, _, err = _run(capsys, *argv, "--light", "studio", "--model", model)
        assert code == 2 and str(fifo) in err and "not a regular file" in err, err
        fifo.unlink()
        code, _, err = _run(capsys, *argv, "--light", "studio", "--model", model)
        assert code == 0 and out.exists(), err


def _folder_of_one(tmp_path):
    src = tmp_path / "one"
    if not src.exists():
        src.mkdir()
        _save_photo(src / "p0.png")
    return src


def test_the_cores_refusals_of_a_photo_or_a_map_name_the_file(model, tmp_path, capsys):
    # issue 48: "photo is too small for a person matte", "light has mean luminance 0" and, for
    # --light-from, "no person found in the photo" named no file
    from relight.cli import main

    tiny = _save_photo(tmp_path / "tiny.png", h=20, w=20)
    noise = _save_photo(tmp_path / "noise.png", h=80, w=60)  # no person in it
    black = tmp_path / "black.exr"
    write_exr(black, {c: np.zeros((16, 32), np.float32) for c in "RGB"})
    out = tmp_path / "o.png"
    person = ["--matte", "person"]
    cases = [([tiny, "--light", "studio", *person], f"{tiny}: photo is too small for a person matte (20x20;"),
             ([noise, "--light", black], f"{black}: light has mean luminance 0 <= 0"),
             ([noise, "--light-from", noise, *person], f"--light-from {noise}: no person found in the photo"),
             ([noise, "--light-from", tiny, *person], f"--light-from {tiny}: photo is too small for a person matte"),
             ([noise, "--light", "studio", *person], f"{noise}: no person found in the photo: give a mask (--mask)")]
    for argv, said in cases:
        code, _, err = _run(capsys, *argv, "--model", model, "--out", out)
        assert code == 2 and err.count("\n") == 1 and err.startswith(f"relight image: error: {said}"), err
        assert "--light-from" not in argv or "--mask" not in err  # the other photo's option is no advice here
    code = main(["light", str(tiny), "--out", str(tmp_path / "l.exr"), "--model", model, "--quality", "draft"])
    err = capsys.readouterr().err
    assert code == 2 and err == f"relight light: error: {tiny}: photo is too small for a person matte (20x20; " \
                                "need at least 32 px a side)\n", err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["black.exr", "noise.png", "tiny.png"]


def test_folder_mode_refuses_an_output_named_as_a_file_of_another_format(model, tmp_path, capsys):
    src = tmp_path / "in"
    src.mkdir()
    _save_photo(src / "p0.png")
    code, _, err = _run(capsys, src, "--light", "studio", "--model", model, "--out", tmp_path / "o.gif")
    assert code == 2 and ".gif is not a format" in err and "folder name without an extension" in err
    assert not (tmp_path / "o.gif").exists()
    code, _, err = _run(capsys, src, "--light", "studio", "--model", model, "--out", tmp_path / "run.2")
    assert code == 0, err  # a folder name with a dot is a folder name


def test_too_bright_advises_only_what_helps(model, tmp_path, capsys):
    import re

    photo = _save_photo(tmp_path / "p.png")
    out = tmp_path / "o.png"
    code, _, err = _run(capsys, photo, "--light", "studio", "--exposure", 64, "--model", model, "--out", out)
    assert code == 2 and "too bright" in err and not out.exists()
    assert "--no-normalize" not in err  # it was not given: dropping it cannot help
    most = re.search(r"give --exposure (\S+) or lower", err)
    assert most, err
    # the advice is right: the exposure it names relights
    code, _, err = _run(capsys, photo, "--light", "studio", "--exposure", most.group(1), "--model", model,
                        "--out", out)
    assert code == 0, err


def test_folder_progress_is_reported_when_stderr_is_not_a_terminal(model, tmp_path, capsys, monkeypatch):
    from relight.command import cli_output

    src = tmp_path / "in"
    src.mkdir()
    for i in range(3):
        _save_photo(src / f"p{i}.png", seed=i)
    monkeypatch.setattr(cli_output, "PROGRESS_EVERY", 0.0)  # a line at every photo
    code, _, err = _run(capsys, src, "--light", "studio", "--model", model, "--out", tmp_path / "out")
    assert code == 0, err
    lines = [line.split(",")[0] for line in err.strip().splitlines() if " photos (" in line]
    assert lines == [f"relight image: {i} of 3 photos ({100 * i / 3:.0f}%)" for i in (1, 2, 3)]


def test_exposure_is_checked_by_the_parser_before_anything_is_opened(tmp_path, capsys):
    # issue 39: --exposure checked once, by its argparse type, with the library's bound and words
    photo = _save_photo(tmp_path / "p.png")
    for value, words in (("-1e9", "exposure must be a finite number of EV within +-64, got -1000000000.0"),
                         ("nan", "exposure must be a finite number of EV within +-64, got nan"),
                         ("bright", "invalid float value: 'bright'")):
        code, out, err = _run(capsys, photo, "--light", "studio", "--exposure", value, "--model",
                              tmp_path / "no-such-model.onnx", "--out", tmp_path / "o.png")
        assert code == 2 and out == "" and err.splitlines() == [f"relight image: error: argument --exposure: {words}"]
    assert not (tmp_path / "o.png").exists()
