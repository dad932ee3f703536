"""Reader for the FineDance layout: ``motion/NNN.npy``, ``music_wav/NNN.wav``, ``label_json/NNN.json``.

FineDance (Li et al., ICCV 2023) is mocap dance with fingers, at 30 FPS. Each ``motion/NNN.npy`` is a float array
(T, 315): the root translation (3, metres, y-up), then 52 joints x 6D rotation in SMPL-X order (22 body joints,
15 left-hand and 15 right-hand joints; jaw and eyes are not stored). The 6D rotation is the first two ROWS of the
rotation matrix (pytorch3d's ``matrix_to_rotation_6d``, which FineDance's code uses), the same convention as
:mod:`dgsdp.motion.rotation`. Each ``label_json/NNN.json`` names the song (``name``), the coarse style
(``style1``) and the fine genre (``style2``, see ``dgsdp/resources/finedance/genres.yaml``).

Split and ignore lists are looked up in ``<root>/splits/``, then ``<root>/``, then the official lists shipped in
``dgsdp/resources/finedance/``, as for AIST++ (:func:`dgsdp.data.aistpp.find_list`). Two split schemes:
``genre`` (FineDance@Genre, recommended by its authors: ``train``, ``test``) and ``dancer`` (FineDance@Dancer:
``train``, ``val``, ``test``).

Pose vectors (:func:`pose_vector`): the project's layout, 4 foot contacts + 3 root translation + 6D per joint, z-up,
for the 22 body joints (``joints="body"``, 139-d, LODGE's body-only layout) or all 52 (``joints="full"``, 319-d).
The contacts need forward kinematics on the SMPL-X skeleton, which the caller passes in.
"""

from __future__ import annotations

import json
import re
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import yaml

from dgsdp.data.aistpp import find_list, read_list
from dgsdp.errors import ConfigError, DataError
from dgsdp.motion.axes import (
    points_y_up_to_z_up,
    points_z_up_to_y_up,
    root_rotation_y_up_to_z_up,
    root_rotation_z_up_to_y_up,
)
from dgsdp.motion.representation import foot_contacts, pack_pose
from dgsdp.motion.rotation import matrix_to_6d, sixd_to_matrix
from dgsdp.resources import FINEDANCE_DIR
from dgsdp.style.vocab import GenreVocab

if TYPE_CHECKING:
    from dgsdp.motion.skeleton import Skeleton

FPS = 30
NUM_JOINTS = 52  # SMPL-X without jaw and eyes: 22 body + 15 left hand + 15 right hand
NUM_BODY_JOINTS = 22
RAW_DIM = 3 + 6 * NUM_JOINTS  # 315
JOINT_SETS = {"body": NUM_BODY_JOINTS, "full": NUM_JOINTS}
SKELETON_KINDS = {"body": "body22", "full": "full52"}  # dgsdp.motion.skeleton.smplx_skeleton's kinds
ID_PATTERN = re.compile(r"^\d{3}$")
# split scheme -> (prefix of its list files, its splits)
SPLIT_SCHEMES: dict[str, tuple[str, tuple[str, ...]]] = {
    "genre": ("crossgenre", ("train", "test")),
    "dancer": ("crossdancer", ("train", "val", "test")),
}
MAX_LABEL_BYTES = 1 << 16

FINEDANCE_GENRES = GenreVocab.from_yaml(FINEDANCE_DIR / "genres.yaml")
"""The fine genres of FineDance's label files, in LODGE's class order (16; the paper counts 22)."""
GENRE_ALIASES: dict[str, str] = yaml.safe_load((FINEDANCE_DIR / "genre_aliases.yaml").read_text(encoding="utf-8"))


@dataclass(frozen=True)
class Label:
    """The contents of one ``label_json/NNN.json``."""

    genre: str  # code in FINEDANCE_GENRES, e.g. "DA"
    genre_index: int
    coarse_style: str  # "style1" as the file writes it, e.g. "Folk"
    song: str  # "name": the song's title ("" when the file has none)


@dataclass(frozen=True)
class FineDanceSequence:
    """One FineDance sequence as stored: raw motion (T, 315) float32 at 30 FPS, its label and its music file."""

    id: str
    motion: np.ndarray
    label: Label
    wav: Path

    @property
    def genre(self) -> str:
        return self.label.genre

    @property
    def genre_index(self) -> int:
        return self.label.genre_index


def check_root(root: str | Path) -> Path:
    root = Path(root).expanduser()
    if not (root / "motion").is_dir():
        raise DataError(
            f"no FineDance dataset at {root}: expected a 'motion/' folder of NNN.npy files, 'music_wav/' and "
            "'label_json/' (see docs/finedance.md for where to get it). For a stand-in, generate the synthetic set "
            f"with 'python -m dgsdp.data.synthetic_finedance {root}'"
        )
    return root


