"""The `relight sh` and `relight presets` commands."""

import json
import subprocess
import sys

import numpy as np
import pytest

from relight import cli
from relight.files import exr
from relight.lighting import light, presets, sh, sh_projection, sh_rotation


def run(capsys, *argv):
    code = cli.main(list(argv))
    out, err = capsys.readouterr()
    return code, out, err


def test_sh_json(capsys):
    code, out, err = run(capsys, "sh", "venice", "--order", "3", "--json")
    assert code == 0 and err == ""
    data = json.loads(out)
    assert data["order"] == 3 and len(data["coeffs"]) == 16
    assert all(len(row) == 3 for row in data["coeffs"])
    # printed with 9 decimals
    np.testing.assert_allclose(data["coeffs"], light.sh_light("venice", 3, normalize=False), atol=5e-10)


def test_sh_rotate_and_normalize(capsys, tmp_path):
    img = np.random.default_rng(3).random((16, 32, 3)).astype(np.float32)
    path = tmp_path / "map.exr"
    exr.write_exr(path, {c: img[..., i] for i, c in enumerate("RGB")})
    code, out, _ = run(capsys, "sh", str(path), "--order", "2", "--rotate", "90", "--normalize", "--json")
    assert code == 0
    coeffs = np.array(json.loads(out)["coeffs"])
    projected = sh_projection.project_equirect(img, 2)
    expected, _ = sh.normalize_reference(sh_rotation.rotate(projected, sh_rotation.z_rotation(90)))
    np.testing.assert_allclose(coeffs, expected, atol=5e-10)
    assert abs(sh.mean_luminance(coeffs) - 0.8) < 1e-8


def test_sh_window(capsys):
    code, out, _ = run(capsys, "sh", "sky", "--order", "4", "--window", "lanczos", "--json")
    assert code == 0
    expected = sh.apply_window(light.sh_light("sky", 4, normalize=False), "lanczos")
    np.testing.assert_allclose(json.loads(out)["coeffs"], expected, atol=5e-10)
    code, _, err = run(capsys, "sh", "sky", "--window", "box")
    assert code == 2 and "invalid choice" in err


def test_sh_text_table(capsys):
    code, out, _ = run(capsys, "sh", "studio", "--order", "1")
    lines = out.strip().splitlines()
    assert code == 0 and len(lines) == 1 + 4
    assert lines[2].split()[:2] == ["1", "-1"]


def test_presets(capsys):
    code, out, _ = run(capsys, "presets")
    lines = out.strip().splitlines()
    assert code == 0 and len(lines) == len(presets.list_presets())
    assert "venice\theld-out" in lines and "apartment" in lines


@pytest.mark.parametrize(
    "argv, match",
    [
        (["sh", "no-such-map", "--json"], "neither a file nor a preset"),
        (["sh", "venice", "--order", "-2"], "order"),
        (["sh", "venice", "--order", "two"], "invalid int"),
        (["sh", "venice", "--rotate", "nan"], "angle"),
        (["sh", "venice", "--normalize", "--target", "-1"], "target"),
        (["sh"], "required"),
        ([], "required"),
    ],
)
def test_bad_input_one_line_exit_2(capsys, argv, match):
    code, out, err = run(capsys, *argv)
    assert code == 2 and out == ""
    assert len(err.strip().splitlines()) == 1 and match in err


def test_bad_map_file_one_line(capsys, tmp_path):
    bad = tmp_path / "nan.exr"
    plane = np.ones((8, 16), np.float32)
    exr.write_exr(bad, {"R": plane, "G": plane * np.nan, "B": plane})
    code, out, err = run(capsys, "sh", str(bad))
    assert code == 2 and out == "" and "NaN" in err and len(err.splitlines()) == 1


def test_module_entry_point_exit_code():
    ok = subprocess.run([sys.executable, "-m", "relight.cli", "sh", "sky", "--order", "0", "--json"],
                        capture_output=True, text=True, timeout=60)
    assert ok.returncode == 0 and len(json.loads(ok.stdout)["coeffs"]) == 1
    bad = subprocess.run([sys.executable, "-m", "relight.cli", "sh", "/nonexistent.exr"],
                         capture_output=True, text=True, timeout=60)
    assert bad.returncode == 2 and bad.stdout == "" and len(bad.stderr.splitlines()) == 1


def test_logging_is_configured_once_by_the_command():
    # issue 39: main() configures logging once (warnings on stderr in the command's own line
    # format) and leaves a process's own configuration alone
    code = ("import logging, sys\n"
            "from relight.cli import main\n"
            "main(['sh', 'sky', '--order', '0', '--json'])\n"
            "main(['sh', 'sky', '--order', '0', '--json'])\n"
            "assert len(logging.getLogger().handlers) == 1\n"
            "logging.getLogger('relight.lighting.envmap').info('not shown')\n"
            "logging.getLogger('relight.lighting.envmap').warning('clamped %d texels', 3)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stderr.splitlines() == ["relight sh: warning: clamped 3 texels"], res.stderr
    own = ("import logging\n"
           "logging.basicConfig(format='own: %(message)s')\n"
           "from relight.cli import main\n"
           "main(['sh', 'sky', '--order', '0', '--json'])\n"
           "logging.getLogger('relight.lighting.envmap').warning('w')\n")
    res = subprocess.run([sys.executable, "-c", own], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0 and res.stderr.splitlines() == ["own: w"], res.stderr
