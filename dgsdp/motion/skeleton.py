"""The SMPL 24-joint skeleton used throughout the project (mean body, zero betas).

Our forward kinematics uses these fixed rest offsets, as EDGE does; the official SMPL body model (licensed
weights, ``smplx``) gives slightly different joint positions. Offsets are in metres in SMPL's y-up rest frame.
"""

from __future__ import annotations

import torch

JOINT_NAMES: tuple[str, ...] = (
    "pelvis", "left_hip", "right_hip", "spine1", "left_knee", "right_knee", "spine2", "left_ankle",
    "right_ankle", "spine3", "left_foot", "right_foot", "neck", "left_collar", "right_collar", "head",
    "left_shoulder", "right_shoulder", "left_elbow", "right_elbow", "left_wrist", "right_wrist",
    "left_hand", "right_hand",
)  # fmt: skip
NUM_JOINTS = 24

PARENTS: tuple[int, ...] = (-1, 0, 0, 0, 1, 2, 3, 4, 5, 6, 7, 8, 9, 9, 9, 12, 13, 14, 16, 17, 18, 19, 20, 21)

REST_OFFSETS_M: tuple[tuple[float, float, float], ...] = (
    (0.0, 0.0, 0.0),
    (0.05858135, -0.08228004, -0.01766408),
    (-0.06030973, -0.09051332, -0.01354254),
    (0.00443945, 0.12440352, -0.03838522),
    (0.04345142, -0.38646945, 0.008037),
    (-0.04325663, -0.38368791, -0.00484304),
    (0.00448844, 0.1379564, 0.02682033),
    (-0.01479032, -0.42687458, -0.037428),
    (0.01905555, -0.4200455, -0.03456167),
    (-0.00226458, 0.05603239, 0.00285505),
    (0.04105436, -0.06028581, 0.12204243),
    (-0.03483987, -0.06210566, 0.13032329),
    (-0.0133902, 0.21163553, -0.03346758),
    (0.07170245, 0.11399969, -0.01889817),
    (-0.08295366, 0.11247234, -0.02370739),
    (0.01011321, 0.08893734, 0.05040987),
    (0.12292141, 0.04520509, -0.019046),
    (-0.11322832, 0.04685326, -0.00847207),
    (0.2553319, -0.01564902, -0.02294649),
    (-0.26012748, -0.01436928, -0.03126873),
    (0.26570925, 0.01269811, -0.00737473),
    (-0.26910836, 0.00679372, -0.00602676),
    (0.08669055, -0.01063603, -0.01559429),
    (-0.0887537, -0.00865157, -0.01010708),
)

# Joints whose speed defines foot contact, in the order of the contact channels of the pose vector:
# left ankle, right ankle, left toe, right toe.
FOOT_JOINTS: tuple[int, ...] = (7, 8, 10, 11)

# Joint groups for editing masks. The pelvis (root rotation) goes with the lower body, as do the root
# translation and foot-contact channels (see dgsdp.motion.representation.channels_for_joints).
LOWER_BODY_JOINTS: tuple[int, ...] = (0, 1, 2, 4, 5, 7, 8, 10, 11)
UPPER_BODY_JOINTS: tuple[int, ...] = tuple(j for j in range(NUM_JOINTS) if j not in LOWER_BODY_JOINTS)


def rest_offsets(dtype: torch.dtype = torch.float32, device: torch.device | str | None = None) -> torch.Tensor:
    """Rest offsets from each joint's parent, (24, 3) metres, y-up."""
    return torch.tensor(REST_OFFSETS_M, dtype=dtype, device=device)


def joint_index(name_or_index: str | int) -> int:
    """Index of a joint given by SMPL name (``"left_wrist"``) or index; raises ValueError listing names."""
    if isinstance(name_or_index, int):
        if not 0 <= name_or_index < NUM_JOINTS:
            raise ValueError(f"joint index {name_or_index} out of range 0..{NUM_JOINTS - 1}")
        return name_or_index
    key = str(name_or_index).strip().lower()
    if key.isdigit():
        return joint_index(int(key))
    if key not in JOINT_NAMES:
        raise ValueError(f"unknown joint {name_or_index!r}; known joints: {', '.join(JOINT_NAMES)}")
    return JOINT_NAMES.index(key)
