"""Sampling: DDPM/DDIM with classifier-free guidance and editing masks, and the settings shared by every caller."""

from dgsdp.sampling.noise import Noise
from dgsdp.sampling.sampler import METHODS, Condition, Guidance, Sampler
from dgsdp.sampling.settings import GuidanceSettings, SamplingSettings

__all__ = ["METHODS", "Condition", "Guidance", "GuidanceSettings", "Noise", "Sampler", "SamplingSettings"]
