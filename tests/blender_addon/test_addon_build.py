"""Relight Photo packaging: `python -m blender_addon.build` makes a zip that
Blender's own extension validator accepts and that Blender installs headlessly
(bpy.ops.extensions.package_install_files) and runs.

The platform wheels are stand-ins made here (valid wheel layout, same file
names as the real ones) so the test needs no network; docs/addon.md records
a real build with the downloaded onnxruntime/OpenEXR/Pillow wheels.
"""

from __future__ import annotations

import base64
import hashlib
import importlib.metadata
import json
import os
import subprocess
import sys
import textwrap
import zipfile
from pathlib import Path

import numpy as np
import pytest

import relight
from blender_addon import build, manifest

from addon_support import write_person_png
from tiny_model import make_tiny_model

REPO = Path(__file__).resolve().parents[2]
PLATFORM_FILE_TAGS = {  # what PyPI names the real files, in manifest.PLATFORMS order
    "onnxruntime": ("manylinux_2_28_x86_64", "win_amd64", "macosx_14_0_arm64", "macosx_13_0_x86_64"),
    "openexr": ("manylinux_2_28_x86_64", "win_amd64", "macosx_11_0_arm64", "macosx_10_15_x86_64"),
    "pillow": ("manylinux_2_27_x86_64.manylinux_2_28_x86_64", "win_amd64", "macosx_11_0_arm64",
               "macosx_10_10_x86_64"),
}


def _version(dist: str, platform: str) -> str:
    return build.VERSION_OVERRIDES.get((dist.lower(), platform), importlib.metadata.version(dist))


def _tag(python: str) -> str:
    return build.python_tag(python)


def _targets():
    """(Blender platform, index in manifest.PLATFORMS, Python) of every wheel the full zip holds."""
    return [(platform, i, python) for i, platform in enumerate(manifest.PLATFORMS)
            for python in manifest.PLATFORM_PYTHONS[platform]]


def _stand_in_wheel(folder: Path, prefix: str, version: str, platform: str, python: str) -> Path:
    """A metadata-only wheel named like the real one (installs nothing importable)."""
    tag = _tag(python)
    name = f"{prefix}-{version}-{tag}-{tag}-{platform}.whl"
    dist_info = f"{prefix}-{version}.dist-info"
    files = {f"{dist_info}/METADATA": f"Metadata-Version: 2.1\nName: {prefix}\nVersion: {version}\n"
                                      f"Summary: stand-in for {tag}\n",
             f"{dist_info}/WHEEL": f"Wheel-Version: 1.0\nRoot-Is-Purelib: false\nTag: {tag}-{tag}-{platform}\n"}
    with zipfile.ZipFile(folder / name, "w") as zf:
        for arc, text in files.items():
            zf.writestr(arc, text)
        zf.writestr(f"{dist_info}/RECORD", "".join(f"{a},,\n" for a in files) + f"{dist_info}/RECORD,,\n")
    return folder / name


@pytest.fixture(scope="module")
def wheel_cache(tmp_path_factory):
    cache = tmp_path_factory.mktemp("wheel_cache")
    for dist, prefix in build.BINARY_DEPS:
        for blender_platform, index, python in _targets():
            _stand_in_wheel(cache, prefix, _version(dist, blender_platform), PLATFORM_FILE_TAGS[prefix][index], python)
    return cache


@pytest.fixture(scope="module")
def built_zip(wheel_cache, tmp_path_factory):
    return build.build(tmp_path_factory.mktemp("dist"), wheel_cache, offline=True)


def _blender_ext_cli() -> Path:
    import bpy

    path = Path(bpy.utils.system_resource("SCRIPTS")) / "addons_core" / "bl_pkg" / "cli" / "blender_ext.py"
    assert path.is_file(), path
    return path


def test_one_version_string():
    """relight.__version__ is the project's version: pyproject.toml reads it (dynamic), the build
    writes it into the zip's manifest, and the source manifest (which Blender reads when the add-on
    folder itself is installed) states the same."""
    import tomllib

    root = Path(__file__).resolve().parents[2]
    project = tomllib.loads((root / "pyproject.toml").read_text(encoding="utf-8"))
    assert "version" not in project["project"] and "version" in project["project"]["dynamic"]
    assert project["tool"]["setuptools"]["dynamic"]["version"] == {"attr": "relight.__version__"}
    assert manifest.load(root / "blender_addon" / "blender_manifest.toml")["version"] == relight.__version__


