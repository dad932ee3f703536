"""dgsdp: music- and style-conditioned dance generation (EDGE and DGSDP as one experiment framework).

The Python API (README, "Python API"; reference: docs/reference/api.md)::

    from dgsdp import DanceGenerator
    gen = DanceGenerator.from_checkpoint("model.ckpt")
    dance = gen.dance_to_song("song.wav", style="krump")
    dance.save("my_dance", formats=["bvh", "npy"])

The names below are imported on first use, so that ``import dgsdp.motion`` (or any part) stays light.
"""

from __future__ import annotations

import importlib
from typing import Any

__version__ = "0.1.0"

_API = {
    "DanceGenerator": "dgsdp.generation.pipeline",
    "Dance": "dgsdp.generation.dance",
    "EditSettings": "dgsdp.generation.pipeline",
    "load_model": "dgsdp.trained",
    "TrainedModel": "dgsdp.trained",
    "SamplingSettings": "dgsdp.sampling",
}
__all__ = ["Dance", "DanceGenerator", "EditSettings", "SamplingSettings", "TrainedModel", "__version__", "load_model"]


def __getattr__(name: str) -> Any:
    if name in _API:
        return getattr(importlib.import_module(_API[name]), name)
    raise AttributeError(f"module 'dgsdp' has no attribute {name!r}")
