import pytest

from dgsdp.data.synthetic import generate_synthetic_aistpp


@pytest.fixture(scope="session")
def tiny_synthetic(tmp_path_factory):
    """A small synthetic AIST++ dataset (2 dances per genre: one train, one test) and a shared cache folder."""
    base = tmp_path_factory.mktemp("synthetic")
    root = generate_synthetic_aistpp(base / "data", seed=0, sequences_per_genre=2, seconds=7.0, num_ignored=0)
    return {"root": str(root), "cache": str(base / "cache")}
