"""LODGE's conventions for FineDance, and conversions between its 139-d (or 319-d) motion and this project's.

LODGE (Li et al., CVPR 2024; li-ronghui/LODGE) trains and scores on FineDance through its own preprocessing
(``data/code/preprocess.py``), dataset code (``dld/data/FineDance_dataset.py``), inference (``infer_lodge.py``) and
metric scripts (``metric/``). Where these differ from this project's reader (docs/finedance.md, "Differences from
LODGE"), this module holds LODGE's numbers and the functions that apply them:

- :data:`TRIM_FRAMES`: the frames its preprocessing cuts from the start of ten dances (motion and music);
- :func:`ground`: each dance's first frame put on the floor, by LODGE's rule on the two foot joints;
- :func:`to_lodge` / :func:`from_lodge`: the same column order (4 foot contacts, root translation, 6D per joint),
  but LODGE's is y-up with contacts from foot heights, this project's z-up with contacts from foot speeds;
- :func:`moving_windows`: the training windows LODGE keeps (it drops windows whose motion barely varies).

Command line (the conversion, for LODGE's scripts or from its files)::

    python -m dgsdp.data.finedance_lodge to-lodge ours.npy lodge.npy --smplx-file SMPLX_NEUTRAL.npz
    python -m dgsdp.data.finedance_lodge from-lodge lodge.npy ours.npy --smplx-file SMPLX_NEUTRAL.npz

Either path may be a folder: every ``.npy`` in it is converted into the output folder.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence
from pathlib import Path

import numpy as np
import torch

from dgsdp.errors import DataError, DgsdpError
from dgsdp.motion.axes import (
    points_y_up_to_z_up,
    points_z_up_to_y_up,
    root_rotation_y_up_to_z_up,
    root_rotation_z_up_to_y_up,
)
from dgsdp.motion.fk import forward_kinematics
from dgsdp.motion.representation import CONTACT_CHANNELS, ROOT_CHANNELS, foot_contacts, unpack_pose
from dgsdp.motion.rotation import matrix_to_6d
from dgsdp.motion.skeleton import Skeleton, _smplx_rest_joints, skeleton_from_config

# Frames LODGE's preprocessing (data/code/preprocess.py, motion_feats_extract) drops from the start of these dances
# and of their music features: 3 frames of 010 and 014, and whole seconds (at 30 FPS) of the others, whose openings
# it calls monotonous. 211 is a FineDance@Genre test id; the others are training ids.
TRIM_FRAMES: dict[str, int] = {
    "004": 8 * 30,
    "005": 10 * 30,
    "010": 3,
    "014": 3,
    "067": 6 * 30,
    "105": 19 * 30,
    "110": 14 * 30,
    "113": 29 * 30,
    "153": 52 * 30,
    "211": 22 * 30,
}
# The test ids LODGE's inference generates (infer_lodge.py): FineDance@Genre's 20, 120 and 130 included
TEST_IDS: tuple[str, ...] = (
    "063", "193", "132", "143", "036", "098", "198", "130", "012", "120",
    "179", "065", "137", "161", "092", "037", "109", "204", "144", "211",
)  # fmt: skip
ANKLE_CONTACT_HEIGHT_M = 0.12  # ankle joints below this height (y, metres above the floor) touch the floor
FOOT_CONTACT_HEIGHT_M = 0.05  # foot (toe) joints below this height touch the floor
GROUND_TOLERANCE_M = 0.02  # feet closer in height than this: the floor is their mean height, else the lower one
STATIC_STD = 0.07  # a training window whose 139 channels' mean standard deviation is not above this is dropped
STATIC_CHANNELS = 139  # LODGE measures (and trains on) the body-only vector: contacts, translation, 22 x 6D
UP = 1  # LODGE's up axis (y)


def _as_pose(x: np.ndarray | torch.Tensor, skeleton: Skeleton) -> torch.Tensor:
    """(T, D) pose vectors of ``skeleton`` as float64; one DataError for another shape or non-finite values."""
    x = torch.as_tensor(np.asarray(x) if not isinstance(x, torch.Tensor) else x).to(torch.float64)
    if x.ndim != 2 or x.shape[1] != skeleton.pose_dim or x.shape[0] == 0:
        raise DataError(
            f"motion of shape {tuple(x.shape)}: expected (T, {skeleton.pose_dim}) pose vectors of {skeleton.name} "
            "(4 foot contacts, root translation, 6D per joint)"
        )
    if not torch.isfinite(x).all():
        raise DataError("the motion has NaN or infinite values")
    return x


def ground_height(left: torch.Tensor | float, right: torch.Tensor | float) -> torch.Tensor:
    """LODGE's floor under a standing pose from its two foot joints' heights: their mean when they differ by less
    than 2 cm, else the lower one (``set_on_ground`` in LODGE's preprocessing)."""
    left, right = torch.as_tensor(left, dtype=torch.float64), torch.as_tensor(right, dtype=torch.float64)
    return torch.where((left - right).abs() < GROUND_TOLERANCE_M, (left + right) / 2, torch.minimum(left, right))


def height_contacts(heights: torch.Tensor) -> torch.Tensor:
    """LODGE's foot contacts from heights above the floor (..., 4) of the left and right ankle and foot joints:
    1 where an ankle is below 12 cm or a foot joint below 5 cm."""
    limits = torch.tensor([ANKLE_CONTACT_HEIGHT_M] * 2 + [FOOT_CONTACT_HEIGHT_M] * 2, dtype=heights.dtype)
    return (heights < limits.to(heights.device)).to(heights.dtype)


def ground(x: np.ndarray | torch.Tensor, skeleton: Skeleton) -> np.ndarray:
    """This project's pose vectors (T, D), z-up, with the root translation shifted up or down so that the first
    frame stands on the floor (z = 0) by LODGE's rule (:func:`ground_height` of the two foot joints). float32."""
    x = _as_pose(x, skeleton)
    parts = unpack_pose(x[:1], skeleton)
    toes = list(skeleton.foot_joints[2:])
    height = ground_height(*parts.joints()[0, toes, 2])
    out = x.clone()
    out[:, ROOT_CHANNELS.stop - 1] -= height
    return out.float().numpy()


def to_lodge(
    x: np.ndarray | torch.Tensor, skeleton: Skeleton, *, pelvis_m: Sequence[float], ground: bool = True
) -> np.ndarray:
    """This project's pose vectors (T, 139 or 319: z-up, contacts from foot speeds) -> LODGE's (the same columns:
    y-up, contacts from foot heights), float32.

    The root translation and orientation are turned to y-up (the inverse of how the reader turns FineDance's
    motion), the other joints' 6D are kept as they are. ``pelvis_m`` is SMPL-X's rest pelvis position (y-up, the
    first row of the SMPL-X joints): LODGE's forward kinematics adds it to the translation, this project's does
    not, so it moves every height LODGE measures. With ``ground`` (as LODGE's preprocessing does) the translation
    is lowered so that LODGE's forward kinematics puts the first frame's feet on y = 0; the contacts are then
    those LODGE's preprocessing computes from the same motion."""
    x = _as_pose(x, skeleton)
    pelvis = torch.as_tensor(pelvis_m, dtype=torch.float64)
    if pelvis.shape != (3,) or not torch.isfinite(pelvis).all():
        raise DataError(f"pelvis_m must be three finite numbers (SMPL-X's rest pelvis, metres), got {pelvis_m!r}")
    parts = unpack_pose(x, skeleton)
    rotmats = parts.rotmats.clone()
    rotmats[:, 0] = root_rotation_z_up_to_y_up(rotmats[:, 0])
    trans = points_z_up_to_y_up(parts.root_trans)
    feet = list(skeleton.foot_joints)
    heights = forward_kinematics(rotmats, trans, skeleton=skeleton)[:, feet, UP] + pelvis[UP]
    if ground:
        floor = ground_height(heights[0, 2], heights[0, 3])
        trans[:, UP] -= floor
        heights = heights - floor
    out = x.clone()
    out[:, CONTACT_CHANNELS] = height_contacts(heights)
    out[:, ROOT_CHANNELS] = trans
    out[:, ROOT_CHANNELS.stop : ROOT_CHANNELS.stop + 6] = matrix_to_6d(rotmats[:, 0])
    return out.float().numpy()


def from_lodge(x: np.ndarray | torch.Tensor, skeleton: Skeleton) -> np.ndarray:
    """LODGE's motion (T, 139 or 319: y-up, height contacts) -> this project's pose vectors (z-up, contacts from
    foot speeds, as the FineDance reader makes them), float32. The translation is turned, not moved: a grounded
    LODGE file stays grounded for LODGE's forward kinematics, which places the body higher by SMPL-X's pelvis."""
    x = _as_pose(x, skeleton)
    parts = unpack_pose(x, skeleton)
    rotmats = parts.rotmats.clone()
    rotmats[:, 0] = root_rotation_y_up_to_z_up(rotmats[:, 0])
    trans = points_y_up_to_z_up(parts.root_trans)
    out = x.clone()
    out[:, CONTACT_CHANNELS] = foot_contacts(forward_kinematics(rotmats, trans, skeleton=skeleton), skeleton=skeleton)
    out[:, ROOT_CHANNELS] = trans
    out[:, ROOT_CHANNELS.stop : ROOT_CHANNELS.stop + 6] = matrix_to_6d(rotmats[:, 0])
    return out.float().numpy()


def window_variation(lodge: np.ndarray, starts: Sequence[int], length: int) -> np.ndarray:
    """LODGE's measure of how much a window moves: the mean over its channels (the first 139) of each channel's
    standard deviation over the window's ``length`` frames; one value per start frame."""
    v = np.asarray(lodge, dtype=np.float64)[:, :STATIC_CHANNELS]
    starts = np.asarray(starts, dtype=np.int64)
    if len(starts) == 0:
        return np.zeros(0)
    if length <= 0 or starts.min() < 0 or starts.max() + length > len(v):
        raise ValueError(f"windows of {length} frames at starts {starts.min()}..{starts.max()} exceed {len(v)} frames")
    # sums over each window from cumulative sums, after centring each channel (keeps the variance accurate)
    v = v - v.mean(axis=0)
    s1 = np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(v, axis=0)])
    s2 = np.concatenate([np.zeros((1, v.shape[1])), np.cumsum(v * v, axis=0)])
    mean = (s1[starts + length] - s1[starts]) / length
    var = (s2[starts + length] - s2[starts]) / length - mean**2
    return np.sqrt(np.clip(var, 0.0, None)).mean(axis=1)


