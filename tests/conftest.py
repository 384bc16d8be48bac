"""Shared fixtures."""

import pytest


@pytest.fixture(scope="session")
def model(tmp_path_factory):
    """The tests' tiny exported model (tests/support/tiny_model.py: random weights, SH order 4), made once
    per session, as the path string a command line takes; a module that needs another model makes
    it under another fixture's name."""
    from tiny_model import make_tiny_model
    return str(make_tiny_model(tmp_path_factory))


@pytest.fixture
def addon_settings():
    """The panel's settings for the `addon` fixture beyond Draft, the network's matte and the studio
    preset: a module overrides this fixture to change them."""
    return {}


@pytest.fixture
def addon(model, tmp_path, addon_settings):
    """The add-on registered in an empty scene (tests/support/addon_support.addon_in_empty_scene): the person
    photo in tmp_path/person.png, the panel set to the tiny model and `addon_settings`; yields tmp_path."""
    from addon_support import addon_in_empty_scene
    with addon_in_empty_scene(tmp_path, model, **addon_settings):
        yield tmp_path


@pytest.fixture
def one_thread():
    """One torch thread for tiny tensors: faster, and 2 threads crawl when other jobs share the cores."""
    import torch
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)


def pytest_report_header(config):
    """CPU and kernel-library facts at the top of the log, so that a run that is red on
    another machine says which instruction sets and versions it ran with."""
    import platform

    lines = [f"python {platform.python_version()} on {platform.machine()}"]
    cpu, flags = "unknown", set()
    try:
        with open("/proc/cpuinfo", encoding="utf-8") as f:
            for line in f:
                key, _, value = line.partition(":")
                if key.strip() == "model name" and cpu == "unknown":
                    cpu = value.strip()
                elif key.strip() == "flags" and not flags:
                    flags = set(value.split())
    except OSError:
        cpu = platform.processor() or "unknown"
    simd = [f for f in ("sse4_2", "avx", "fma", "avx2", "avx512f", "avx512bw", "avx512vl", "avx512_vnni",
                        "avx512_bf16", "avx512_fp16", "amx_tile") if f in flags]
    lines.append(f"cpu: {cpu}; flags: {' '.join(simd) or 'n/a'}")
    try:
        import numpy as np
        try:
            from numpy._core import _multiarray_umath as umath
        except ImportError:  # numpy 1.x
            from numpy.core import _multiarray_umath as umath
        dispatched = [f for f in umath.__cpu_dispatch__ if umath.__cpu_features__.get(f)]
        lines.append(f"numpy {np.__version__}: baseline {' '.join(umath.__cpu_baseline__)}; "
                     f"dispatch {' '.join(dispatched)}")
    except ImportError:
        pass
    try:
        import onnxruntime as ort
        lines.append(f"onnxruntime {ort.__version__} ({', '.join(ort.get_available_providers())})")
    except ImportError:
        pass
    return lines
