"""Decode the HDR maps of the npm package @pmndrs/assets into plain EXR files.

Each hdri/<name>.exr.js in the package holds
`export default 'data:application/exr;base64,...'`. This writes the decoded
bytes unchanged to relight/data/hdri/<name>.exr.

Usage (the tarball from `npm pack @pmndrs/assets@1.7.0`):
    python tools/decode_pmndrs_hdri.py pmndrs-assets-1.7.0.tgz [--out relight/data/hdri]
"""

from __future__ import annotations

import argparse
import base64
import os
import re
import sys
import tarfile
from pathlib import Path

_DATA_URL = re.compile(r"""^\s*export\s+default\s+['"]data:application/exr;base64,([A-Za-z0-9+/=]+)['"]\s*;?\s*$""")
_MEMBER = re.compile(r"^package/hdri/([a-z0-9_]+)\.exr\.js$")
_EXR_MAGIC = b"\x76\x2f\x31\x01"


def decode_module(text: str) -> bytes:
    """The EXR bytes inside one <name>.exr.js module."""
    m = _DATA_URL.match(text)
    if not m:
        raise ValueError("not an `export default 'data:application/exr;base64,...'` module")
    data = base64.b64decode(m.group(1), validate=True)
    if not data.startswith(_EXR_MAGIC):
        raise ValueError("decoded data is not an OpenEXR file")
    return data


def decode_tarball(tarball: Path, out: Path) -> list[Path]:
    written = []
    out.mkdir(parents=True, exist_ok=True)
    with tarfile.open(tarball, "r:gz") as tar:
        for member in tar.getmembers():
            m = _MEMBER.match(member.name)
            if not m or not member.isfile():
                continue
            text = tar.extractfile(member).read().decode("ascii")
            try:
                data = decode_module(text)
            except ValueError as exc:
                raise ValueError(f"{member.name}: {exc}") from None
            target = out / f"{m.group(1)}.exr"
            tmp = target.with_name(f".{target.name}.tmp")
            tmp.write_bytes(data)
            os.replace(tmp, target)
            written.append(target)
    if not written:
        raise ValueError(f"{tarball}: no package/hdri/*.exr.js members")
    return sorted(written)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("tarball", type=Path)
    parser.add_argument("--out", type=Path, default=Path(__file__).resolve().parents[1] / "relight/data/hdri")
    args = parser.parse_args(argv)
    try:
        written = decode_tarball(args.tarball, args.out)
    except (OSError, ValueError, tarfile.TarError) as exc:
        print(f"decode_pmndrs_hdri: {exc}", file=sys.stderr)
        return 2
    for path in written:
        print(f"{path.name}\t{path.stat().st_size} bytes")
    return 0


if __name__ == "__main__":
    sys.exit(main())
