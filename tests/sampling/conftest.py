"""Shared fixtures of the sampling tests: one torch thread, and the generation tests' tiny random-init model."""

import pytest
from generation.gen_helpers import tiny_model as build_tiny_model


@pytest.fixture(autouse=True)
def _tiny_tensors(one_torch_thread):
    """Every test here works on tiny tensors: one torch thread (see tests/conftest.py)."""


@pytest.fixture(scope="module")
def tiny_model():
    return build_tiny_model()