def moving_windows(x: np.ndarray | torch.Tensor, skeleton: Skeleton, starts: Sequence[int], length: int) -> np.ndarray:
    """For each window of this project's pose vectors ``x`` (T, D), whether LODGE's training keeps it: the
    window of the same frames of LODGE's vector (:func:`to_lodge`, grounded on the first frame of ``x``) varies by
    more than 0.07 (:func:`window_variation`). The pelvis does not matter here (a constant translation offset
    changes no standard deviation, and grounding cancels it in the contacts). Boolean array, one per start."""
    lodge = to_lodge(x, skeleton, pelvis_m=(0.0, 0.0, 0.0), ground=True)
    return window_variation(lodge, starts, length) > STATIC_STD


# --- command line ---------------------------------------------------------------------------------------------

_SKELETONS = {139: "smplx22", 319: "smplx52"}


def _read(path: Path) -> np.ndarray:
    if not path.is_file():
        raise DataError(f"motion file {path} does not exist")
    try:
        data = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as e:
        raise DataError(f"{path} is not a plain .npy array ({e})") from e
    if isinstance(data, np.ndarray) and data.ndim == 2 and data.shape[1] == 315:
        raise DataError(
            f"{path} is a raw FineDance motion (T, 315), not pose vectors: make them with "
            "dgsdp.data.finedance.pose_vector first"
        )
    if not isinstance(data, np.ndarray) or data.ndim != 2 or data.shape[1] not in _SKELETONS:
        raise DataError(
            f"{path} holds an array of shape {getattr(data, 'shape', None)}; expected (T, 139) (22 body joints) or "
            "(T, 319) (52 joints) pose vectors"
        )
    return data


