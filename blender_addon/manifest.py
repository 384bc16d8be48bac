"""Checks of blender_manifest.toml against Blender's extension rules (plain Python).

Mirrors what Blender's own `extension validate` requires of this add-on, plus
this project's policy: only the 'files' permission, the four platforms we
ship wheels for, and every listed wheel present in the package.
"""

from __future__ import annotations

import re
import tomllib
from pathlib import Path, PurePosixPath

REQUIRED = ("schema_version", "id", "version", "name", "tagline", "maintainer", "type",
            "blender_version_min", "license")
PLATFORMS = ("linux-x64", "windows-x64", "macos-arm64", "macos-x64")
# The Python each Blender release embeds, as [first, last) Blender version: 4.2 - 5.0 run
# 3.11, 5.1 - 5.3 run 3.13. The last bound is the newest release known to keep 3.13
# (Blender's blender_version_max is exclusive).
PYTHON_BLENDERS = {"3.11": ("4.2.0", "5.1.0"), "3.13": ("5.1.0", "5.4.0")}
# Blender 5.0 dropped Intel Macs: macos-x64 runs 4.2 - 4.5, Python 3.11 only
PLATFORM_PYTHONS = {"linux-x64": ("3.11", "3.13"), "windows-x64": ("3.11", "3.13"),
                    "macos-arm64": ("3.11", "3.13"), "macos-x64": ("3.11",)}
ALLOWED_PERMISSIONS = {"files"}
_VERSION = re.compile(r"^(0|[1-9]\d*)\.(0|[1-9]\d*)\.(0|[1-9]\d*)$")
_ID = re.compile(r"^[A-Za-z][A-Za-z0-9_]*$")
_TAGLINE_MAX = 64   # Blender's limit for the tagline


def load(path: str | Path) -> dict:
    """Parse a manifest file; ValueError on TOML errors."""
    try:
        with open(path, "rb") as f:
            return tomllib.load(f)
    except tomllib.TOMLDecodeError as exc:
        raise ValueError(f"{path}: not valid TOML ({exc})") from None


def problems(manifest: dict, package_root: str | Path | None = None,
             expect_platforms: tuple[str, ...] = PLATFORMS) -> list[str]:
    """Every rule the manifest breaks (empty when valid). With `package_root`, wheels must exist
    there; `expect_platforms` is what it must list (one of them for a single-platform zip)."""
    errors = []
    for key in REQUIRED:
        if key not in manifest:
            errors.append(f"missing required key '{key}'")
    for key in ("schema_version", "version", "blender_version_min", "blender_version_max"):
        value = manifest.get(key)
        if value is not None and not (isinstance(value, str) and _VERSION.match(value)):
            errors.append(f"'{key}' must be a version string like 1.2.3, got {value!r}")
    if manifest.get("schema_version") not in (None, "1.0.0"):
        errors.append(f"'schema_version' must be \"1.0.0\", got {manifest.get('schema_version')!r}")
    ident = manifest.get("id")
    if ident is not None and not (isinstance(ident, str) and _ID.match(ident)):
        errors.append(f"'id' must be a Python identifier without leading underscore, got {ident!r}")
    if manifest.get("type") not in (None, "add-on"):
        errors.append(f"'type' must be \"add-on\", got {manifest.get('type')!r}")
    tagline = manifest.get("tagline")
    if isinstance(tagline, str) and (len(tagline) > _TAGLINE_MAX or tagline.endswith((".", "!", "?"))):
        errors.append(f"'tagline' must be at most {_TAGLINE_MAX} characters without final punctuation")
    version_min = manifest.get("blender_version_min")
    if isinstance(version_min, str) and _VERSION.match(version_min) and \
            tuple(map(int, version_min.split("."))) < (4, 2, 0):
        errors.append("'blender_version_min' must be 4.2.0 or later (extensions need it)")
    version_max = manifest.get("blender_version_max")
    if isinstance(version_min, str) and isinstance(version_max, str) and \
            _VERSION.match(version_min) and _VERSION.match(version_max) and \
            version_key(version_max) <= version_key(version_min):
        errors.append("'blender_version_max' (exclusive) must be above 'blender_version_min'")
    licenses = manifest.get("license")
    if licenses is not None and not (isinstance(licenses, list) and licenses and
                                     all(isinstance(x, str) and x.startswith("SPDX:") for x in licenses)):
        errors.append("'license' must be a list of \"SPDX:<identifier>\" strings")
    permissions = manifest.get("permissions", {})
    if not isinstance(permissions, dict):
        errors.append("'permissions' must be a table of reasons")
    else:
        extra = set(permissions) - ALLOWED_PERMISSIONS
        if extra:
            errors.append(f"only the 'files' permission is allowed, found {sorted(extra)}")
        for key, reason in permissions.items():
            if not (isinstance(reason, str) and reason.strip()) or reason.endswith(".") \
                    or len(reason) > _TAGLINE_MAX:
                errors.append(f"permission '{key}' needs a reason of at most {_TAGLINE_MAX} "
                              "characters without final punctuation")
    platforms = manifest.get("platforms")
    if platforms is not None and sorted(platforms) != sorted(expect_platforms):
        errors.append(f"'platforms' must be {list(expect_platforms)}, got {platforms}")
    wheels = manifest.get("wheels", [])
    if not isinstance(wheels, list):
        errors.append("'wheels' must be a list of paths")
        wheels = []
    for wheel in wheels:
        p = PurePosixPath(wheel) if isinstance(wheel, str) else None
        if p is None or "\\" in wheel or not wheel.endswith(".whl") or p.is_absolute() or ".." in p.parts:
            errors.append(f"wheel path {wheel!r} must be a relative ./path/NAME.whl with forward slashes")
            continue
        if not 5 <= len(p.name.split("-")) <= 6:
            errors.append(f"wheel file name {p.name!r} does not follow NAME-VERSION-PY-ABI-PLATFORM.whl")
        if package_root is not None and not (Path(package_root) / p).is_file():
            errors.append(f"wheel {wheel!r} is listed but not in the package")
    errors += _python_coverage(manifest, wheels)
    return errors


