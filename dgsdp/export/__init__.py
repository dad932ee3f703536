"""Files people can open: AIST++ motion pickles, BVH for Blender, and stick-figure videos with the music.

Every exporter takes a motion in the project's z-up world (local rotations (T, 24, 3, 3) and root translation
(T, 3) metres, or FK joints for rendering) and writes atomically.
"""

from dgsdp.export.aistpp_pkl import motion_to_aistpp, save_aistpp_pkl
from dgsdp.export.bvh import bvh_text, matrix_to_euler_zxy, save_bvh
from dgsdp.export.formats import MOTION_FORMATS, check_formats
from dgsdp.export.render import Camera, ffmpeg_available, fit_camera, render_frame, render_video

__all__ = [
    "MOTION_FORMATS", "Camera", "bvh_text", "check_formats", "ffmpeg_available", "fit_camera", "matrix_to_euler_zxy", "motion_to_aistpp",
    "render_frame", "render_video", "save_aistpp_pkl", "save_bvh",
]  # fmt: skip
