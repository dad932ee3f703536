"""Reader for the FineDance layout: ``motion/NNN.npy``, ``music_wav/NNN.wav``, ``label_json/NNN.json``.

FineDance (Li et al., ICCV 2023) is mocap dance with fingers, at 30 FPS. Each ``motion/NNN.npy`` is a float array
(T, 315): the root translation (3, metres, y-up), then 52 joints x 6D rotation in SMPL-X order (22 body joints,
15 left-hand and 15 right-hand joints; jaw and eyes are not stored). The 6D rotation is the first two ROWS of the
rotation matrix (pytorch3d's ``matrix_to_rotation_6d``, which FineDance's code uses), the same convention as
:mod:`dgsdp.motion.rotation`. Each ``label_json/NNN.json`` names the song (``name``), the coarse style
(``style1``) and the fine genre (``style2``, see ``dgsdp/resources/finedance/genres.yaml``).

Split and ignore lists are looked up in ``<root>/splits/``, then ``<root>/``, then the official lists shipped in
``dgsdp/resources/finedance/``, as for AIST++ (:func:`dgsdp.data.aistpp.find_list`). Three split schemes:
``genre`` (FineDance@Genre, recommended by its authors: ``train``, ``test``), ``dancer`` (FineDance@Dancer:
``train``, ``val``, ``test``) and ``lodge`` (FineDance@Genre with the 20 test ids LODGE generates: 120 and 130 are
not ignored).

Pose vectors (:func:`pose_vector`): the project's layout, 4 foot contacts + 3 root translation + 6D per joint, z-up,
for the 22 body joints (``joints="body"``, 139-d, LODGE's body-only layout) or all 52 (``joints="full"``, 319-d).
The contacts need forward kinematics on the SMPL-X skeleton, which the caller passes in. LODGE's preprocessing
(trimmed starts, grounding, static windows dropped) is available as options (:func:`load_finedance_sequences`,
:class:`FineDanceDataModule`); :mod:`dgsdp.data.finedance_lodge` converts to and from LODGE's 139-d layout.
"""

from __future__ import annotations

import functools
import json
import logging
import re
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import torch
import yaml

from dgsdp.audio import AudioEncoder
from dgsdp.data import finedance_lodge as lodge
from dgsdp.data.aistpp import find_list, read_list
from dgsdp.data.datamodule import (
    MOTION_CACHE_VERSION,
    DanceDataModule,
    Sequence,
    SourceItem,
    WindowDataset,
    read_sequences,
)
from dgsdp.errors import ConfigError, DataError
from dgsdp.motion.axes import (
    points_y_up_to_z_up,
    points_z_up_to_y_up,
    root_rotation_y_up_to_z_up,
    root_rotation_z_up_to_y_up,
)
from dgsdp.motion.fk import forward_kinematics
from dgsdp.motion.representation import foot_contacts, pack_pose
from dgsdp.motion.rotation import matrix_to_6d, sixd_to_matrix
from dgsdp.resources import FINEDANCE_DIR
from dgsdp.style.vocab import GenreVocab
from dgsdp.utils.io import stable_hash

if TYPE_CHECKING:
    from dgsdp.motion.skeleton import Skeleton

FPS = 30
NUM_JOINTS = 52  # SMPL-X without jaw and eyes: 22 body + 15 left hand + 15 right hand
NUM_BODY_JOINTS = 22
RAW_DIM = 3 + 6 * NUM_JOINTS  # 315
JOINT_SETS = {"body": NUM_BODY_JOINTS, "full": NUM_JOINTS}
SKELETONS = {"body": "smplx22", "full": "smplx52"}  # the skeleton of each joint set (dgsdp.motion.skeleton)
ID_PATTERN = re.compile(r"^\d{3}$")
# split scheme -> (prefix of its list files, its splits)
SPLIT_SCHEMES: dict[str, tuple[str, tuple[str, ...]]] = {
    "genre": ("crossgenre", ("train", "test")),
    "dancer": ("crossdancer", ("train", "val", "test")),
    "lodge": ("lodge", ("train", "test")),  # FineDance@Genre's lists with LODGE's ignore list (docs/finedance.md)
}
MAX_LABEL_BYTES = 1 << 16
LODGE_OPTIONS = ("trim_starts", "ground", "drop_static")  # data.finedance switches for LODGE's preprocessing
log = logging.getLogger(__name__)

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


def is_finedance(root: str | Path) -> bool:
    """Whether a folder holds the FineDance layout (``motion/``; AIST++'s has ``motions/``)."""
    root = Path(root).expanduser()
    return (root / "motion").is_dir() and not (root / "motions").is_dir()


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


def finedance_skeleton(joints: str, joints_file: str | Path | None, *, option: str = "data.smplx_file") -> Skeleton:
    """The SMPL-X skeleton of ``joints`` (``body``: smplx22, ``full``: smplx52) from the SMPL-X model file or a file
    of its rest joint positions (``option`` names the setting that gives it, for the error when it is missing).

    The one place that maps this reader's joint sets onto the project's skeletons."""
    from dgsdp.motion.skeleton import skeleton_from_config

    _joint_count(joints)
    return skeleton_from_config(SKELETONS[joints], joints_file, option=option)