def test_zip_layout_and_manifest(built_zip, tmp_path):
    with zipfile.ZipFile(built_zip) as zf:
        names = set(zf.namelist())
        zf.extractall(tmp_path)
    assert "blender_manifest.toml" in names and "__init__.py" in names
    assert "build.py" not in names and not any("__pycache__" in n for n in names)
    data = manifest.load(tmp_path / "blender_manifest.toml")
    assert manifest.problems(data, tmp_path) == []
    assert data["version"] == relight.__version__  # written by the build from the one version string
    listed = {w.removeprefix("./") for w in data["wheels"]}
    assert listed == {n for n in names if n.startswith("wheels/")}
    # every binary dependency for each platform and each Python its Blender releases embed
    # (3.11 and 3.13; Intel Macs 3.11 only: 7 targets), plus the core
    assert len(_targets()) == 7 and len(listed) == 1 + 7 * len(build.BINARY_DEPS)
    for dist, prefix in build.BINARY_DEPS:
        for blender_platform, index, python in _targets():
            tag = _tag(python)
            name = f"{prefix}-{_version(dist, blender_platform)}-{tag}-{tag}-{PLATFORM_FILE_TAGS[prefix][index]}.whl"
            assert f"wheels/{name}" in listed
    # Intel Macs get onnxruntime 1.23.2: the newest with macOS x86-64 wheels on PyPI
    assert any(w.endswith("onnxruntime-1.23.2-cp311-cp311-macosx_13_0_x86_64.whl") for w in listed)
    # the range is what the wheels cover: Blender 4.2 (Python 3.11) up to, not including, 5.4
    assert (data["blender_version_min"], data["blender_version_max"]) == ("4.2.0", "5.4.0")


