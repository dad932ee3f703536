"""Reader for the AIST++ layout: ``motions/*.pkl``, ``wavs/*.wav``, split lists and the ignore list.

The same code reads the real AIST++ (point ``data.root`` at it) and the synthetic dataset that
:mod:`dgsdp.data.synthetic` writes in the same layout.

Split lists are looked up in ``<root>/splits/``, then ``<root>/``, then the official lists shipped with the
package (``dgsdp/resources/aistpp_splits/``).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch

from dgsdp.audio.tempo import tempo_from_music_id
from dgsdp.errors import DataError
from dgsdp.motion import smpl_to_pose
from dgsdp.resources import AISTPP_SPLITS_DIR as SHIPPED_SPLITS_DIR
from dgsdp.safety.safe_pickle import load_pickle

SOURCE_FPS = 60
NAME_PATTERN = re.compile(
    r"^g(?P<genre>[A-Z]{2})_s(?P<situation>[A-Z]{2})_c(?P<camera>\w+?)_d(?P<dancer>\d+)_"
    r"m(?P<music_genre>[A-Z]{2})(?P<music_index>\d+)_ch(?P<choreo>\d+)$"
)
SPLIT_FILES = {"train": "crossmodal_train.txt", "test": "crossmodal_test.txt", "val": "crossmodal_val.txt"}
AUDIO_EXTENSIONS = (".wav", ".mp3", ".flac", ".ogg")


@dataclass(frozen=True)
class SequenceName:
    """The parts of an AIST++ motion name such as ``gBR_sBM_cAll_d04_mBR0_ch01``."""

    name: str
    genre: str  # two-letter code, e.g. "BR"
    situation: str  # "BM" basic or "FM" advanced
    dancer: str
    music_id: str  # e.g. "mBR0"
    choreography: str


def parse_name(name: str) -> SequenceName:
    m = NAME_PATTERN.match(name)
    if m is None:
        raise DataError(
            f"{name!r} is not an AIST++ motion name (expected e.g. 'gBR_sBM_cAll_d04_mBR0_ch01': "
            "genre, situation, camera, dancer, music id, choreography)"
        )
    music_id = f"m{m['music_genre']}{m['music_index']}"
    return SequenceName(name, m["genre"], m["situation"], m["dancer"], music_id, m["choreo"])


def music_tempo_bpm(music_id: str) -> float:
    """Tempo encoded in an AIST++ music id (``mBR0`` is 80 BPM, House ``mHO3`` 125 BPM); DataError if none."""
    bpm = tempo_from_music_id(music_id)
    if bpm is None:
        raise DataError(f"{music_id!r} is not an AIST++ music id (expected e.g. 'mBR0')")
    return bpm


def find_list(root: Path, filename: str, shipped_dir: Path = SHIPPED_SPLITS_DIR) -> Path | None:
    """A split or ignore list: ``<root>/splits/<filename>``, else ``<root>/<filename>``, else the shipped one."""
    for folder in (root / "splits", root, shipped_dir):
        if (folder / filename).is_file():
            return folder / filename
    return None


def read_list(path: Path) -> list[str]:
    """The names in a list file, one a line; blank lines and ``#`` comment lines are skipped."""
    lines = (line.strip() for line in path.read_text().splitlines())
    return [line for line in lines if line and not line.startswith("#")]


def check_root(root: str | Path) -> Path:
    root = Path(root).expanduser()
    if not (root / "motions").is_dir():
        raise DataError(
            f"no AIST++ dataset at {root}: expected a 'motions/' folder of .pkl files and a 'wavs/' folder. "
            "Set data.root to your AIST++ copy, or generate the synthetic dataset with "
            f"'python -m dgsdp.data.synthetic --out {root}'"
        )
    return root


