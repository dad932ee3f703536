"""Shared fixtures for the style tests: nothing downloads, and the real MiniLM model loads once."""

from __future__ import annotations

import os
import zlib
from typing import Any

import pytest
import torch

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("WANDB_MODE", "offline")

from dgsdp.style.text_encoders import MiniLMTextEncoder, TextEncoder  # noqa: E402


class CountingEncoder(TextEncoder):
    """A cheap deterministic text encoder (vector seeded by the text's CRC) that counts encoded texts."""

    name = "counting"

    def __init__(self, dim: int = 6, salt: int = 0) -> None:
        self._dim = dim
        self.salt = salt
        self.calls = 0
        self.texts_seen: list[str] = []

    @property
    def dim(self) -> int:
        return self._dim

    def settings(self) -> dict[str, Any]:
        return {"name": self.name, "dim": self._dim, "salt": self.salt}

    @property
    def loaded(self) -> bool:
        return self.calls > 0

    def vector(self, text: str) -> torch.Tensor:
        g = torch.Generator().manual_seed(zlib.crc32(text.encode()) + self.salt)
        return torch.randn(self._dim, generator=g)

    def _encode_batch(self, texts: list[str]) -> torch.Tensor:
        self.calls += 1
        self.texts_seen.extend(texts)
        return torch.stack([self.vector(t) for t in texts])


@pytest.fixture
def counting_encoder() -> CountingEncoder:
    return CountingEncoder()


@pytest.fixture(scope="session")
def minilm() -> MiniLMTextEncoder:
    """The real bundled MiniLM encoder, loaded once for the whole test session."""
    return MiniLMTextEncoder()


@pytest.fixture
def counting_encoder_cls() -> type[CountingEncoder]:
    """The class itself, for tests that need several fresh instances."""
    return CountingEncoder