def _list_ids(path: Path) -> list[str]:
    ids = read_list(path)
    bad = [i for i in ids if not ID_PATTERN.match(i)]
    if bad:
        raise DataError(f"list {path} has lines that are not three-digit FineDance ids (e.g. '063'): {bad[:5]}")
    return ids


def read_split(root: str | Path, split: str = "train", scheme: str = "genre") -> list[str]:
    """Ids of a split of ``scheme`` (``genre`` or ``dancer``), minus the scheme's ignore list, keeping only those
    whose motion file exists, in the list's order."""
    root = check_root(root)
    if scheme not in SPLIT_SCHEMES:
        raise ConfigError(f"unknown FineDance split scheme {scheme!r}; known schemes: {', '.join(SPLIT_SCHEMES)}")
    prefix, splits = SPLIT_SCHEMES[scheme]
    if split not in splits:
        raise ConfigError(f"FineDance's {scheme!r} scheme has no split {split!r}; its splits: {', '.join(splits)}")
    filename = f"{prefix}_{split}.txt"
    path = find_list(root, filename, FINEDANCE_DIR)
    if path is None:
        raise DataError(
            f"no split list {filename!r} for {root}: put it in {root / 'splits'} (the official lists ship in "
            f"{FINEDANCE_DIR})"
        )
    ignore_path = find_list(root, f"{prefix}_ignore.txt", FINEDANCE_DIR)
    ignored = set(_list_ids(ignore_path)) if ignore_path else set()
    ids = [i for i in _list_ids(path) if i not in ignored]
    present = [i for i in ids if (root / "motion" / f"{i}.npy").is_file()]
    if not present:
        raise DataError(
            f"none of the {len(ids)} ids of split {split!r} ({path}) has a motion file in {root / 'motion'}"
        )
    return present


