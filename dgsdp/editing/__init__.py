"""Editing: masks over frames x channels of the pose vector and the given motions they refer to."""

from dgsdp.editing.masks import (
    TASKS,
    build_mask,
    check_task,
    given_frames,
    joint_channels,
    keyframe_indices,
    place_known,
)
from dgsdp.editing.motion_files import load_motion_file

__all__ = [
    "TASKS",
    "build_mask",
    "check_task",
    "given_frames",
    "joint_channels",
    "keyframe_indices",
    "load_motion_file",
    "place_known",
]
