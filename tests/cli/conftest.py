import pytest
import torch


@pytest.fixture(autouse=True)
def one_torch_thread():
    """These tests run tiny tensors: one intra-op thread is fastest, and on a small shared machine a second
    thread mostly waits for a core (tiny forwards are tens of times slower with two threads under load)."""
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
