"""Fixtures of the planner tests."""

import pytest
import torch


@pytest.fixture(autouse=True)
def one_thread():
    """Planning is a chain of small tensor ops: with a second intra-op thread on a busy 2-core machine, every
    batched Cholesky waits for the other core (docs/planner.md)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
