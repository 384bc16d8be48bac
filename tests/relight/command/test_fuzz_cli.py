"""Fuzzing the `relight sh` and `relight image` argument handling (Hypothesis; profile in fuzz_support).

Generated command lines mix good and hostile values (numbers as text such as
1e308, -1e9, -inf, nan, 0x10; random text; forged, damaged and overflowing
maps and photos; bad output paths). Property, read at the file-descriptor
level (so C libraries' own prints count): exit 0 with finite output (JSON
coefficients, or an output image whose values are finite), or a non-zero
exit whose stderr is one `relight ...: error:` line (after any warnings);
never a traceback, another exception, or NaN with exit 0.
"""

from __future__ import annotations

import json
import math
import tempfile
import warnings
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from PIL import Image

from export.random_model import export_random_model
from fuzz_support import accepted_share, exr_bytes, fuzz_settings, jpeg_bytes, new_case, radiance_hdr, record
from relight.cli import main
from relight.files.exr import read_exr


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, str]:
    tmp = tmp_path_factory.mktemp("fuzz-cli")
    model, _, _ = export_random_model(tmp / "tiny.onnx", seed=3, sh_order=4, width=4, depth=2)
    rng = np.random.default_rng(0)
    Image.fromarray(rng.integers(30, 220, (40, 30, 3), dtype=np.uint8)).save(tmp / "photo.png")
    Image.fromarray(np.full((40, 30), 255, np.uint8)).save(tmp / "mask.png")
    Image.fromarray(np.full((10, 10), 255, np.uint8)).save(tmp / "mask-small.png")
    (tmp / "forged.jpg").write_bytes(jpeg_bytes(declared=(12000, 12000)))
    (tmp / "forged-4mp.jpg").write_bytes(jpeg_bytes(declared=(2000, 2000)))
    damaged = exr_bytes(tmp, {c: rng.random((16, 32)).astype(np.float32) for c in "RGB"})
    (tmp / "damaged.exr").write_bytes(damaged[: len(damaged) // 2])
    (tmp / "max.exr").write_bytes(exr_bytes(tmp, {c: np.full((16, 32), 3e38, np.float32) for c in "RGB"}))
    (tmp / "e255.hdr").write_bytes(radiance_hdr(16, 32, exponent=255))
    (tmp / "ok.hdr").write_bytes(radiance_hdr(16, 32, rle=True))
    (tmp / "forged.hdr").write_bytes(radiance_hdr(16, 32, declared=("100000", "200000")))
    (tmp / "folder").mkdir()
    Image.fromarray(rng.integers(30, 220, (24, 20, 3), dtype=np.uint8)).save(tmp / "folder" / "a.png")
    (tmp / "folder" / "b.jpg").write_bytes(b"not a jpeg")
    tampered = bytearray(Path(model).read_bytes())
    tampered[len(tampered) // 2] ^= 1
    (tmp / "tampered.onnx").write_bytes(bytes(tampered))
    Path(str(tmp / "tampered.onnx") + ".sha256").write_text(Path(str(model) + ".sha256").read_text())
    names = ["photo.png", "mask.png", "mask-small.png", "forged.jpg", "forged-4mp.jpg", "damaged.exr", "max.exr",
             "e255.hdr", "ok.hdr", "forged.hdr", "folder", "tampered.onnx"]
    return {"dir": str(tmp), "model": str(model), "missing": str(tmp / "missing.png"),
            **{name: str(tmp / name) for name in names}}


NUMBER_TEXT = st.one_of(
    st.integers(1, 8).map(str),  # values most options accept, so that runs get past parsing too
    st.floats(-360, 360).map(lambda v: f"{v:.6g}"),
    st.integers(-10**6, 10**6).map(str),
    st.floats(allow_nan=True, allow_infinity=True).map(repr),
    st.sampled_from(["1e308", "-1e9", "-inf", "inf", "nan", "-nan", "1e-320", "0", "-0", "100000", "9" * 30,
                     "0x10", "1_000", " 5", "", "-", "--", "-1e", "1e400"]),
    st.text(max_size=6),
)
MAPS = ["studio", "sky", "no-such-preset", "e255.hdr", "max.exr", "ok.hdr", "forged.hdr", "damaged.exr", "missing"]


def _file(files, name: str) -> str:
    return files.get(name, name)


@st.composite
def sh_argv(draw, files) -> list[str]:
    argv = ["sh", _file(files, draw(st.sampled_from(MAPS)))]
    for option in draw(st.lists(st.sampled_from(["--order", "--rotate", "--target", "--window", "--normalize",
                                                 "--json", "--bogus"]), max_size=3)):
        argv.append(option)
        if option in ("--order", "--rotate", "--target"):
            argv.append(draw(NUMBER_TEXT))
        elif option == "--window":
            argv.append(draw(st.sampled_from(["none", "hanning", "lanczos", "x"])))
    if draw(st.booleans()):
        argv.append("--json")
    return argv


@st.composite
def image_argv(draw, files, out_dir: str) -> list[str]:
    sane = draw(st.booleans())  # half the cases: valid files, only the options fuzzed (else most runs end early)
    photo = "photo.png" if sane else draw(st.sampled_from(["photo.png", "forged.jpg", "forged-4mp.jpg",
                                                           "damaged.exr", "folder", "missing"]))
    argv = ["image", _file(files, photo)]
    if draw(st.integers(0, 5)) == 0:
        argv += ["--light-from", _file(files, draw(st.sampled_from(["photo.png", "forged.jpg", "missing"])))]
    else:
        argv += ["--light", _file(files, draw(st.sampled_from(MAPS[:6] if sane else MAPS)))]
    model = "model" if sane else draw(st.sampled_from(["model", "tampered.onnx", "missing"]))
    argv += ["--model", files[model], "--quality", "draft"]
    argv += ["--matte", "network" if sane else draw(st.sampled_from(["network", "person", "bogus"]))]
    out = draw(st.sampled_from(["o.png", "o.exr", None] if sane else ["o.png", "o.txt", "nowhere/o.png", "outdir",
                                                                       "=input", "o.gif"]))
    if out == "=input":  # issue 40: the output is the photo (or folder) itself: refused, the input kept
        argv += ["--out", argv[1]]
    elif out is not None:
        argv += ["--out", str(Path(out_dir) / out)]
    for option in draw(st.lists(st.sampled_from(["--rotate", "--exposure", "--threads", "--max-pixels", "--person",
                                                 "--mask", "--layers", "--no-normalize", "--quality"]), max_size=3)):
        argv.append(option)
        if option == "--mask":
            argv.append(_file(files, draw(st.sampled_from(["mask.png", "mask-small.png", "damaged.exr", "missing"]))))
        elif option == "--quality":
            argv.append(draw(st.sampled_from(["draft", "best", "huge"])))
        elif option in ("--rotate", "--exposure", "--threads", "--max-pixels", "--person"):
            argv.append(draw(NUMBER_TEXT))
    return argv


def _check_run(prop: str, argv: list[str], capfd) -> tuple[int, str]:
    try:
        with warnings.catch_warnings(record=True) as caught:  # a Python warning is stderr lines for a user
            warnings.simplefilter("always")
            code = main(argv)
    except BaseException as exc:  # main() must turn everything into an exit status
        record(prop, type(exc).__name__)
        raise
    out, err = capfd.readouterr()
    if caught:
        record(prop, "warning")
    assert not caught, [f"{w.category.__name__}: {w.message}" for w in caught]
    record(prop, f"exit {code}")
    assert code in (0, 1, 2), code
    assert "Traceback" not in err and "Warning:" not in err, err
    lines = err.splitlines()
    if code != 0:
        errors = [line for line in lines if ": error: " in line]
        assert len(errors) == 1 and lines[-1] == errors[0] and lines[-1].startswith("relight"), err
        assert all(line.startswith(("relight image: warning: ", "relight image: failed: ")) for line in lines[:-1]), err
    else:
        assert all(line.startswith("relight image: warning: ") for line in lines), err
    return code, out


def test_fuzz_sh_arguments(files, capfd):
    # a run ends in exit 0 when its map and options are good; no branch is good by
    # construction (any option may take a hostile number): the floor is "some accepted"
    @given(st.data())
    @fuzz_settings()
    def case(data):
        argv = data.draw(sh_argv(files))
        new_case("test_fuzz_sh_arguments")
        code, out = _check_run("cli.sh", argv, capfd)
        if code == 0 and "-h" not in argv and "--help" not in argv:
            if out.startswith("{"):  # --json
                coeffs = np.array(json.loads(out)["coeffs"], dtype=np.float64)
                assert coeffs.ndim == 2 and coeffs.shape[1] == 3 and np.all(np.isfinite(coeffs))
            else:
                values = [float(v) for line in out.splitlines()[1:] for v in line.split()[2:]]
                assert values and all(math.isfinite(v) for v in values)

    with accepted_share("cli.sh", 0.0, accepted=("exit 0",)):
        case()


def test_fuzz_image_arguments(files, capfd):
    # "sane" cases have good files, but their options are fuzzed: the floor is "some accepted"
    @given(st.data())
    @fuzz_settings(0.5)  # each case loads a model and runs the network: slower than the others
    def case(data):
        out_dir = tempfile.mkdtemp(dir=files["dir"])
        (Path(out_dir) / "outdir").mkdir()
        argv = data.draw(image_argv(files, out_dir))
        new_case("test_fuzz_image_arguments")
        out = argv[argv.index("--out") + 1] if "--out" in argv else None
        onto_input = out is not None and out == argv[1]
        before = Path(out).read_bytes() if onto_input and Path(out).is_file() else None
        code, _ = _check_run("cli.image", argv, capfd)
        if onto_input:
            assert code == 2, argv
            assert before is None or Path(out).read_bytes() == before  # the input is kept byte for byte
        written = [p for p in Path(out_dir).rglob("*") if p.is_file()]
        if code == 2:
            assert written == [], written  # nothing partial
        for path in written:
            assert not path.name.startswith("."), path  # no temporary file left behind
            if path.suffix == ".exr":
                assert all(np.all(np.isfinite(a)) for a in read_exr(path).values())
            else:
                with Image.open(path) as im:
                    im.load()

    with accepted_share("cli.image", 0.0, accepted=("exit 0",)):
        case()
