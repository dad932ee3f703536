"""Shared fixtures of the sampling tests: the generation tests' tiny random-init model."""

import pytest
from generation.gen_helpers import tiny_model as build_tiny_model


@pytest.fixture(scope="module")
def tiny_model():
    return build_tiny_model()
