"""Editing masks over frames x channels of the pose vector (DGSDP Algorithm 2, EDGE Eq. 8).

A mask ``(T, D)`` (D the skeleton's pose size, SMPL-24: 151) holds 1 where the motion is given and 0 where the model
generates it. Joint groups map to channels with :func:`dgsdp.motion.channels_for_joints`: a joint owns its six
6D-rotation channels, and the root translation and foot contacts go with the lower body (the skeleton's
``lower_body_joints``: pelvis, hips, knees, ankles, toes).

Tasks:

- ``none``: nothing given (plain generation);
- ``seed_motion``: the first ``seed_frames`` frames given;
- ``inbetween``: the first ``seed_frames`` and the last ``end_frames`` frames given;
- ``inpaint``: a random ``inpaint_fraction`` of the frames given (EDGE: 70%);
- ``upper_body``: the upper body is generated, the lower body (with root and contacts) given;
- ``lower_body``: the lower body (with root and contacts) is generated, the upper body given;
- ``joints``: the channels of the listed joints given at every frame (``with_root`` adds root and contacts);
- ``keyframes``: every channel (or only the listed joints' channels) given at the listed frames.
"""

from __future__ import annotations

from collections.abc import Sequence

import torch

from dgsdp.errors import ConfigError
from dgsdp.motion import SMPL24, Skeleton, channels_for_joints

TASKS: tuple[str, ...] = (
    "none", "seed_motion", "inbetween", "inpaint", "upper_body", "lower_body", "joints", "keyframes",
)  # fmt: skip


def check_task(task: str | None) -> str:
    """The task name (``None`` means ``none``); raises ConfigError listing the tasks for an unknown one."""
    name = "none" if task is None else str(task).strip().lower()
    if name not in TASKS:
        raise ConfigError(f"unknown editing task {task!r}; use one of: {', '.join(TASKS)}")
    return name


def joint_channels(joints: Sequence[int | str], with_root: bool, skeleton: Skeleton = SMPL24) -> list[int]:
    """Channels of the listed joints (the skeleton's names or indices); ConfigError for an unknown joint."""
    try:
        return channels_for_joints(list(joints), with_root_and_contacts=with_root, skeleton=skeleton)
    except ValueError as e:
        raise ConfigError(str(e)) from e


def keyframe_indices(
    n_frames: int,
    keyframes: Sequence[int] | None = None,
    keyframe_seconds: Sequence[float] | None = None,
    fps: float = 30,
) -> list[int]:
    """Sorted unique frame indices of keyframes given as frames and/or seconds (rounded to the nearest frame).

    Negative frames count from the end (-1 is the last frame). Raises ConfigError for one outside the motion.
    """
    frames: list[int] = []
    for f in keyframes or []:
        f = int(f)
        frames.append(f + n_frames if f < 0 else f)
    for s in keyframe_seconds or []:
        f = int(round(float(s) * fps))
        if f == n_frames and f > 0:  # a keyframe at the very end of the song is its last frame
            f -= 1
        frames.append(f)
    bad = [f for f in frames if not 0 <= f < n_frames]
    if bad:
        raise ConfigError(
            f"keyframe(s) at frame(s) {bad} lie outside the motion of {n_frames} frames "
            f"({n_frames / fps:.2f} s at {fps:g} FPS)"
        )
    return sorted(set(frames))


