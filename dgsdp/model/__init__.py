"""The denoiser network (EDGE DanceDecoder / DGSDP MCSAD) and its layers."""

from dgsdp.model.denoiser import DanceDenoiser

__all__ = ["DanceDenoiser"]
