"""One header reader in the core (issue 49): in relight/, only relight/files/photo_header.py opens an
image file with Pillow (PIL.Image.open). The pixel decoders (relight.files.photo, and
relight.files.video_io for a frame's 8-bit codes) decode from the image it opened (open_photo), so
a file's size, format, orientation and focal length, and what is wrong with it, have one reading.

Read from the source (AST), as a grep would but knowing the names a module binds: `from PIL import
Image [as X]`, `import PIL[.Image] [as X]`, `from PIL.Image import open [as X]`, at module level or
inside a function."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
# the modules that may open an image file with Pillow: the header reader
ALLOWED = ("relight/files/photo_header.py",)


def pillow_opens(source: str) -> list[int]:
    """The lines of `source` that call PIL.Image.open, under whatever names the module bound."""
    tree = ast.parse(source)
    pil, image, opener = set(), set(), set()  # names bound to PIL, to PIL.Image, to PIL.Image.open
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                if alias.name == "PIL" or (alias.name == "PIL.Image" and alias.asname is None):
                    pil.add(alias.asname or "PIL")
                elif alias.name == "PIL.Image":
                    image.add(alias.asname)
        elif isinstance(node, ast.ImportFrom) and node.module in ("PIL", "PIL.Image"):
            for alias in node.names:
                if node.module == "PIL" and alias.name == "Image":
                    image.add(alias.asname or "Image")
                elif node.module == "PIL.Image" and alias.name == "open":
                    opener.add(alias.asname or "open")
    lines = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        f = node.func
        if isinstance(f, ast.Name) and f.id in opener:
            lines.append(node.lineno)
        elif isinstance(f, ast.Attribute) and f.attr == "open":
            owner = f.value
            if isinstance(owner, ast.Name) and owner.id in image:
                lines.append(node.lineno)
            elif (isinstance(owner, ast.Attribute) and owner.attr == "Image" and isinstance(owner.value, ast.Name)
                  and owner.value.id in pil):
                lines.append(node.lineno)
    return sorted(lines)


def test_the_check_finds_each_way_of_calling_pillows_open():
    assert pillow_opens("from PIL import Image\nwith Image.open(p) as im:\n    pass\n") == [2]
    assert pillow_opens("def f(p):\n    from PIL import Image as I\n    return I.open(p)\n") == [3]
    assert pillow_opens("import PIL.Image\nPIL.Image.open(p)\n") == [2]
    assert pillow_opens("import PIL.Image as PI\nPI.open(p)\n") == [2]
    assert pillow_opens("from PIL.Image import open as o\no(p)\n") == [2]
    # not Pillow's: the built-in open, a file's open, Pillow's other calls
    assert pillow_opens("from PIL import Image\nopen(p)\nPath(p).open()\nImage.fromarray(a)\n") == []


def test_only_the_header_reader_opens_images_with_pillow():
    found = {}
    for path in sorted((ROOT / "relight").rglob("*.py")):
        name = path.relative_to(ROOT).as_posix()
        if name not in ALLOWED and (lines := pillow_opens(path.read_text(encoding="utf-8"))):
            found[name] = lines
    assert found == {}, ("open image files through relight.files.photo_header (read_header, open_photo), "
                         f"not PIL.Image.open: {found}")
    assert all(pillow_opens((ROOT / name).read_text(encoding="utf-8")) for name in ALLOWED)  # the rule's one home