def build_mask(
    task: str | None,
    n_frames: int,
    *,
    seed_frames: int = 30,
    end_frames: int = 30,
    inpaint_fraction: float = 0.7,
    joints: Sequence[int | str] | None = None,
    with_root: bool = False,
    keyframes: Sequence[int] | None = None,
    keyframe_seconds: Sequence[float] | None = None,
    fps: float = 30,
    generator: torch.Generator | None = None,
    skeleton: Skeleton = SMPL24,
) -> torch.Tensor:
    """Mask ``(n_frames, D)`` float32 over ``skeleton``'s pose vector, 1 = given, for one of :data:`TASKS` (see the
    module docstring).

    seed_frames / end_frames: frames given at the start / end (``seed_motion``, ``inbetween``); inpaint_fraction:
    fraction of frames given at random (``inpaint``, drawn with ``generator``); joints: joint names or indices
    (``joints``; optional for ``keyframes``); keyframes / keyframe_seconds: keyframe positions (``keyframes``).
    """
    task = check_task(task)
    if n_frames <= 0:
        raise ConfigError(f"a mask needs at least one frame, got n_frames={n_frames}")
    mask = torch.zeros(n_frames, skeleton.pose_dim)
    if task == "none":
        return mask
    if task in ("seed_motion", "inbetween"):
        if seed_frames < 0 or end_frames < 0:
            raise ConfigError(f"seed_frames and end_frames must be >= 0, got {seed_frames} and {end_frames}")
        mask[: min(seed_frames, n_frames)] = 1
        if task == "inbetween" and end_frames > 0:
            mask[max(n_frames - end_frames, 0) :] = 1
        return mask
    if task == "inpaint":
        if not 0.0 <= inpaint_fraction <= 1.0:
            raise ConfigError(f"inpaint_fraction must lie in [0, 1], got {inpaint_fraction}")
        n_given = int(round(inpaint_fraction * n_frames))
        frames = torch.randperm(n_frames, generator=generator)[:n_given]
        mask[frames] = 1
        return mask
    if task in ("upper_body", "lower_body"):
        # The named group is generated; the other group is given.
        given = skeleton.lower_body_joints if task == "upper_body" else skeleton.upper_body_joints
        mask[:, joint_channels(given, with_root=task == "upper_body", skeleton=skeleton)] = 1
        return mask
    if task == "joints":
        if not joints:
            raise ConfigError("task=joints needs a list of joints, e.g. joints=[left_wrist,right_wrist]")
        mask[:, joint_channels(joints, with_root=with_root, skeleton=skeleton)] = 1
        return mask
    # keyframes
    frames = keyframe_indices(n_frames, keyframes, keyframe_seconds, fps)
    if not frames:
        raise ConfigError("task=keyframes needs keyframes (frame numbers) or keyframe_seconds")
    channels = joint_channels(joints, with_root=with_root, skeleton=skeleton) if joints else list(range(mask.shape[1]))
    rows = torch.tensor(frames)[:, None]
    mask[rows, torch.tensor(channels)[None, :]] = 1
    return mask


def given_frames(mask: torch.Tensor) -> torch.Tensor:
    """Indices of frames with any given channel: mask (T, D) -> (K,) long."""
    return mask.bool().any(dim=-1).nonzero().flatten()


def frames_needed(task: str, n_frames: int, seed_frames: int, end_frames: int) -> int:
    """How many frames a given motion must supply for ``task`` when it is not the whole motion."""
    if task == "seed_motion":
        return min(seed_frames, n_frames)
    if task == "inbetween":
        return min(seed_frames + end_frames, n_frames)
    return n_frames


def place_known(
    task: str,
    motion: torch.Tensor,
    mask: torch.Tensor,
    *,
    seed_frames: int = 30,
    end_frames: int = 30,
    source: str = "the given motion",
) -> torch.Tensor:
    """Lay a given motion ``(N, D)`` out over the mask's frames (T, D): the known motion ``(T, D)``.

    Accepted layouts: a motion at least as long as the output (its first T frames are used, frame for frame);
    for ``seed_motion`` at least ``seed_frames`` frames (placed at the start); for ``inbetween`` exactly
    ``seed_frames + end_frames`` frames (the first part at the start, the rest at the end); for ``keyframes``
    one frame per keyframe, in order. Anything else raises one ConfigError that says what is expected.
    Values outside the mask are zero (they are never used).
    """
    task = check_task(task)
    n_frames = mask.shape[0]
    motion = torch.as_tensor(motion, dtype=torch.float32)
    if motion.ndim != 2 or motion.shape[1] != mask.shape[1]:
        raise ConfigError(
            f"{source} has shape {tuple(motion.shape)}; the model's pose vectors have {mask.shape[1]} channels"
        )
    known = torch.zeros(n_frames, mask.shape[1])
    n = motion.shape[0]
    if n >= n_frames:
        known = motion[:n_frames].clone()
    elif task == "seed_motion" and n >= frames_needed(task, n_frames, seed_frames, end_frames):
        known[:n] = motion
    elif task == "inbetween" and n == seed_frames + end_frames:
        known[:seed_frames] = motion[:seed_frames]
        known[n_frames - end_frames :] = motion[seed_frames:]
    elif task == "keyframes" and n == len(given_frames(mask)):
        known[given_frames(mask)] = motion
    else:
        needed = {
            "seed_motion": f"at least seed_frames={seed_frames} frames",
            "inbetween": f"seed_frames + end_frames = {seed_frames + end_frames} frames (start, then end) or "
            f"at least {n_frames}",
            "keyframes": f"one frame per keyframe ({len(given_frames(mask))}) or at least {n_frames} frames",
        }.get(task, f"at least {n_frames} frames")
        raise ConfigError(
            f"{source} has {n} frames, which does not fit task={task} on {n_frames} frames: give {needed}"
        )
    return known * mask
