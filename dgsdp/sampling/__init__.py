"""Sampling: DDPM/DDIM with classifier-free guidance and editing masks."""

from dgsdp.sampling.noise import Noise
from dgsdp.sampling.sampler import Condition, Guidance, Sampler

__all__ = ["Condition", "Guidance", "Noise", "Sampler"]