def convert_file(
    source: str | Path, target: str | Path, *, direction: str, smplx_file: str | Path, ground: bool = True
) -> Path:
    """Convert one ``.npy`` (``direction``: ``to-lodge`` or ``from-lodge``) with the skeleton of the SMPL-X file
    (its 22 or 52 joints after the file's width); write ``target`` (float32). Returns the written path."""
    if direction not in ("to-lodge", "from-lodge"):
        raise ValueError(f"direction must be 'to-lodge' or 'from-lodge', got {direction!r}")
    source, target = Path(source), Path(target)
    data = _read(source)
    skeleton = skeleton_from_config(_SKELETONS[data.shape[1]], smplx_file, option="--smplx-file")
    if direction == "to-lodge":
        pelvis = _smplx_rest_joints(smplx_file, "--smplx-file")[0]
        out = to_lodge(data, skeleton, pelvis_m=pelvis, ground=ground)
    else:
        out = from_lodge(data, skeleton)
    target.parent.mkdir(parents=True, exist_ok=True)
    np.save(target, out)
    return target


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m dgsdp.data.finedance_lodge",
        description="Convert FineDance pose vectors between this project's layout (z-up, contacts from foot "
        "speeds) and LODGE's (y-up, contacts from foot heights, grounded).",
    )
    sub = parser.add_subparsers(dest="direction", required=True)
    for name, what in (("to-lodge", "ours -> LODGE's"), ("from-lodge", "LODGE's -> ours")):
        p = sub.add_parser(name, help=f"{what} (a file, or every .npy of a folder)")
        p.add_argument("source", type=Path, help=".npy of (T, 139) or (T, 319), or a folder of them")
        p.add_argument("target", type=Path, help="the .npy to write, or a folder when the source is one")
        p.add_argument(
            "--smplx-file", required=True,
            help="SMPLX_NEUTRAL.npz or a .npy/.npz of SMPL-X's rest joints (as data.smplx_file)",
        )  # fmt: skip
        if name == "to-lodge":
            p.add_argument("--no-ground", action="store_true", help="keep the height (LODGE's preprocessing grounds)")
    args = parser.parse_args(argv)
    try:
        if args.source.is_dir():
            pairs = [(f, args.target / f.name) for f in sorted(args.source.glob("*.npy"))]
            if not pairs:
                raise DataError(f"no .npy files in {args.source}")
        else:
            pairs = [(args.source, args.target)]
        for source, target in pairs:
            convert_file(
                source, target, direction=args.direction, smplx_file=args.smplx_file,
                ground=not getattr(args, "no_ground", False),
            )  # fmt: skip
    except DgsdpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    print(f"wrote {len(pairs)} file(s) ({args.direction}) to {args.target}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
