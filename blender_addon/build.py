"""Build the extension zip that Blender's "Install from Disk" takes.

    python -m blender_addon.build [--out dist/] [--wheel-cache DIR] [--offline]
                                  [--platform P ...] [--split-platforms] [--split-pythons]
                                  [--docs docs/addon.md]

Bundles the add-on, this project's torch-free core `relight/` (as a wheel,
with the HDR presets and the ONNX models the quality presets use), and the
onnxruntime, OpenEXR and Pillow wheels for linux-x64, windows-x64, macos-arm64 and
macos-x64, each for every Python the supported Blender releases embed (3.11 for
Blender 4.2-5.0, 3.13 for 5.1-5.3; Intel Macs run only 4.2-4.5), at the versions
installed here (onnxruntime 1.23.2 on macos-x64, its last Intel Mac wheel).
Blender installs only the wheels of its own platform and Python. The manifest's
blender_version_min / _max are rewritten to the releases whose Python the zip has
wheels for. `--split-platforms` adds one zip per platform, `--split-pythons` one
per platform and Python (the smallest downloads). `--docs docs/addon.md` writes the
measured sizes there. Wheels are downloaded once with pip into a cache outside the
repository; numpy is Blender's own. The zip is written atomically and its manifest
validated.
"""

from __future__ import annotations

import argparse
import base64
import csv
import hashlib
import importlib.metadata
import io
import os
import re
import subprocess
import sys
import tempfile
import zipfile
from pathlib import Path

from relight.files.fileio import atomic_path

from . import manifest as manifest_rules

ADDON_DIR = Path(__file__).resolve().parent
REPO_ROOT = ADDON_DIR.parent
CORE_DIR = REPO_ROOT / "relight"
CORE_DIST = "fullbody_relight_core"
PYTHON_BLENDERS, PLATFORM_PYTHONS = manifest_rules.PYTHON_BLENDERS, manifest_rules.PLATFORM_PYTHONS
# (distribution on PyPI, file-name prefix) of the binary wheels bundled per platform
BINARY_DEPS = (("onnxruntime", "onnxruntime"), ("OpenEXR", "openexr"), ("Pillow", "pillow"))
# pip --platform tag per Blender platform; pip also accepts older compatible tags
PLATFORM_TAGS = {
    "linux-x64": "manylinux_2_28_x86_64",
    "windows-x64": "win_amd64",
    "macos-arm64": "macosx_14_0_arm64",
    "macos-x64": "macosx_13_0_x86_64",   # Blender 4.2 - 4.5 run on Intel Macs (5.0 does not)
}
# (distribution, Blender platform) -> version, where PyPI has no wheel of the installed
# version: onnxruntime's last macOS x86-64 wheels are 1.23.2 (the shipped models give
# bit-identical results with 1.23.2 and the installed version on Linux).
VERSION_OVERRIDES = {("onnxruntime", "macos-x64"): "1.23.2"}
DOCS_BEGIN = "<!-- sizes from `python -m blender_addon.build --split-platforms --split-pythons --docs docs/addon.md`: begin -->"
DOCS_END = "<!-- sizes: end -->"
ADDON_EXCLUDE = {"build.py", "__main__.py", "dev"}  # files and folders not in the zip
CORE_DATA_SUFFIXES = {".py", ".exr", ".md", ".json", ".onnx", ".sha256"}
ZIP_DATE = (2024, 1, 1, 0, 0, 0)  # fixed timestamps: same inputs, same zip


class BuildError(Exception):
    """A build failure with a message meant for the user."""


def default_cache() -> Path:
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "relight-photo" / "wheels"


def installed_version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        raise BuildError(f"{dist} is not installed here; the add-on bundles the installed version") from None


def python_tag(python: str) -> str:
    """"3.13" -> "cp313"."""
    return "cp" + python.replace(".", "")


def _wheel_matches(name: str, prefix: str, version: str, platform_tag: str, python: str) -> bool:
    parts = name[:-4].split("-")
    if len(parts) not in (5, 6) or parts[0].lower() != prefix or parts[1] != version:
        return False
    wheel_python, platform = parts[-3], parts[-1]
    if wheel_python != python_tag(python):
        return False
    if platform_tag.startswith("manylinux"):
        return "x86_64" in platform and "linux" in platform
    if platform_tag.startswith("macosx"):
        arch = "arm64" if platform_tag.endswith("arm64") else "x86_64"
        return platform.startswith("macosx") and platform.endswith((arch, "universal2"))
    return platform == platform_tag