def motion_namespace(skeleton: Skeleton, fps: int = FPS) -> str:
    """Cache folder name of processed FineDance motions: the pose vectors depend on the skeleton's joints and rest
    offsets (the foot contacts come from its FK), so another skeleton or SMPL-X file is another folder."""
    return f"finedance-motion-v{MOTION_CACHE_VERSION}-{fps}fps-{skeleton.name}-{stable_hash(skeleton.to_dict(), 8)}"


def load_finedance_sequences(
    root: str | Path,
    split: str,
    *,
    skeleton: Skeleton,
    scheme: str = "genre",
    cache_dir: str | Path,
    audio_encoder: AudioEncoder | None = None,
    waveform_sample_rate: int | None = None,
    vocab: GenreVocab = FINEDANCE_GENRES,
    max_sequences: int | None = None,
    progress: bool = True,
    errors: list[tuple[str, str]] | None = None,
    trim_starts: bool = False,
    ground: bool = False,
) -> list[Sequence]:
    """The sequences of a FineDance split as pose vectors of ``skeleton`` (smplx22: 22 body joints, smplx52: all
    52) with their music, through the datamodule's cached reading (:func:`dgsdp.data.datamodule.read_sequences`;
    ``errors`` as there). Each id is its own song: the music id is the sequence id.

    LODGE's preprocessing, applied after the cache (which holds the motion as read): ``trim_starts`` drops the
    frames it cuts from the start of ten dances, from their motion and music (:data:`finedance_lodge.TRIM_FRAMES`;
    a dance no longer than its cut is left out); ``ground`` then puts each dance's first frame on the floor
    (:func:`finedance_lodge.ground`)."""
    joints = {v: k for k, v in SKELETONS.items()}.get(skeleton.name)
    if joints is None:
        raise ConfigError(f"FineDance motions are SMPL-X ({', '.join(SKELETONS.values())}), not {skeleton.name}")
    root = check_root(root)

    def read_motion(path: Path) -> np.ndarray:
        def fk(rotmats: torch.Tensor, trans: torch.Tensor) -> torch.Tensor:
            return forward_kinematics(rotmats, trans, skeleton=skeleton)

        return pose_vector(load_motion(path), joints, fk)

    items = []
    for seq_id in read_split(root, split, scheme)[:max_sequences]:
        label = read_label(root / "label_json" / f"{seq_id}.json", vocab)
        items.append(
            SourceItem(
                seq_id,
                label.genre,
                label.genre_index,
                seq_id,
                root / "motion" / f"{seq_id}.npy",
                read_motion,
                functools.partial(wav_path, root, seq_id),
            )  # fmt: skip
        )
    sequences = read_sequences(
        items, split=split, root=root, cache_dir=cache_dir, motion_namespace=motion_namespace(skeleton),
        audio_encoder=audio_encoder, waveform_sample_rate=waveform_sample_rate, progress=progress, errors=errors,
    )  # fmt: skip
    if trim_starts:
        sequences = [t for t in (trim_start(seq, waveform_sample_rate) for seq in sequences) if t is not None]
    if ground:
        sequences = [replace(seq, motion=lodge.ground(seq.motion, skeleton)) for seq in sequences]
    return sequences


def trim_start(seq: Sequence, waveform_sample_rate: int | None = None) -> Sequence | None:
    """``seq`` without the frames LODGE's preprocessing cuts from the start of its dance and music
    (:data:`finedance_lodge.TRIM_FRAMES`; unchanged for other ids), or None when nothing would be left.
    ``waveform_sample_rate``: the rate of a waveform in ``seq.audio`` (features are cut by frames)."""
    cut = lodge.TRIM_FRAMES.get(seq.name, 0)
    if cut == 0:
        return seq
    if cut >= len(seq.motion):
        log.info("FineDance %s left out: LODGE's preprocessing cuts its first %d frames, it has %d", seq.name, cut,
                 len(seq.motion))  # fmt: skip
        return None
    audio = seq.audio
    if audio is not None and audio.ndim == 1:
        if waveform_sample_rate is None:
            raise ValueError(f"the music of {seq.name} is a waveform: give its sample rate to cut its start")
        audio = audio[int(round(cut * waveform_sample_rate / FPS)) :]
    elif audio is not None:
        audio = audio[cut:]
    return replace(seq, motion=seq.motion[cut:], audio=audio)


