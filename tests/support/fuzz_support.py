"""Shared by tests/relight/command/test_hostile_inputs.py and tests/test_fuzz_*.py: generated hostile
files, the Hypothesis profiles, and the outcome counts `make fuzz` prints.

Profiles (RELIGHT_FUZZ_PROFILE picks one; default "ci"): "ci" runs a small,
fixed (derandomized) number of examples per property in the normal test run;
"fuzz" runs many random ones with a per-example deadline (a hang fails).
Loaded with `pytest -p fuzz_support`, this module is also a pytest plugin
that prints the counts: cases run and outcomes by type per property.
"""

from __future__ import annotations

import io
import os
import struct
import warnings
import zlib
from collections import Counter, defaultdict
from contextlib import contextmanager
from datetime import timedelta

import numpy as np
from hypothesis import HealthCheck, settings

PROFILE = os.environ.get("RELIGHT_FUZZ_PROFILE", "ci")
_EXAMPLES = {"ci": 12, "fuzz": int(os.environ.get("RELIGHT_FUZZ_EXAMPLES", "1500"))}
if PROFILE not in _EXAMPLES:
    raise ValueError(f"RELIGHT_FUZZ_PROFILE must be one of {sorted(_EXAMPLES)}, got {PROFILE!r}")

_SUPPRESS = [HealthCheck.function_scoped_fixture, HealthCheck.too_slow, HealthCheck.data_too_large,
             HealthCheck.filter_too_much]
settings.register_profile("relight-ci", max_examples=_EXAMPLES["ci"], deadline=None, derandomize=True,
                          suppress_health_check=_SUPPRESS, print_blob=True)
settings.register_profile("relight-fuzz", max_examples=_EXAMPLES["fuzz"], deadline=timedelta(seconds=30),
                          suppress_health_check=_SUPPRESS, print_blob=True)


def fuzz_settings(scale: float = 1.0) -> settings:
    """The chosen profile's settings, with `scale` times its examples (slow properties: < 1)."""
    parent = settings.get_profile(f"relight-{PROFILE}")
    return settings(parent, max_examples=max(1, int(round(parent.max_examples * scale))))


# ------------------------------------------------------------------ outcome counts

OUTCOMES: dict[str, Counter] = defaultdict(Counter)
CASES: Counter = Counter()


def new_case(test: str) -> None:
    """Count one generated case (one Hypothesis example) of `test`."""
    CASES[test] += 1


def record(prop: str, outcome: str) -> None:
    """Count one call under test, `prop` (a case may make several): "ok", "exit N", or the
    exception type it ended in."""
    OUTCOMES[prop][outcome] += 1


def one_line_error(exc: BaseException) -> None:
    """The project's error contract: a non-empty message on one line."""
    text = str(exc)
    assert text.strip(), f"{type(exc).__name__} with an empty message"
    assert "\n" not in text.strip(), f"{type(exc).__name__} message spans lines: {text!r}"