def find_cached_wheel(cache: Path, prefix: str, version: str, platform_tag: str,
                      python: str) -> Path | None:
    for p in sorted(cache.glob("*.whl")):
        if _wheel_matches(p.name, prefix, version, platform_tag, python):
            return p
    return None


def fetch_wheel(cache: Path, dist: str, prefix: str, version: str, platform_tag: str,
                offline: bool, python: str) -> Path:
    """The cached wheel for `python` ("3.11"), downloading it with pip first when needed."""
    found = find_cached_wheel(cache, prefix, version, platform_tag, python)
    if found is not None:
        return found
    where = f"{platform_tag}, Python {python}"
    if offline:
        raise BuildError(f"{dist}=={version} for {where} is not in the wheel cache {cache} "
                         "and --offline forbids downloading it")
    cache.mkdir(parents=True, exist_ok=True)
    cmd = [sys.executable, "-m", "pip", "download", "--only-binary=:all:", "--no-deps",
           "--python-version", python, "--platform", platform_tag,
           "--disable-pip-version-check", "-q", f"{dist}=={version}", "-d", str(cache)]
    done = subprocess.run(cmd, capture_output=True, text=True)
    found = find_cached_wheel(cache, prefix, version, platform_tag, python)
    if done.returncode != 0 or found is None:
        reason = (done.stderr.strip().splitlines() or ["no wheel for this platform"])[-1]
        raise BuildError(f"cannot download {dist}=={version} for {where} (offline? {reason}); "
                         f"put the wheel into {cache} and run the build again")
    return found


def _record_hash(data: bytes) -> str:
    digest = hashlib.sha256(data).digest()
    return "sha256=" + base64.urlsafe_b64encode(digest).rstrip(b"=").decode()


def _zip_write(zf: zipfile.ZipFile, arcname: str, data: bytes) -> None:
    info = zipfile.ZipInfo(arcname, ZIP_DATE)
    info.compress_type = zipfile.ZIP_DEFLATED
    info.external_attr = 0o644 << 16
    zf.writestr(info, data)


def shipped_models(registry: dict) -> list[str]:
    """The registry names the add-on needs: those the quality presets run (Draft,
    Balanced, Best, and the networks of a preset's ensemble), the registry's default and the
    person matte's networks (the Automatic mask); no other model goes into the zip."""
    from relight.network import quality as core_quality

    names = {core_quality.model_name(p.key, registry) for p in core_quality.PRESETS}
    names.update(name for p in core_quality.PRESETS for name in p.ensemble)
    names.add(registry.get("default"))
    try:
        from relight.person.matte import MODELS as MATTE_MODELS
    except ImportError:  # a core without the person matte
        MATTE_MODELS = {}
    names.update(name for name, _file in MATTE_MODELS.values())
    return sorted(n for n in names if n in registry.get("models", {}))


def _models_dir(core_dir: Path) -> Path:
    return core_dir / "models"


def _shipped_registry(core_dir: Path) -> tuple[dict, set[str]]:
    """(the registry cut down to the shipped models, the model file names that ship)."""
    import json

    registry_path = _models_dir(core_dir) / "models.json"
    if not registry_path.is_file():
        return {}, set()
    registry = json.loads(registry_path.read_text(encoding="utf-8"))
    keep = shipped_models(registry)
    registry = dict(registry, models={n: registry["models"][n] for n in keep})
    files = {registry["models"][n]["file"] for n in keep}
    return registry, files | {f + ".sha256" for f in files}


def core_files(core_dir: Path = CORE_DIR) -> list[Path]:
    """The files of relight/ that ship: code, HDR presets, licences, the models the presets use."""
    _, model_files = _shipped_registry(core_dir)
    files = []
    for p in sorted(core_dir.rglob("*")):
        if not p.is_file() or "__pycache__" in p.parts or p.suffix not in CORE_DATA_SUFFIXES:
            continue
        if p.parent == _models_dir(core_dir) and p.suffix in {".onnx", ".sha256"} and p.name not in model_files:
            continue
        files.append(p)
    return files


def _core_file_bytes(f: Path, core_dir: Path) -> bytes:
    if f == _models_dir(core_dir) / "models.json":
        import json

        registry, _ = _shipped_registry(core_dir)
        return (json.dumps(registry, indent=2, sort_keys=True) + "\n").encode()
    return f.read_bytes()