def version_key(version: str) -> tuple[int, ...]:
    return tuple(int(x) for x in version.split("."))


def pythons_in_range(version_min: str, version_max: str | None) -> list[str]:
    """The Pythons (PYTHON_BLENDERS) of the Blender releases in [version_min, version_max)."""
    low, high = version_key(version_min), version_key(version_max) if version_max else (10 ** 6,)
    return [py for py, (first, last) in PYTHON_BLENDERS.items() if version_key(first) < high and low < version_key(last)]


def _python_coverage(manifest: dict, wheels: list) -> list[str]:
    """Every binary wheel's distribution must have a wheel for each Python of the Blender
    releases the manifest claims: otherwise those releases install an add-on that cannot
    import it (Blender 5.1+ refused the 3.11-only zip; a range wider than the wheels is a lie)."""
    version_min, version_max = manifest.get("blender_version_min"), manifest.get("blender_version_max")
    if not (isinstance(version_min, str) and _VERSION.match(version_min)) or \
            (version_max is not None and not (isinstance(version_max, str) and _VERSION.match(version_max))):
        return []
    have: dict[str, set[str]] = {}
    for wheel in wheels:
        parts = PurePosixPath(str(wheel)).name[:-4].split("-")
        if len(parts) in (5, 6) and parts[-3].startswith("cp"):
            have.setdefault(parts[0].lower(), set()).add(parts[-3][2] + "." + parts[-3][3:])
    errors = []
    for dist, pythons in sorted(have.items()):
        missing = [py for py in pythons_in_range(version_min, version_max) if py not in pythons]
        if missing:
            errors.append(f"Blender {version_min} - {version_max or 'any'} embeds Python {', '.join(missing)}, "
                          f"but no {dist} wheel is for it (set blender_version_min/_max to what the wheels cover)")
    return errors


def check(manifest: dict, package_root: str | Path | None = None,
          expect_platforms: tuple[str, ...] = PLATFORMS) -> None:
    """ValueError listing every problem, if any."""
    errors = problems(manifest, package_root, expect_platforms)
    if errors:
        raise ValueError("invalid blender_manifest.toml: " + "; ".join(errors))


def wheels_toml(wheels: list[str]) -> str:
    """The `wheels = [...]` assignment for a manifest."""
    body = "".join(f'  "{w}",\n' for w in wheels)
    return f"wheels = [\n{body}]\n"