def run_case(prop: str, call):
    """Run one call under test: its result, or None after a one-line ValueError. Any other
    exception fails the case, and so does a Python warning (it would be stderr lines in
    the CLI); every outcome is counted under `prop`."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            result, outcome = call(), "ok"
        except ValueError as exc:
            one_line_error(exc)
            result, outcome = None, "ValueError"
        except BaseException as exc:
            record(prop, type(exc).__name__)
            raise
    if caught:
        record(prop, "warning")
    assert not caught, [f"{w.category.__name__}: {w.message}" for w in caught]
    record(prop, outcome)
    return result


@contextmanager
def accepted_share(prop: str, floor: float, accepted: tuple[str, ...] = ("ok",)):
    """Around a property's run: fails unless some of the calls counted under `prop` in the
    block were accepted (outcome in `accepted`) and their share is at least `floor`.

    Refusing with a one-line ValueError is allowed case by case, so a loader that refused
    every input would pass each case; this floor fails it. A floor is half the share q of
    cases the generator makes valid by construction (derived where it is set; 0 where no
    branch is valid by construction, leaving "some accepted"): over the "fuzz" profile's
    1500 cases the accepted count falls below half its mean with probability at most
    exp(-1500 q / 8) (Chernoff), under 1e-8 for every q >= 0.1 used here; the "ci"
    profile's cases are fixed (derandomized).
    """
    before = Counter(OUTCOMES[prop])
    yield
    now = OUTCOMES[prop] - before
    calls = sum(now.values())
    ok = sum(now[name] for name in accepted)
    assert ok >= 1 and ok >= floor * calls, (
        f"{prop}: {ok} of {calls} calls accepted, below the floor of {floor:.1%} ({dict(now)})")


def pytest_terminal_summary(terminalreporter):
    if not OUTCOMES:
        return
    total = Counter()
    terminalreporter.write_sep("=", f"fuzz counts (profile {PROFILE})")
    for test in sorted(CASES):
        terminalreporter.write_line(f"{test}: {CASES[test]} generated cases")
    terminalreporter.write_line(f"generated cases: {sum(CASES.values())}")
    for prop in sorted(OUTCOMES):
        counts = OUTCOMES[prop]
        total.update(counts)
        detail = ", ".join(f"{k} {v}" for k, v in sorted(counts.items(), key=lambda kv: -kv[1]))
        terminalreporter.write_line(f"{prop}: {sum(counts.values())} calls ({detail})")
    detail = ", ".join(f"{k} {v}" for k, v in sorted(total.items(), key=lambda kv: -kv[1]))
    terminalreporter.write_line(f"calls: {sum(total.values())} ({detail})")


# ------------------------------------------------------------------ generated files


def radiance_hdr(height: int, width: int, *, declared: tuple[str, str] | None = None, exponent: int | None = None,
                 rle: bool = False, seed: int = 0) -> bytes:
    """A Radiance .hdr file of random texels; `declared` overrides the resolution line's
    (Y, X) text; `exponent` fixes every texel's exponent byte (255: near float32's max)."""
    rng = np.random.default_rng(seed)
    rgbe = rng.integers(0, 256, (height, width, 4), dtype=np.uint8)
    rgbe[..., 3] = rng.integers(120, 140, (height, width)) if exponent is None else exponent
    ys, xs = declared or (str(height), str(width))
    data = bytearray(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {ys} +X {xs}\n".encode())
    for row in rgbe:
        if rle:  # literal runs only: 4 header bytes, then per component chunks of <= 128 bytes
            data += bytes([2, 2, width >> 8, width & 255])
            for c in range(4):
                values = row[:, c].tobytes()
                for i in range(0, width, 128):
                    chunk = values[i:i + 128]
                    data += bytes([len(chunk)]) + chunk
        else:
            data += row.tobytes()
    return bytes(data)


def uniform_rle_hdr(height: int, width: int, value: int = 200, exponent: int = 129) -> bytes:
    """The smallest legal encoding of a uniform map: every component in runs of 127."""
    row = bytearray([2, 2, width >> 8, width & 255])
    for byte in (value, value, value, exponent):
        left = width
        while left:
            run = min(127, left)
            row += bytes([128 + run, byte])
            left -= run
    return b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {height} +X {width}\n".encode() + bytes(row) * height


def jpeg_bytes(height: int = 16, width: int = 16, *, declared: tuple[int, int] | None = None, seed: int = 0,
               smooth: bool = False) -> bytes:
    """A baseline JPEG; `declared` (height, width) is patched into its SOF0 header."""
    from PIL import Image

    rng = np.random.default_rng(seed)
    if smooth:
        y = np.linspace(40, 200, height)[:, None, None]
        x = np.linspace(0, 40, width)[None, :, None]
        pixels = np.broadcast_to(y + x * np.array([-1, 0, 1]), (height, width, 3)).clip(0, 255).astype(np.uint8)
    else:
        pixels = rng.integers(0, 256, (height, width, 3), dtype=np.uint8)
    buf = io.BytesIO()
    Image.fromarray(pixels).save(buf, format="JPEG", quality=85)
    data = bytearray(buf.getvalue())
    if declared is not None:
        sof = data.find(b"\xff\xc0")
        assert sof > 0, "Pillow wrote no baseline SOF0 marker"
        struct.pack_into(">HH", data, sof + 5, *declared)
    return bytes(data)


def png_bytes(height: int, width: int, *, declared: tuple[int, int] | None = None, bit_depth: int = 8,
              colour: int = 2, seed: int = 0) -> bytes:
    """A PNG written by hand (so its IHDR can declare any size with a valid CRC)."""
    rng = np.random.default_rng(seed)
    channels = {0: 1, 2: 3, 4: 2, 6: 4}[colour]
    dtype = ">u2" if bit_depth == 16 else np.uint8
    pixels = rng.integers(0, 2**bit_depth, (height, width * channels)).astype(dtype)
    raw = b"".join(b"\x00" + row.tobytes() for row in pixels)

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    dh, dw = declared or (height, width)
    ihdr = struct.pack(">IIBBBBB", dw, dh, bit_depth, colour, 0, 0, 0)
    return b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IDAT", zlib.compress(raw)) + chunk(b"IEND", b"")


def exr_bytes(tmp_dir, planes: dict[str, np.ndarray], compression: str = "zip") -> bytes:
    """An EXR of the given [H, W] planes, written by relight.files.exr."""
    from relight.files.exr import write_exr

    path = tmp_dir / f".gen_{os.getpid()}.exr"
    write_exr(path, planes, compression=compression)
    data = path.read_bytes()
    path.unlink()
    return data


# ------------------------------------------------------------------ a concurrent writer


@contextmanager
def writer_holding(output):
    """A separate process that holds the writer's lock of `output` (relight.files.fileio.output_lock)
    as a running `relight image` / `relight video` would, until the block ends (then killed with
    SIGKILL, as kill -9 would: the kernel drops the lock). Yields the process."""
    import subprocess
    import sys
    from pathlib import Path

    root = Path(__file__).resolve().parents[2]
    code = ("import sys; from relight.files.fileio import output_lock\n"
            "with output_lock(sys.argv[1]):\n    print('held', flush=True); sys.stdin.read()\n")
    proc = subprocess.Popen([sys.executable, "-c", code, str(output)], cwd=root, stdin=subprocess.PIPE,
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "held"
        yield proc
    finally:
        proc.kill()
        proc.wait(timeout=30)
        proc.stdin.close()
        proc.stdout.close()
