"""Test helpers shared across test folders (importable because tests/conftest.py puts tests/ on sys.path)."""

import torch

from dgsdp.motion import axis_angle_to_matrix, pack_pose


def random_motion(n: int, seed: int = 0) -> torch.Tensor:
    """A valid unnormalised motion (n, 151): random joint rotations, a wandering root, binary contacts."""
    g = torch.Generator().manual_seed(seed)
    rot = axis_angle_to_matrix(0.5 * torch.randn(n, 24, 3, generator=g, dtype=torch.float64))
    trans = torch.randn(n, 3, generator=g, dtype=torch.float64).cumsum(0) * 0.01
    contacts = (torch.rand(n, 4, generator=g) > 0.5).double()
    return pack_pose(contacts, trans, rot).float()
