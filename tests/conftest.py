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