def load_motion(path: str | Path) -> np.ndarray:
    """Read a FineDance motion file: (T, 315) float32. Never unpickles; one DataError for a bad file."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"motion file {path} does not exist; check the dataset folder (motion/NNN.npy)")
    try:
        data = np.load(path, allow_pickle=False)
    except ValueError as e:  # an object (pickled) array, or a file that is not an .npy
        raise DataError(
            f"motion file {path} cannot be read without unpickling or is not an .npy array ({e}); FineDance "
            f"motions are plain float arrays (T, {RAW_DIM}): re-download the file"
        ) from e
    except (OSError, EOFError) as e:
        raise DataError(f"cannot read motion file {path} ({type(e).__name__}: {e}); re-download the file") from e
    if not isinstance(data, np.ndarray) or data.ndim != 2 or data.shape[1] != RAW_DIM or data.shape[0] == 0:
        shape = getattr(data, "shape", type(data).__name__)
        raise DataError(
            f"motion file {path} holds an array of shape {shape}; FineDance motions are (T, {RAW_DIM}): root "
            "translation (3) and 52 joints x 6D rotation"
        )
    if not (np.issubdtype(data.dtype, np.floating) or np.issubdtype(data.dtype, np.integer)):
        raise DataError(f"motion file {path} holds {data.dtype} values; FineDance motions are float arrays")
    if not np.isfinite(data).all():
        raise DataError(f"motion file {path} has NaN or infinite values; re-download or remove it")
    return data.astype(np.float32)


def read_label(path: str | Path, vocab: GenreVocab = FINEDANCE_GENRES) -> Label:
    """Read and check a ``label_json/NNN.json``: a JSON object with ``style1`` (coarse style) and ``style2`` (fine
    genre, one of ``vocab`` or an alias in ``genre_aliases.yaml``) as non-empty strings, and ``name`` (the song)
    as a string if present."""
    path = Path(path)
    if not path.is_file():
        raise DataError(f"label file {path} does not exist; every motion needs label_json/<id>.json with its genre")
    if path.stat().st_size > MAX_LABEL_BYTES:
        raise DataError(f"label file {path} is {path.stat().st_size} bytes; a FineDance label is a small JSON object")
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (UnicodeDecodeError, ValueError) as e:
        raise DataError(f"label file {path} is not valid JSON ({e}); re-download it") from e
    if not isinstance(data, dict):
        raise DataError(f"label file {path} holds a {type(data).__name__}; expected an object with style1, style2")
    for key in ("style1", "style2"):
        if not isinstance(data.get(key), str) or not data[key].strip():
            raise DataError(
                f"label file {path}: {key!r} must be a non-empty string, got {data.get(key)!r} "
                "(style1 is the coarse style, style2 the fine genre)"
            )
    song = data.get("name", "")
    if not isinstance(song, str):
        raise DataError(f"label file {path}: 'name' (the song) must be a string, got {song!r}")
    written = data["style2"].strip()
    try:
        index = vocab.index(GENRE_ALIASES.get(written, written))
    except ConfigError as e:
        raise DataError(f"label file {path}: style2 {written!r} is not a FineDance genre ({e})") from e
    return Label(vocab.codes[index], index, data["style1"].strip(), song)


def wav_path(root: str | Path, seq_id: str) -> Path:
    path = Path(root) / "music_wav" / f"{seq_id}.wav"
    if not path.is_file():
        raise DataError(f"no music file for FineDance id {seq_id}: {path} is missing; every motion needs its wav")
    return path


def load_sequence(root: str | Path, seq_id: str, vocab: GenreVocab = FINEDANCE_GENRES) -> FineDanceSequence:
    """Motion, label and music path of one id; one DataError naming the bad or missing file."""
    root = Path(root)
    if not ID_PATTERN.match(seq_id):
        raise DataError(f"{seq_id!r} is not a FineDance id (three digits, e.g. '063')")
    motion = load_motion(root / "motion" / f"{seq_id}.npy")
    label = read_label(root / "label_json" / f"{seq_id}.json", vocab)
    return FineDanceSequence(seq_id, motion, label, wav_path(root, seq_id))


def load_split(
    root: str | Path, split: str = "train", scheme: str = "genre", vocab: GenreVocab = FINEDANCE_GENRES
) -> list[FineDanceSequence]:
    """Every sequence of a split (see :func:`read_split`). All files are tried; a DataError lists every bad one."""
    root = check_root(root)
    sequences: list[FineDanceSequence] = []
    failed: list[str] = []
    ids = read_split(root, split, scheme)
    for seq_id in ids:
        try:
            sequences.append(load_sequence(root, seq_id, vocab))
        except DataError as e:
            failed.append(f"{seq_id}: {str(e).rstrip('.')}")
    if failed:
        raise DataError(
            f"{len(failed)} of {len(ids)} sequences of FineDance split {split!r} ({scheme}) in {root} cannot be "
            f"read: {'; '.join(failed)}. Fix or remove these files (or add their ids to {root / 'splits'}/"
            f"{SPLIT_SCHEMES[scheme][0]}_ignore.txt)"
        )
    return sequences


def _joint_count(joints: str) -> int:
    if joints not in JOINT_SETS:
        raise ConfigError(f"data.finedance.joints={joints!r}: use 'body' (22 joints) or 'full' (52, with fingers)")
    return JOINT_SETS[joints]


def motion_parts(raw: np.ndarray | torch.Tensor, joints: str = "body") -> tuple[torch.Tensor, torch.Tensor]:
    """Raw FineDance motion (T, 315) -> root translation (T, 3) and local rotations (T, J, 3, 3), z-up, float64.

    ``joints``: ``body`` keeps the 22 body joints (hands dropped), ``full`` all 52. Rotations are decoded from 6D by
    Gram-Schmidt on the two stored rows; the root orientation and translation are turned from FineDance's y-up
    to the project's z-up as for AIST++ (:mod:`dgsdp.motion.axes`).
    """
    n = _joint_count(joints)
    raw = torch.as_tensor(raw, dtype=torch.float64)
    if raw.ndim != 2 or raw.shape[1] != RAW_DIM:
        raise DataError(f"FineDance motion must be (T, {RAW_DIM}), got {tuple(raw.shape)}")
    rotmats = sixd_to_matrix(raw[:, 3:].reshape(-1, NUM_JOINTS, 6)[:, :n]).clone()
    rotmats[:, 0] = root_rotation_y_up_to_z_up(rotmats[:, 0])
    return points_y_up_to_z_up(raw[:, :3]), rotmats


def raw_motion(root_trans: torch.Tensor, rotmats: torch.Tensor) -> np.ndarray:
    """The inverse of :func:`motion_parts`: z-up translation (T, 3) and rotations (T, 22 or 52, 3, 3) -> raw
    FineDance motion (T, 315) float32, y-up. Hand joints missing from a body-only motion are written as identity
    (flat hands)."""
    if rotmats.shape[-3] not in JOINT_SETS.values() or rotmats.shape[-2:] != (3, 3) or rotmats.ndim != 4:
        raise ValueError(f"rotmats must be (T, 22 or 52, 3, 3), got {tuple(rotmats.shape)}")
    rotmats = rotmats.to(torch.float64).clone()
    rotmats[:, 0] = root_rotation_z_up_to_y_up(rotmats[:, 0])
    if rotmats.shape[1] < NUM_JOINTS:
        hands = torch.eye(3, dtype=rotmats.dtype).expand(len(rotmats), NUM_JOINTS - rotmats.shape[1], 3, 3)
        rotmats = torch.cat((rotmats, hands), dim=1)
    trans = points_z_up_to_y_up(root_trans.to(torch.float64))
    return torch.cat((trans, matrix_to_6d(rotmats).flatten(-2)), dim=-1).float().numpy()


ForwardKinematics = Callable[[torch.Tensor, torch.Tensor], torch.Tensor]
"""(local rotations (T, J, 3, 3), root translation (T, 3)) -> joint positions (T, J, 3), z-up metres."""


def pose_vector(raw: np.ndarray | torch.Tensor, joints: str, fk: ForwardKinematics) -> np.ndarray:
    """Raw FineDance motion (T, 315) at 30 FPS -> pose vectors (T, 4 + 3 + 6J) float32, z-up: foot contacts, root
    translation, J x 6D rotation (J = 22 for ``body``: LODGE's 139-d layout; 52 for ``full``: 319-d).

    ``fk`` is forward kinematics on the SMPL-X skeleton of the same joints (the contacts come from the speed of
    the ankles and feet, joints 7, 8, 10, 11 as in SMPL, by :func:`dgsdp.motion.foot_contacts`).
    """
    trans, rotmats = motion_parts(raw, joints)
    positions = fk(rotmats, trans)
    if positions.shape != (*rotmats.shape[:2], 3):
        raise ValueError(f"fk returned joints of shape {tuple(positions.shape)}, expected {(*rotmats.shape[:2], 3)}")
    return pack_pose(foot_contacts(positions), trans, rotmats).float().numpy()


def finedance_skeleton(joints: str, joints_file: str | Path) -> Skeleton:
    """The SMPL-X skeleton of ``joints`` (``body`` or ``full``) from the rest joint positions in ``joints_file``.

    The one place that maps this reader's joint sets onto :func:`dgsdp.motion.skeleton.smplx_skeleton`."""
    from dgsdp.motion.skeleton import smplx_skeleton

    _joint_count(joints)
    return smplx_skeleton(SKELETON_KINDS[joints], joints_file)


class FineDanceDataModule:
    """``data=finedance``: the FineDance settings of a run, checked against the dataset folder.

    Training, generation and evaluation on FineDance need pose vectors and forward kinematics on the SMPL-X
    skeleton, which the training datamodule (:class:`dgsdp.data.datamodule.DanceDataModule`, SMPL 24 joints) does
    not have yet. Until then :meth:`prepare_data` checks everything it can (settings, the folder, every split's ids,
    labels and music files) and then stops with a ConfigError saying so. Errors are raised there, not on
    construction, so that the entry points report them as one clear message.
    """

    def __init__(
        self,
        root: str,
        cache_dir: str,
        finedance: dict[str, Any] | None = None,
        *,
        train_split: str = "train",
        val_split: str = "test",
        test_split: str = "test",
        audio_encoder: Any = None,
        **settings: Any,
    ) -> None:
        self.root = Path(root).expanduser()
        self.cache_dir = Path(cache_dir).expanduser()
        options = dict(finedance or {})
        self.joints = str(options.pop("joints", "body"))
        self.scheme = str(options.pop("split_scheme", "genre"))
        self.joints_file = options.pop("joints_file", None)
        self.unknown = sorted(options)
        self.splits = {"train": train_split, "val": val_split, "test": test_split}
        self.audio_encoder = audio_encoder
        self.settings = settings  # window and loader settings, for the datamodule to come

    def check(self) -> dict[str, list[str]]:
        """Check the settings and the folder; return the ids of each split. One DgsdpError for what is wrong."""
        if self.unknown:
            raise ConfigError(
                f"unknown data.finedance settings {self.unknown}; known: joints, split_scheme, joints_file"
            )
        _joint_count(self.joints)
        ids = {stage: read_split(self.root, split, self.scheme) for stage, split in self.splits.items()}
        for seq_id in sorted({i for split_ids in ids.values() for i in split_ids}):
            read_label(self.root / "label_json" / f"{seq_id}.json")
            wav_path(self.root, seq_id)
        return ids

    def prepare_data(self) -> None:
        ids = self.check()
        counts = ", ".join(f"{stage} {len(i)}" for stage, i in ids.items())
        raise ConfigError(
            f"FineDance at {self.root} reads correctly ({counts} sequences, joints={self.joints}), but training, "
            "generation and evaluation on FineDance are not available yet: they need the SMPL-X skeleton's pose "
            f"vectors in the training datamodule. Until then, read it with dgsdp.data.finedance (see docs/finedance.md)"
        )
