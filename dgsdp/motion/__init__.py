"""Motion core: skeletons, rotations, forward kinematics, axes, the pose vector, normalisation.

Imports nothing else from dgsdp but its error classes (a bad SMPL-X file or stored skeleton is a user error);
every other sub-package builds on it.
"""

from dgsdp.motion.axes import (
    points_y_up_to_z_up,
    points_z_up_to_y_up,
    root_rotation_y_up_to_z_up,
    root_rotation_z_up_to_y_up,
)
from dgsdp.motion.fk import forward_kinematics
from dgsdp.motion.floor import FloorCleanup, clean_motion, lowest_foot_height, measure_floor_height
from dgsdp.motion.normalizer import MinMaxNormalizer
from dgsdp.motion.representation import (
    POSE_DIM,
    PoseParts,
    channels_for_joints,
    check_pose_dim,
    foot_contacts,
    pack_pose,
    pose_to_joints,
    project_rotations,
    rotation_channels,
    smpl_to_pose,
    unpack_pose,
)
from dgsdp.motion.rotation import (
    axis_angle_to_matrix,
    axis_angle_to_quaternion,
    matrix_slerp,
    matrix_to_6d,
    matrix_to_axis_angle,
    matrix_to_quaternion,
    quaternion_slerp,
    quaternion_to_axis_angle,
    quaternion_to_matrix,
    sixd_to_matrix,
)
from dgsdp.motion.skeleton import (
    FOOT_JOINTS,
    JOINT_NAMES,
    LOWER_BODY_JOINTS,
    NUM_JOINTS,
    PARENTS,
    REST_OFFSETS_M,
    SKELETON_NAMES,
    SMPL24,
    SMPLX52_JOINT_NAMES,
    SMPLX52_PARENTS,
    UPPER_BODY_JOINTS,
    Skeleton,
    joint_index,
    rest_offsets,
    skeleton_from_config,
    smpl24_layout,
    smplx_skeleton,
)

__all__ = [
    "FOOT_JOINTS", "JOINT_NAMES", "LOWER_BODY_JOINTS", "NUM_JOINTS", "PARENTS", "POSE_DIM", "REST_OFFSETS_M",
    "SKELETON_NAMES", "SMPL24", "SMPLX52_JOINT_NAMES", "SMPLX52_PARENTS", "UPPER_BODY_JOINTS", "Skeleton",
    "skeleton_from_config", "smpl24_layout", "smplx_skeleton", "check_pose_dim", "rotation_channels",
    "FloorCleanup", "MinMaxNormalizer", "PoseParts", "axis_angle_to_matrix", "clean_motion", "lowest_foot_height",
    "measure_floor_height", "axis_angle_to_quaternion", "channels_for_joints",
    "foot_contacts", "forward_kinematics", "joint_index", "matrix_slerp", "matrix_to_6d", "matrix_to_axis_angle",
    "matrix_to_quaternion", "pack_pose", "points_y_up_to_z_up", "points_z_up_to_y_up", "pose_to_joints",
    "project_rotations",
    "quaternion_slerp", "quaternion_to_axis_angle", "quaternion_to_matrix", "rest_offsets",
    "root_rotation_y_up_to_z_up", "root_rotation_z_up_to_y_up", "sixd_to_matrix", "smpl_to_pose", "unpack_pose",
]  # fmt: skip
