"""Files people can open: AIST++ motion pickles, BVH and glTF (.glb) for Blender and game engines, and
stick-figure videos with the music.

Every exporter takes a motion in the project's z-up world (local rotations (T, 24, 3, 3) and root translation
(T, 3) metres, or FK joints for rendering) and writes atomically. ``blender_import`` is a script for Blender's own
Python; names are imported on first use so that it can be imported there without the project's dependencies.
"""

from __future__ import annotations

import importlib
from typing import Any

_EXPORTS = {
    "motion_to_aistpp": "aistpp_pkl", "save_aistpp_pkl": "aistpp_pkl",
    "bvh_text": "bvh", "matrix_to_euler_zxy": "bvh", "save_bvh": "bvh",
    "gltf_document": "gltf", "save_glb": "gltf", "MOTION_FORMATS": "formats", "check_formats": "formats",
    "Camera": "render", "ffmpeg_available": "render", "fit_camera": "render", "follow_cameras": "render",
    "render_frame": "render", "render_video": "render",
}  # fmt: skip

__all__ = sorted(_EXPORTS)


def __getattr__(name: str) -> Any:
    if name in _EXPORTS:
        return getattr(importlib.import_module(f"dgsdp.export.{_EXPORTS[name]}"), name)
    raise AttributeError(f"module 'dgsdp.export' has no attribute {name!r}")
