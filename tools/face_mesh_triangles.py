"""Write relight/models/face_mesh_triangles.json: the triangles of MediaPipe's face mesh over its
468 landmarks, read from the mediapipe 0.10.21 wheel (Apache-2.0; relight/models/NOTICE.md).

Not run by CI or the tests. The wheel has no canonical_face_model.obj; its
mediapipe/python/solutions/face_mesh_connections.py lists FACEMESH_TESSELATION as edges, written
in the source as (a, b), (b, c), (c, a) for each triangle in turn (the frozenset loses that order,
so the source text is read): every third edge closes a triangle, which this script checks.

    unzip -o /tmp/mp/mediapipe-0.10.21-*.whl 'mediapipe/python/solutions/face_mesh*' -d /tmp/mp
    python3 tools/face_mesh_triangles.py /tmp/mp/mediapipe/python/solutions/face_mesh_connections.py
"""

from __future__ import annotations

import hashlib
import json
import re
import sys
from pathlib import Path

OUT = Path(__file__).resolve().parents[1] / "relight" / "models" / "face_mesh_triangles.json"


def triangles(source: str) -> list[list[int]]:
    body = source[source.index("FACEMESH_TESSELATION = frozenset(["):]
    body = body[:body.index("])")]
    edges = [(int(a), int(b)) for a, b in re.findall(r"\((\d+),\s*(\d+)\)", body)]
    if len(edges) % 3:
        raise ValueError(f"{len(edges)} edges: not whole triangles")
    out = []
    for i in range(0, len(edges), 3):
        (a, b), (c, d), (e, f) = edges[i:i + 3]
        if not (b == c and d == e and f == a):
            raise ValueError(f"edges {i}..{i + 2} do not close a triangle: {edges[i:i + 3]}")
        out.append([a, b, d])
    return out


def main(argv) -> int:
    path = Path(argv[0])
    tris = triangles(path.read_text(encoding="utf-8"))
    data = {"format": "relight-face-mesh/1",
            "source": "mediapipe 0.10.21 wheel (PyPI), mediapipe/python/solutions/face_mesh_connections.py, "
                      "FACEMESH_TESSELATION: its edges listed in the source as (a, b), (b, c), (c, a) per "
                      "triangle, read back as the triangles (a, b, c) in that order",
            "licence": "Apache-2.0 (Google LLC, MediaPipe): relight/models/NOTICE.md",
            "landmarks": 468, "triangles": tris}
    OUT.write_text(json.dumps(data, separators=(",", ":")) + "\n", encoding="utf-8")
    print(f"{OUT}: {len(tris)} triangles; source sha256 {hashlib.sha256(path.read_bytes()).hexdigest()}, "
          f"written sha256 {hashlib.sha256(OUT.read_bytes()).hexdigest()}")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
