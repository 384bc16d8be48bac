"""A static ban on unseeded randomness where data is made: farm/ (a scene depends only on
its seed and index), and model/data*.py, model/samples/capture.py and model/training/train_data.py (a
training sample and its order only on (seed, epoch, index)).

Read from the source with `ast` (nothing is imported or run): every call that draws from
a process-global or entropy-seeded source is refused - numpy's module-level functions
(np.random.rand, .seed, ...), np.random.default_rng() / SeedSequence() / RandomState()
without a seed, the standard library's `random` functions and an unseeded
random.Random(), torch's sampling functions and in-place samplers (tensor.uniform_())
without generator=, and os.urandom / uuid.uuid4 / secrets. Explicit seeded generators
pass: np.random.default_rng([seed, index]), random.Random(seed), torch.Generator()
.manual_seed(seed) handed over as generator=.
"""

from __future__ import annotations

import ast
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]

# numpy.random names that build a generator from an explicit seed (checked for one)
NUMPY_SEEDED = {"default_rng", "SeedSequence", "RandomState", "PCG64", "PCG64DXSM", "Philox", "SFC64", "MT19937"}
NUMPY_TYPES = {"Generator", "BitGenerator"}  # wrap a bit generator: no entropy of their own
TORCH_SAMPLERS = {"rand", "randn", "randint", "randperm", "rand_like", "randn_like", "randint_like", "normal",
                  "bernoulli", "multinomial", "poisson"}
TORCH_INPLACE = {"uniform_", "normal_", "bernoulli_", "random_", "exponential_", "geometric_", "cauchy_",
                 "log_normal_"}
ENTROPY = {"os.urandom", "uuid.uuid1", "uuid.uuid4"}


def scanned_files() -> list[Path]:
    model = ROOT / "model"
    return (sorted((ROOT / "farm").rglob("*.py")) + sorted(model.rglob("data*.py"))
            + [model / "samples" / "capture.py", model / "training" / "train_data.py"])


def _aliases(tree: ast.AST) -> dict[str, str]:
    """Local name -> the dotted name it stands for, from the module's imports (any scope)."""
    names: dict[str, str] = {}
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            for alias in node.names:
                names[alias.asname or alias.name.split(".")[0]] = alias.name if alias.asname else alias.name.split(".")[0]
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            for alias in node.names:
                names[alias.asname or alias.name] = f"{node.module}.{alias.name}"
    return names


def _dotted(node: ast.AST, names: dict[str, str]) -> str | None:
    parts = []
    while isinstance(node, ast.Attribute):
        parts.append(node.attr)
        node = node.value
    if not isinstance(node, ast.Name):
        return None
    return ".".join([names.get(node.id, node.id)] + parts[::-1])


def _has_seed(call: ast.Call) -> bool:
    """A first argument or seed= that is not the literal None."""
    args = list(call.args) + [k.value for k in call.keywords if k.arg in ("seed", "entropy", "x")]
    return bool(args) and not (isinstance(args[0], ast.Constant) and args[0].value is None)


def unseeded_calls(source: str, filename: str = "<source>") -> list[str]:
    """'file:line: call' for every unseeded random draw in `source`."""
    tree = ast.parse(source, filename)
    names = _aliases(tree)
    found = []
    for node in ast.walk(tree):
        if not isinstance(node, ast.Call):
            continue
        name = _dotted(node.func, names)
        # generator= given and not the literal None
        keywords = {k.arg for k in node.keywords if not (isinstance(k.value, ast.Constant) and k.value.value is None)}
        bad = False
        if name is not None and name.startswith("numpy.random."):
            leaf = name.rsplit(".", 1)[1]
            bad = leaf not in NUMPY_TYPES and (leaf not in NUMPY_SEEDED or not _has_seed(node))
        elif name is not None and name.startswith("random."):
            bad = name != "random.Random" or not _has_seed(node)
        elif name is not None and name.startswith("torch.") and name.rsplit(".", 1)[1] in TORCH_SAMPLERS:
            bad = "generator" not in keywords
        elif name is not None and (name in ENTROPY or name.startswith("secrets.")):
            bad = True
        elif isinstance(node.func, ast.Attribute) and node.func.attr in TORCH_INPLACE:
            bad = "generator" not in keywords
        if bad:
            found.append(f"{filename}:{node.lineno}: {ast.unparse(node.func)}(...)")
    return found


def test_farm_and_model_data_draw_only_from_seeded_generators():
    files = scanned_files()
    assert len(files) > 20 and any(p.name == "data_augment.py" for p in files)  # the scan reaches them
    found = [hit for path in files for hit in unseeded_calls(path.read_text(encoding="utf-8"),
                                                              str(path.relative_to(ROOT)))]
    assert not found, "unseeded random sources:\n" + "\n".join(found)


UNSEEDED = '''
import random
import os, uuid
import numpy as np
import numpy.random as npr
from numpy.random import default_rng, rand
import torch
from random import randint

a = np.random.rand(3)
np.random.seed(0)
b = np.random.default_rng()
c = default_rng(None)
d = npr.permutation(5)
e = rand(2)
f = random.random()
g = randint(0, 9)
h = random.Random()
i = torch.rand(3)
j = torch.randn(2, generator=None)
k = torch.zeros(3).uniform_()
l = os.urandom(4)
m = uuid.uuid4()
n = np.random.RandomState()
'''

SEEDED = '''
import random
import numpy as np
import torch
from numpy.random import default_rng, Generator, PCG64

rng = np.random.default_rng([seed, index])
other = default_rng(seed=7)
wrapped = Generator(PCG64(3))
draw = rng.uniform(0, 1, 3)          # a Generator's method: seeded
shuffled = rng.permutation(5)
stdlib = random.Random(42).random()
gen = torch.Generator().manual_seed(1)
t = torch.rand(3, generator=gen)
u = torch.zeros(3).normal_(generator=gen)
'''


def test_the_ban_catches_every_unseeded_form_and_passes_seeded_generators():
    found = unseeded_calls(UNSEEDED)
    lines = sorted(int(hit.split(":")[1]) for hit in found)
    # each draw of UNSEEDED (the assignments a .. n and the seed call) is one hit
    expected = [n for n, text in enumerate(UNSEEDED.splitlines(), 1)
                if " = " in text or text.startswith("np.random.seed")]
    assert len(expected) == 15 and lines == expected, found
    assert unseeded_calls(SEEDED) == []


@pytest.mark.parametrize("snippet", ["import numpy\nnumpy.random.shuffle(x)\n",
                                     "from numpy import random as r\nr.normal()\n",
                                     "import secrets\nsecrets.token_bytes(4)\n"])
def test_aliases_do_not_hide_a_source(snippet):
    assert len(unseeded_calls(snippet)) == 1
