"""Test-wide settings: nothing may reach a model hub or a dashboard server."""

import os
from pathlib import Path

import pytest

os.environ.setdefault("HF_HUB_OFFLINE", "1")
os.environ.setdefault("TRANSFORMERS_OFFLINE", "1")
os.environ.setdefault("WANDB_MODE", "offline")
os.environ.setdefault("WANDB_SILENT", "true")


@pytest.fixture(scope="session")
def repo_root(pytestconfig) -> Path:
    """The source checkout under test (pytest's root folder): it holds train.py, generate.py and evaluate.py."""
    return Path(pytestconfig.rootpath)


@pytest.fixture
def one_torch_thread():
    """One intra-op thread for the test: tiny tensors run fastest so, and on a small shared machine a second thread
    mostly waits for a core (tiny forwards are tens of times slower with two threads under load). Folders of tiny
    unit tests use it for every test (their conftest.py)."""
    import torch

    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    yield
    torch.set_num_threads(threads)