def build_core_wheel(out_dir: Path, version: str, core_dir: Path = CORE_DIR) -> Path:
    """A pure-Python wheel of relight/ (PEP 427 layout, RECORD with hashes)."""
    dist_info = f"{CORE_DIST}-{version}.dist-info"
    path = out_dir / f"{CORE_DIST}-{version}-py3-none-any.whl"
    records = []
    with zipfile.ZipFile(path, "w") as zf:
        for f in core_files(core_dir):
            arcname = "relight/" + f.relative_to(core_dir).as_posix()
            data = _core_file_bytes(f, core_dir)
            _zip_write(zf, arcname, data)
            records.append((arcname, _record_hash(data), str(len(data))))
        meta = {
            "METADATA": (f"Metadata-Version: 2.1\nName: {CORE_DIST}\nVersion: {version}\n"
                         "Summary: Torch-free core of single-image full-body human relighting\n"
                         "License: Apache-2.0\nRequires-Dist: numpy\nRequires-Dist: onnxruntime\n"
                         "Requires-Dist: OpenEXR\n"),
            "WHEEL": "Wheel-Version: 1.0\nGenerator: blender_addon.build\nRoot-Is-Purelib: true\nTag: py3-none-any\n",
            "top_level.txt": "relight\n",
        }
        for name, text in meta.items():
            data = text.encode()
            _zip_write(zf, f"{dist_info}/{name}", data)
            records.append((f"{dist_info}/{name}", _record_hash(data), str(len(data))))
        buf = io.StringIO()
        writer = csv.writer(buf, lineterminator="\n")
        writer.writerows(records)
        writer.writerow((f"{dist_info}/RECORD", "", ""))
        _zip_write(zf, f"{dist_info}/RECORD", buf.getvalue().encode())
    return path


def addon_files(addon_dir: Path = ADDON_DIR) -> list[Path]:
    return sorted(p for p in addon_dir.rglob("*.py") if not set(p.relative_to(addon_dir).parts) & ADDON_EXCLUDE)


def _rewrite_wheels(manifest_text: str, wheels: list[str]) -> str:
    pattern = re.compile(r"^wheels\s*=\s*\[.*?\]\s*$\n?", re.S | re.M)
    replacement = manifest_rules.wheels_toml(wheels)
    if pattern.search(manifest_text):
        return pattern.sub(lambda _m: replacement, manifest_text, count=1)
    return manifest_text.rstrip("\n") + "\n\n" + replacement


def _rewrite_platforms(manifest_text: str, platforms: tuple[str, ...]) -> str:
    listed = ", ".join(f'"{p}"' for p in platforms)
    text, count = re.subn(r"^platforms\s*=\s*\[.*?\]\s*$", f"platforms = [{listed}]", manifest_text,
                          count=1, flags=re.M)
    if count != 1:
        raise BuildError("blender_manifest.toml has no one-line 'platforms = [...]' to rewrite")
    return text


def _rewrite_version(manifest_text: str, version: str) -> str:
    """The manifest's `version = "..."`: the project's one version string (relight.__version__)."""
    text, count = re.subn(r'^version\s*=\s*"[^"]*".*$', f'version = "{version}"', manifest_text, count=1, flags=re.M)
    if count != 1:
        raise BuildError("blender_manifest.toml has no one-line 'version = \"...\"' to rewrite")
    return text


def _rewrite_version_range(manifest_text: str, low: str, high: str) -> str:
    """blender_version_min = low and blender_version_max = high (added after min if absent)."""
    text, count = re.subn(r'^blender_version_min\s*=\s*".*?"\s*$', f'blender_version_min = "{low}"',
                          manifest_text, count=1, flags=re.M)
    if count != 1:
        raise BuildError("blender_manifest.toml has no one-line 'blender_version_min = \"...\"' to rewrite")
    text, count = re.subn(r'^blender_version_max\s*=\s*".*?"\s*$', f'blender_version_max = "{high}"',
                          text, count=1, flags=re.M)
    if count == 0:
        text = re.sub(r'^(blender_version_min\s*=.*)$', lambda m: f'{m.group(1)}\nblender_version_max = "{high}"',
                      text, count=1, flags=re.M)
    return text


def blender_range(pythons) -> tuple[str, str]:
    """[first, last) Blender version whose embedded Python is one of `pythons`; they must be
    adjacent in PYTHON_BLENDERS (a gap would claim releases the zip has no wheels for)."""
    ranges = sorted((PYTHON_BLENDERS[p] for p in pythons), key=lambda r: manifest_rules.version_key(r[0]))
    for (_, end), (start, _) in zip(ranges, ranges[1:]):
        if end != start:
            raise BuildError(f"Pythons {sorted(pythons)} leave Blender {end} - {start} without wheels")
    return ranges[0][0], ranges[-1][1]