class FineDanceDataModule(DanceDataModule):
    """``data=finedance``: windows of FineDance for training and evaluation, as :class:`DanceDataModule` makes them
    from AIST++ (the same batches, windows, normaliser, floor height, loaders and caches), with FineDance's reader.

    ``finedance``: ``joints`` (``body``: the 22 body joints, skeleton smplx22, 139-d pose vectors; ``full``: all
    52, smplx52, 319-d) and ``split_scheme`` (``genre``, ``dancer`` or ``lodge``). The skeleton's rest offsets come
    from ``smplx_file`` (the SMPL-X model or a file of its rest joints); ``skeleton`` need not be given (it follows
    ``joints``). Every split's labels and music files are checked in :meth:`prepare_data`, before any processing.

    LODGE's preprocessing, each off by default (docs/finedance.md, "Differences from LODGE"): ``trim_starts`` cuts
    the starts of ten dances, ``ground`` puts each dance's first frame on the floor (both on every split this
    datamodule reads), ``drop_static`` leaves out the training windows whose motion barely varies.
    """

    skeletons = tuple(SKELETONS.values())

    def __init__(
        self,
        root: str,
        cache_dir: str,
        finedance: dict[str, Any] | None = None,
        *,
        skeleton: str | None = None,
        smplx_file: str | None = None,
        fps: int = FPS,
        vocab: GenreVocab | str = FINEDANCE_GENRES,
        **settings: Any,
    ) -> None:
        options = dict(finedance or {})
        self.joints = str(options.pop("joints", "body"))
        self.scheme = str(options.pop("split_scheme", "genre"))
        self.lodge_options = {name: options.pop(name, False) for name in LODGE_OPTIONS}
        if options:
            raise ConfigError(
                f"unknown data.finedance settings {sorted(options)}; known: joints, split_scheme, "
                f"{', '.join(LODGE_OPTIONS)} (the SMPL-X file is data.smplx_file)"
            )
        for name, value in self.lodge_options.items():
            if not isinstance(value, bool):
                raise ConfigError(f"data.finedance.{name} must be true or false, got {value!r}")
        self._static_dropped = False
        _joint_count(self.joints)
        if self.scheme not in SPLIT_SCHEMES:
            raise ConfigError(f"data.finedance.split_scheme={self.scheme!r}: use one of {', '.join(SPLIT_SCHEMES)}")
        wanted = SKELETONS[self.joints]
        if skeleton is not None and skeleton != wanted:
            raise ConfigError(
                f"data.skeleton={skeleton} disagrees with data.finedance.joints={self.joints} (skeleton {wanted}); "
                "choose the joints with data.finedance.joints and leave data.skeleton out"
            )
        if fps != FPS:
            raise ConfigError(f"data.fps={fps}: FineDance is recorded at {FPS} FPS and read at that rate")
        if "synthetic" in settings and settings["synthetic"] is not None:
            raise ConfigError(
                "data=finedance does not generate a dataset; write the synthetic FineDance with "
                "'python -m dgsdp.data.synthetic_finedance <root>'"
            )
        settings.pop("synthetic", None)
        super().__init__(root, cache_dir, skeleton=wanted, smplx_file=smplx_file, fps=fps, vocab=vocab, **settings)

    def settings(self) -> dict[str, Any]:
        finedance = {"joints": self.joints, "split_scheme": self.scheme, **self.lodge_options}
        return {**super().settings(), "finedance": finedance}

    def check(self) -> dict[str, list[str]]:
        """Check the folder; return the ids of each split. One DgsdpError for what is wrong (a bad label or a
        missing song of any split is found here, before any motion is processed)."""
        ids = {stage: read_split(self.root, split, self.scheme) for stage, split in self.splits.items()}
        for seq_id in sorted({i for split_ids in ids.values() for i in split_ids}):
            read_label(self.root / "label_json" / f"{seq_id}.json", self.vocab)
            wav_path(self.root, seq_id)
        return ids

    def prepare_data(self) -> None:
        ids = self.check()
        counts = ", ".join(f"{stage} {len(i)}" for stage, i in ids.items())
        log.info("FineDance at %s: %s sequences, joints=%s (%s)", self.root, counts, self.joints, self.skeleton.name)

    def load_split(self, split: str) -> list[Sequence]:
        return load_finedance_sequences(
            self.root, split, skeleton=self.skeleton, scheme=self.scheme, trim_starts=self.lodge_options["trim_starts"],
            ground=self.lodge_options["ground"], **self.reading_options(),
        )  # fmt: skip

    def setup(self, stage: str | None = None) -> None:
        super().setup(stage)
        train = self.datasets.get("train")
        if self.lodge_options["drop_static"] and train is not None and not self._static_dropped:
            self._drop_static_windows(train)
            self._static_dropped = True

    def _drop_static_windows(self, train: WindowDataset) -> None:
        """Leave out the training windows LODGE's training drops (:func:`finedance_lodge.moving_windows`)."""
        starts: dict[int, list[int]] = {}
        for i, start in train.index:
            starts.setdefault(i, []).append(start)
        keep = {
            (i, s)
            for i, ss in starts.items()
            for s, moving in zip(ss, lodge.moving_windows(train.sequences[i].motion, self.skeleton, ss, self.length))
            if moving
        }
        before = len(train.index)
        train.index = [item for item in train.index if item in keep]
        log.info("FineDance: %d of %d training windows vary too little for LODGE's training and are left out",
                 before - len(train.index), before)  # fmt: skip
        if not train.index:
            raise DataError(
                f"every training window of {self.root} is static by LODGE's measure (data.finedance.drop_static); "
                "turn the option off"
            )
