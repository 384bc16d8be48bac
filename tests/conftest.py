"""Shared fixtures."""

import pytest


@pytest.fixture
def one_thread():
    """One torch thread for tiny tensors: faster, and 2 threads crawl when other jobs share the cores."""
    import torch
    before = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(before)