def test_blenders_own_validator_accepts_the_zip(built_zip):
    done = subprocess.run([sys.executable, str(_blender_ext_cli()), "validate", str(built_zip)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "Success" in done.stdout, done.stdout + done.stderr


def test_core_wheel_is_a_valid_wheel_of_relight(built_zip, tmp_path):
    with zipfile.ZipFile(built_zip) as zf:
        core = next(n for n in zf.namelist() if n.startswith("wheels/fullbody_relight_core-"))
        zf.extract(core, tmp_path)
    with zipfile.ZipFile(tmp_path / core) as wheel:
        names = set(wheel.namelist())
        record = wheel.read(next(n for n in names if n.endswith("dist-info/RECORD"))).decode()
        for line in record.strip().splitlines():
            arc, digest, size = line.rsplit(",", 2)
            if not digest:
                continue
            data = wheel.read(arc)
            want = "sha256=" + base64.urlsafe_b64encode(hashlib.sha256(data).digest()).rstrip(b"=").decode()
            assert digest == want and int(size) == len(data), arc
    for required in ("relight/network/runtime.py", "relight/lighting/sh.py", "relight/lighting/envmap.py", "relight/files/photo.py",
                     "relight/models/models.json", "relight/data/hdri/studio.exr"):
        assert required in names
    # the core only: evaluation-only code (evaluation/: contact sheets, the matte evaluation, its photos) stays out
    assert all(n.startswith(("relight/", "fullbody_relight_core-")) for n in names)
    assert not any("matte_eval" in n or n.endswith("/sheet.py") for n in names)
    # only the models Draft / Balanced / Best and the person matte run ship; the registry lists exactly them
    from relight import models as core_models
    from relight.network import quality as core_quality

    registry = core_models.load_registry(core_models.REGISTRY_PATH)
    from relight.person.matte import MODELS as MATTE_MODELS

    wanted = {core_quality.model_name(p.key, registry) for p in core_quality.PRESETS} | {registry["default"]}
    wanted |= {name for name, _file in MATTE_MODELS.values()}  # the Automatic mask's person matte
    shipped = json.loads(wheel_json(tmp_path / core))
    assert set(shipped["models"]) == wanted and shipped["default"] == registry["default"]
    onnx = {n.rsplit("/", 1)[-1] for n in names if n.endswith(".onnx")}
    assert onnx == {registry["models"][m]["file"] for m in wanted}
    assert all(f"relight/models/{f}.sha256" in names for f in onnx)
    assert not any("__pycache__" in n or n.endswith(".pyc") for n in names)


def wheel_json(wheel_path: Path) -> str:
    with zipfile.ZipFile(wheel_path) as wheel:
        return wheel.read("relight/models/models.json").decode()


def test_size_report_is_measured_from_the_zip_and_written_into_the_docs(built_zip, tmp_path):
    report = build.size_report(built_zip)
    assert f"**{built_zip.stat().st_size / 1e6:.1f} MB**" in report
    with zipfile.ZipFile(built_zip) as zf:
        wheels = [i for i in zf.infolist() if i.filename.startswith("wheels/")]
    assert all(f"| `{i.filename[len('wheels/'):]}` | {i.compress_size / 1e6:.1f} |" in report for i in wheels)
    doc = tmp_path / "addon.md"
    doc.write_text(f"intro\n{build.DOCS_BEGIN}\nold figures\n{build.DOCS_END}\nrest\n")
    build.update_docs(doc, report)
    text = doc.read_text()
    assert "old figures" not in text and report in text and text.startswith("intro") and text.endswith("rest\n")
    (tmp_path / "plain.md").write_text("no block")
    with pytest.raises(build.BuildError, match="has no size block"):
        build.update_docs(tmp_path / "plain.md", report)


def test_split_platform_zips_hold_only_their_own_wheels(wheel_cache, tmp_path):
    paths = build.build_split(tmp_path / "split", wheel_cache, offline=True)
    assert [p.name for p in paths] == [f"relight_photo-{relight.__version__}-{p.replace('-', '_')}.zip" for p in manifest.PLATFORMS]
    for index, (path, platform) in enumerate(zip(paths, manifest.PLATFORMS)):
        folder = tmp_path / platform
        with zipfile.ZipFile(path) as zf:
            names = set(zf.namelist())
            zf.extractall(folder)
        data = manifest.load(folder / "blender_manifest.toml")
        assert data["platforms"] == [platform]
        assert manifest.problems(data, folder, (platform,)) == []
        wanted = {f"wheels/{prefix}-{_version(dist, platform)}-{_tag(py)}-{_tag(py)}-{PLATFORM_FILE_TAGS[prefix][index]}.whl"
                  for dist, prefix in build.BINARY_DEPS for py in manifest.PLATFORM_PYTHONS[platform]}
        wheels = {n for n in names if n.startswith("wheels/")}
        assert wheels - wanted == {n for n in wheels if "fullbody_relight_core" in n} and wanted <= wheels
    done = subprocess.run([sys.executable, str(_blender_ext_cli()), "validate", str(paths[0])],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "Success" in done.stdout, done.stdout + done.stderr
    report = build.size_report(paths)
    assert all(f"Zip `{p.name}`: **{p.stat().st_size / 1e6:.1f} MB**" in report for p in paths)


def test_per_python_zips_claim_only_the_blenders_of_their_python(wheel_cache, tmp_path):
    paths = build.build_split(tmp_path / "split", wheel_cache, offline=True, by_python=True)
    expect = [(platform, py) for platform in manifest.PLATFORMS for py in manifest.PLATFORM_PYTHONS[platform]]
    assert [p.name for p in paths] == [f"relight_photo-{relight.__version__}-{platform.replace('-', '_')}-{_tag(py).replace('cp', 'py')}.zip"
                                       for platform, py in expect]
    for path, (platform, py) in zip(paths, expect):
        folder = tmp_path / path.stem
        with zipfile.ZipFile(path) as zf:
            zf.extractall(folder)
            wheels = [n for n in zf.namelist() if n.startswith("wheels/") and "fullbody_relight_core" not in n]
        data = manifest.load(folder / "blender_manifest.toml")
        assert manifest.problems(data, folder, (platform,)) == []
        assert (data["blender_version_min"], data["blender_version_max"]) == manifest.PYTHON_BLENDERS[py]
        assert len(wheels) == len(build.BINARY_DEPS) and all(f"-{_tag(py)}-" in w for w in wheels)
    # a 3.13 zip is smaller than the two-Python platform zip (the point of splitting)
    both = build.build(tmp_path / "both", wheel_cache, offline=True, platforms=("linux-x64",))
    py313 = next(p for p in paths if p.name.endswith("linux_x64-py313.zip"))
    assert py313.stat().st_size < both.stat().st_size
    done = subprocess.run([sys.executable, str(_blender_ext_cli()), "validate", str(py313)],
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0 and "Success" in done.stdout, done.stdout + done.stderr


def test_manifest_range_wider_than_the_wheels_is_refused():
    """The zip Blender 5.2 refused: cp311 wheels only, yet no blender_version_max."""
    only_311 = {"schema_version": "1.0.0", "id": "x", "version": "1.0.0", "name": "X", "tagline": "x",
                "maintainer": "x", "type": "add-on", "blender_version_min": "4.2.0", "license": ["SPDX:MIT"],
                "wheels": ["./wheels/onnxruntime-1.32.0-cp311-cp311-win_amd64.whl"]}
    assert any("embeds Python 3.13" in e and "onnxruntime" in e for e in manifest.problems(only_311))
    assert manifest.problems(dict(only_311, blender_version_max="5.1.0")) == []
    assert any("above" in e for e in manifest.problems(dict(only_311, blender_version_max="4.2.0")))
    assert manifest.pythons_in_range("4.2.0", "5.4.0") == ["3.11", "3.13"]
    assert manifest.pythons_in_range("5.1.0", None) == ["3.13"]
    with pytest.raises(build.BuildError, match="unknown Pythons"):
        build.build(Path("unused"), None, True, ("linux-x64",), ("3.12",))
    with pytest.raises(build.BuildError, match="no Blender runs Python 3.13 on macos-x64"):
        build.build(Path("unused"), None, True, ("macos-x64",), ("3.13",))


def test_build_is_reproducible(built_zip, wheel_cache, tmp_path):
    again = build.build(tmp_path, wheel_cache, offline=True)
    assert again.read_bytes() == built_zip.read_bytes()


def test_missing_wheel_offline_is_one_clear_line(tmp_path):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    done = subprocess.run([sys.executable, "-m", "blender_addon.build", "--out", str(tmp_path / "d"),
                           "--wheel-cache", str(tmp_path / "empty"), "--offline"],
                          capture_output=True, text=True, cwd=REPO, env=env, timeout=120)
    assert done.returncode == 1
    assert done.stderr.count("\n") == 1 and done.stderr.startswith("error: onnxruntime==")
    assert "is not in the wheel cache" in done.stderr
    assert not (tmp_path / "d").exists() or not list((tmp_path / "d").glob("*.zip"))


def test_failed_download_is_one_clear_line(tmp_path):
    # pip with no index and no find-links cannot fetch anything: the offline case
    env = dict(os.environ, PYTHONPATH=str(REPO), PIP_CONFIG_FILE=os.devnull, PIP_NO_INDEX="1")
    done = subprocess.run([sys.executable, "-m", "blender_addon.build", "--out", str(tmp_path / "d"),
                           "--wheel-cache", str(tmp_path / "cache")],
                          capture_output=True, text=True, cwd=REPO, env=env, timeout=120)
    assert done.returncode == 1 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("error: cannot download onnxruntime==") and "offline?" in done.stderr


def test_blender_installs_the_zip_headlessly_and_it_relights(built_zip, tmp_path, tmp_path_factory):
    model = make_tiny_model(tmp_path_factory)
    photo = tmp_path / "person.png"
    write_person_png(photo)
    script = textwrap.dedent("""
        import json, sys
        import bpy
        zip_path, model, photo = sys.argv[1:4]
        result = bpy.ops.extensions.package_install_files(
            filepath=zip_path, repo="user_default", enable_on_install=True)
        import relight
        image = bpy.data.images.load(photo)
        settings = bpy.context.scene.relight_photo
        settings.model_path = model
        settings.quality = "DRAFT"
        settings.light_kind = "PRESET"
        settings.preset = "sunset"
        ran = bpy.ops.relight_photo.relight(image_name=image.name, synchronous=True)
        relit = bpy.data.images[image.name + ".relit"]
        px = list(relit.pixels[:])
        print(json.dumps({
            "install": sorted(result), "run": sorted(ran), "relight_from": relight.__file__,
            "addons": [a.module for a in bpy.context.preferences.addons],
            "size": list(relit.size), "finite": all(v == v and abs(v) < 1e30 for v in px),
        }))
    """)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["BLENDER_USER_RESOURCES"] = str(tmp_path / "blender_user")  # never the real user's Blender
    done = subprocess.run([sys.executable, "-c", script, str(built_zip), str(model), str(photo)],
                          capture_output=True, text=True, cwd=tmp_path, env=env, timeout=300)
    assert done.returncode == 0, done.stderr[-2000:]
    out = json.loads(done.stdout.strip().splitlines()[-1])
    assert out["install"] == ["FINISHED"] and out["run"] == ["FINISHED"]
    assert "bl_ext.user_default.relight_photo" in out["addons"]
    # the core came from the bundled wheel, not from this checkout
    assert out["relight_from"].startswith(str(tmp_path / "blender_user" / "extensions"))
    assert out["size"] == [48, 72] and out["finite"]


_REAL_INSTALL = """
import json, os, sys
import bpy
import numpy  # Blender's own numpy stays; everything else must come from the extension
# hide this test environment's packages (onnxruntime, OpenEXR, Pillow, the checkout's relight):
# what the add-on imports from now on can only be what the zip's wheels installed
user = os.environ["BLENDER_USER_RESOURCES"]
sys.path[:] = [p for p in sys.path if p.startswith(user) or ("site-packages" not in p and os.path.abspath(p) != {repo!r})]
for name in [m for m in sys.modules if m.split(".")[0] in ("onnxruntime", "OpenEXR", "PIL", "relight")]:
    del sys.modules[name]
step, zip_path, photo, blend = sys.argv[1:5]
if step == "install":
    done = bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    bpy.ops.wm.save_userpref()
else:
    done = bpy.ops.preferences.addon_enable(module="bl_ext.user_default.relight_photo")
import onnxruntime, PIL, OpenEXR, relight
where = {{m.__name__: m.__file__ for m in (onnxruntime, PIL, OpenEXR, relight)}}
settings = bpy.context.scene.relight_photo
if step == "install":
    image = bpy.data.images.load(photo)
    settings.quality, settings.mask_mode = "DRAFT", "NETWORK"
    settings.light_kind, settings.preset = "PRESET", "sunset"
    ran = bpy.ops.relight_photo.relight(image_name=image.name, synchronous=True)
    bpy.ops.wm.save_as_mainfile(filepath=blend)
else:
    ran = bpy.ops.wm.open_mainfile(filepath=blend)
relit = bpy.data.images[os.path.basename(photo) + ".relit"]
px = numpy.empty(relit.size[0] * relit.size[1] * 4, numpy.float32)
relit.pixels.foreach_get(px)
print(json.dumps({{"done": sorted(done), "ran": sorted(ran), "where": where, "python": sys.version[:4],
                   "size": list(relit.size), "pixels": px[::7].tolist()}}))
"""


def test_real_wheels_install_relight_save_and_reopen_on_this_blender(tmp_path):
    """The zip with PyPI's real wheels for this platform and this Blender's Python (3.11 under
    bpy 4.2-5.0, 3.13 under 5.1+), installed by Blender's own installer with the test
    environment's onnxruntime, OpenEXR and Pillow out of reach: it relights with the bundled
    model, saves, and a fresh Blender reopens the result."""
    python = f"{sys.version_info.major}.{sys.version_info.minor}"
    zip_path = build.build(tmp_path / "dist", None, False, ("linux-x64",), (python,))
    photo, blend = tmp_path / "person.png", tmp_path / "shot.blend"
    write_person_png(photo)
    env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    env["BLENDER_USER_RESOURCES"] = str(tmp_path / "blender_user")  # never the real user's Blender
    outs = []
    for step in ("install", "reopen"):
        done = subprocess.run([sys.executable, "-c", _REAL_INSTALL.format(repo=str(REPO)), step, str(zip_path),
                               str(photo), str(blend)], capture_output=True, text=True, cwd=tmp_path, env=env,
                              timeout=300)
        assert done.returncode == 0, done.stderr[-3000:]
        outs.append(json.loads(done.stdout.strip().splitlines()[-1]))
    installed, reopened = outs
    assert installed["done"] == ["FINISHED"] and installed["ran"] == ["FINISHED"] and reopened["ran"] == ["FINISHED"]
    extensions = str(tmp_path / "blender_user" / "extensions")
    for out in outs:
        assert out["python"] == python
        assert all(path.startswith(extensions) for path in out["where"].values()), out["where"]
    assert installed["size"] == reopened["size"] == [48, 72]
    px = np.array(installed["pixels"])
    assert np.all(np.isfinite(px)) and px.max() > 0.05  # a relit person, not a black image
    # the reopened result is the saved one (float16 decomposition: relative 2^-11 per value)
    np.testing.assert_allclose(reopened["pixels"], px, rtol=4e-3, atol=4e-3)
