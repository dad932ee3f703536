import pytest


@pytest.fixture(autouse=True)
def _tiny_tensors(one_torch_thread):
    """Every test here works on tiny tensors: one torch thread (see tests/conftest.py)."""