def build_split(out_dir: Path, cache: Path | None = None, offline: bool = False,
                by_python: bool = False) -> list[Path]:
    """One zip per platform (`<id>-<version>-<platform>.zip`, Blender's naming for split
    extensions), each with only its own platform's wheels; with `by_python`, one per
    platform and Python (`...-<platform>-py313.zip`)."""
    if not by_python:
        return [build(out_dir, cache, offline, (platform,)) for platform in manifest_rules.PLATFORMS]
    return [build(out_dir, cache, offline, (platform,), (python,))
            for platform in manifest_rules.PLATFORMS for python in PLATFORM_PYTHONS[platform]]


def build(out_dir: Path, cache: Path | None = None, offline: bool = False,
          platforms: tuple[str, ...] | None = None, pythons: tuple[str, ...] | None = None) -> Path:
    """Build and validate the extension zip for `platforms` (default: all) and `pythons`
    (default: every Python of PYTHON_BLENDERS); returns its path."""
    platforms = tuple(manifest_rules.PLATFORMS if platforms is None else platforms)
    unknown = set(platforms) - set(manifest_rules.PLATFORMS)
    if unknown or not platforms:
        raise BuildError(f"unknown platforms {sorted(unknown)}; expected some of {list(manifest_rules.PLATFORMS)}")
    pythons = tuple(PYTHON_BLENDERS if pythons is None else pythons)
    unknown = set(pythons) - set(PYTHON_BLENDERS)
    if unknown or not pythons:
        raise BuildError(f"unknown Pythons {sorted(unknown)}; expected some of {list(PYTHON_BLENDERS)}")
    targets = [(platform, python) for platform in platforms for python in pythons
               if python in PLATFORM_PYTHONS[platform]]
    if not targets:
        raise BuildError(f"no Blender runs Python {', '.join(pythons)} on {', '.join(platforms)}")
    low, high = blender_range({python for _, python in targets})
    cache = Path(cache) if cache else default_cache()
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    manifest_path = ADDON_DIR / "blender_manifest.toml"
    manifest_text = manifest_path.read_text(encoding="utf-8")
    manifest = manifest_rules.load(manifest_path)
    from relight import __version__ as core_version

    platform_wheels = []
    for dist, prefix in BINARY_DEPS:
        installed = installed_version(dist)
        for blender_platform, python in targets:
            version = VERSION_OVERRIDES.get((dist.lower(), blender_platform), installed)
            platform_wheels.append(fetch_wheel(cache, dist, prefix, version,
                                               PLATFORM_TAGS[blender_platform], offline, python))
    with tempfile.TemporaryDirectory(prefix="relight_addon_build_") as tmp:
        stage = Path(tmp)
        (stage / "wheels").mkdir()
        core_wheel = build_core_wheel(stage / "wheels", core_version)
        wheels = [core_wheel] + platform_wheels
        listed = [f"./wheels/{w.name}" for w in wheels]
        for w in platform_wheels:
            (stage / "wheels" / w.name).write_bytes(w.read_bytes())
        manifest_text = _rewrite_wheels(manifest_text, listed)
        manifest_text = _rewrite_version_range(_rewrite_version(manifest_text, core_version), low, high)
        if platforms != tuple(manifest_rules.PLATFORMS):
            manifest_text = _rewrite_platforms(manifest_text, platforms)
        (stage / "blender_manifest.toml").write_text(manifest_text, encoding="utf-8")
        final_manifest = manifest_rules.load(stage / "blender_manifest.toml")
        try:
            manifest_rules.check(final_manifest, stage, platforms)
        except ValueError as exc:
            raise BuildError(str(exc)) from None
        suffix = "" if platforms == tuple(manifest_rules.PLATFORMS) else \
            "-" + "-".join(p.replace("-", "_") for p in platforms)
        if pythons != tuple(PYTHON_BLENDERS):
            suffix += "-" + "-".join(python_tag(p).replace("cp", "py") for p in pythons)
        zip_path = out_dir / f"{manifest['id']}-{final_manifest['version']}{suffix}.zip"
        with atomic_path(zip_path) as tmp_zip, zipfile.ZipFile(tmp_zip, "w") as zf:
            _zip_write(zf, "blender_manifest.toml", manifest_text.encode())
            for f in addon_files():
                _zip_write(zf, f.relative_to(ADDON_DIR).as_posix(), f.read_bytes())
            for w in wheels:
                info = zipfile.ZipInfo(f"wheels/{w.name}", ZIP_DATE)
                info.compress_type = zipfile.ZIP_STORED  # wheels are zips already
                info.external_attr = 0o644 << 16
                with open(stage / "wheels" / w.name, "rb") as src:
                    zf.writestr(info, src.read())
    return zip_path


