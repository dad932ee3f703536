"""Shared fixtures of the generation tests."""

import pytest
from gen_helpers import tiny_model as build_tiny_model

from dgsdp.training.module import DanceDiffusion


@pytest.fixture(scope="module")
def tiny_model() -> DanceDiffusion:
    """Random-init tiny denoiser with a one-hot style bank and a normaliser fitted on random motions."""
    return build_tiny_model()