def read_split(root: str | Path, split: str) -> list[str]:
    """Names in a split, minus the ignore list, keeping only those whose motion file exists."""
    root = check_root(root)
    if split not in SPLIT_FILES:
        raise DataError(f"unknown split {split!r}; known splits: {', '.join(SPLIT_FILES)}")
    path = find_list(root, SPLIT_FILES[split])
    if path is None:
        raise DataError(
            f"no split list {SPLIT_FILES[split]!r} for {root}: put it in {root / 'splits'} "
            f"(the official lists ship in {SHIPPED_SPLITS_DIR})"
        )
    ignore_path = find_list(root, "ignore_list.txt")
    ignored = set(read_list(ignore_path)) if ignore_path else set()
    names = [n for n in read_list(path) if n not in ignored]
    present = [n for n in names if (root / "motions" / f"{n}.pkl").is_file()]
    if not present:
        raise DataError(
            f"none of the {len(names)} sequences of split {split!r} ({path}) has a motion file in {root / 'motions'}"
        )
    return present


def music_path(root: str | Path, music_id: str) -> Path:
    root = Path(root)
    for ext in AUDIO_EXTENSIONS:
        p = root / "wavs" / f"{music_id}{ext}"
        if p.is_file():
            return p
    raise DataError(f"no music file for {music_id!r} in {root / 'wavs'} (expected {music_id}.wav)")


def load_motion_pkl(path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """Read an AIST++ motion pickle. Returns (poses (N, 72) axis-angle, trans (N, 3) metres), 60 FPS, y-up."""
    path = Path(path)
    data = load_pickle(path, "motion file")  # plain data and numpy arrays only: never runs code from the file
    return motion_from_pkl_data(data, path)


def motion_from_pkl_data(data: object, path: str | Path) -> tuple[np.ndarray, np.ndarray]:
    """The checked (poses (N, 72), trans (N, 3) metres) of an AIST++ motion pickle's contents ``data``, as read
    from ``path`` (named in the errors); see :func:`load_motion_pkl`."""
    if not isinstance(data, dict):
        raise DataError(f"motion file {path} holds a {type(data).__name__}, expected a dict with 'smpl_poses'")
    missing = [k for k in ("smpl_poses", "smpl_trans") if k not in data]
    if missing:
        raise DataError(
            f"motion file {path} has no {', '.join(missing)} (keys: {sorted(data)}); "
            "AIST++ motion files hold smpl_poses (N, 72), smpl_trans (N, 3) and smpl_scaling (1,)"
        )
    try:
        poses = np.asarray(data["smpl_poses"], dtype=np.float32)
        trans = np.asarray(data["smpl_trans"], dtype=np.float32)
        scaling = float(np.asarray(data.get("smpl_scaling", [1.0]), dtype=np.float64).reshape(-1)[0])
    except (TypeError, ValueError, IndexError) as e:
        raise DataError(
            f"motion file {path}: smpl_poses, smpl_trans and smpl_scaling must be numeric arrays ({e})"
        ) from e
    if poses.ndim != 2 or poses.shape[1] != 72 or trans.shape != (poses.shape[0], 3) or len(poses) == 0:
        raise DataError(
            f"motion file {path}: smpl_poses {poses.shape} and smpl_trans {trans.shape} should be (N, 72) and (N, 3)"
        )
    if not np.isfinite(poses).all() or not np.isfinite(trans).all() or not (np.isfinite(scaling) and scaling > 0):
        raise DataError(f"motion file {path} has non-finite values or a smpl_scaling that is not a positive number")
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        trans_m = trans / scaling
    if not np.isfinite(trans_m).all():
        raise DataError(f"motion file {path}: smpl_trans / smpl_scaling overflows (smpl_scaling {scaling!r})")
    return poses, trans_m


def process_motion(poses: np.ndarray, trans_m: np.ndarray, source_fps: int = SOURCE_FPS, fps: int = 30) -> np.ndarray:
    """AIST++ SMPL parameters (60 FPS, y-up) -> 151-d pose vectors (T, 151) at ``fps``, z-up."""
    if source_fps % fps:
        raise DataError(f"cannot resample {source_fps} FPS motion to {fps} FPS by taking every n-th frame")
    step = source_fps // fps
    x = smpl_to_pose(torch.from_numpy(poses[::step]).double(), torch.from_numpy(trans_m[::step]).double())
    return x.float().numpy()