def size_report(zip_paths) -> str:
    """Markdown: each zip's size and what takes it, measured from the zips themselves."""
    zip_paths = [Path(zip_paths)] if isinstance(zip_paths, (str, Path)) else [Path(p) for p in zip_paths]
    mb = 1e6
    parts: dict[str, int] = {}
    models = []
    lines = []
    for zip_path in zip_paths:
        with zipfile.ZipFile(zip_path) as zf:
            infos = zf.infolist()
            core = next((i for i in infos if i.filename.startswith(f"wheels/{CORE_DIST}-")), None)
            if core is not None and not models:
                with zf.open(core) as f, zipfile.ZipFile(io.BytesIO(f.read())) as wheel:
                    models = [(i.filename.rsplit("/", 1)[-1], i.compress_size) for i in wheel.infolist()
                              if i.filename.endswith(".onnx")]
        lines.append(f"- Zip `{zip_path.name}`: **{zip_path.stat().st_size / mb:.1f} MB**, {len(infos)} files.")
        parts["add-on code and manifest"] = sum(i.compress_size for i in infos
                                                if not i.filename.startswith("wheels/"))
        for i in infos:
            if i.filename.startswith("wheels/"):
                parts[f"`{i.filename[len('wheels/'):]}`"] = i.compress_size
    lines += ["", "| part | MB in the zip |", "|---|---|"]
    lines.append(f"| add-on code and manifest | {parts.pop('add-on code and manifest') / mb:.2f} |")
    for name in sorted(parts):
        lines.append(f"| {name} | {parts[name] / mb:.1f} |")
    if models:
        shipped = ", ".join(f"`{n}` {size / mb:.1f} MB" for n, size in sorted(models))
        lines += ["", f"Models in the core wheel (compressed): {shipped}."]
    return "\n".join(lines)


def update_docs(doc: Path, report: str) -> None:
    """Replace the block between DOCS_BEGIN and DOCS_END in `doc` by `report`."""
    text = doc.read_text(encoding="utf-8")
    start, end = text.find(DOCS_BEGIN), text.find(DOCS_END)
    if start < 0 or end < start:
        raise BuildError(f"{doc} has no size block ({DOCS_BEGIN} ... {DOCS_END})")
    text = text[:start + len(DOCS_BEGIN)] + "\n" + report + "\n" + text[end:]
    doc.write_text(text, encoding="utf-8")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(prog="python -m blender_addon.build", description=__doc__.split("\n\n")[0])
    parser.add_argument("--out", default="dist", help="output folder (default: dist/)")
    parser.add_argument("--wheel-cache", default=None,
                        help=f"where downloaded wheels are kept (default: {default_cache()})")
    parser.add_argument("--offline", action="store_true", help="never download: use the cache only")
    parser.add_argument("--docs", default=None,
                        help="Markdown file whose size block is rewritten with the measured sizes")
    parser.add_argument("--platform", action="append", choices=manifest_rules.PLATFORMS,
                        help="build the main zip for this platform only (repeatable; default: all)")
    parser.add_argument("--split-platforms", action="store_true",
                        help="also one zip per platform, each with only its own wheels")
    parser.add_argument("--split-pythons", action="store_true",
                        help="also one zip per platform and Python (Blender 4.2-5.0: 3.11, 5.1+: 3.13)")
    args = parser.parse_args(argv)
    cache = Path(args.wheel_cache) if args.wheel_cache else None
    try:
        platforms = tuple(dict.fromkeys(args.platform)) if args.platform else None
        paths = [build(Path(args.out), cache, args.offline, platforms)]
        if args.split_platforms:
            paths += build_split(Path(args.out), cache, args.offline)
        if args.split_pythons:
            paths += build_split(Path(args.out), cache, args.offline, by_python=True)
    except BuildError as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 1
    for path in paths:
        with zipfile.ZipFile(path) as zf:
            names = zf.namelist()
        print(f"{path}  {path.stat().st_size / 1e6:.1f} MB, {len(names)} files, "
              f"{sum(n.startswith('wheels/') for n in names)} wheels")
    report = size_report(paths)
    print(report)
    if args.docs:
        try:
            update_docs(Path(args.docs), report)
        except BuildError as exc:
            print(f"error: {exc}", file=sys.stderr)
            return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
