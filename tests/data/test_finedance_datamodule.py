"""data=finedance: the FineDance datamodule's batches, caches, genres and errors on a small synthetic FineDance."""

import numpy as np
import pytest
import torch
from hydra.errors import InstantiationException
from hydra.utils import instantiate

from dgsdp.cli.config import compose_config
from dgsdp.data.finedance import FINEDANCE_GENRES, FineDanceDataModule, load_motion, motion_parts
from dgsdp.data.synthetic_finedance import STANDIN_JOINTS_FILE, generate_synthetic_finedance, standin_rest_joints
from dgsdp.errors import ConfigError, DataError
from dgsdp.motion import forward_kinematics
from dgsdp.motion.skeleton import SMPLX52_PARENTS, smplx_skeleton
from dgsdp.style import StyleEmbedder
from dgsdp.style.vocab import GenreVocab
from dgsdp.utils.io import DiskCache

SMALL = {"sequences_per_genre": 2, "min_seconds": 3.0, "max_seconds": 4.0, "sample_rate_hz": 8000}


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    return generate_synthetic_finedance(tmp_path_factory.mktemp("finedance") / "fd", **SMALL)


def build(cfg):
    """The datamodule of a composed config; a constructor's own error as itself (as the entry points report it)."""
    try:
        return instantiate(cfg.data)
    except InstantiationException as e:
        raise e.__cause__ from None


def config(synthetic, tmp_path, *overrides):
    return compose_config(
        "train",
        [
            "data=finedance", f"data.root={synthetic}", f"data.smplx_file={synthetic / STANDIN_JOINTS_FILE}",
            f"paths.root_dir={tmp_path}", "data.window_seconds=2.0", "data.progress=false", "data.batch_size=4",
            *overrides,
        ],
    )  # fmt: skip


def test_standin_joints_file_is_written_and_labelled(synthetic):
    joints = np.load(synthetic / STANDIN_JOINTS_FILE, allow_pickle=False)
    assert joints.shape == (52, 3) and np.allclose(joints, standin_rest_joints())
    assert "not_smplx" in STANDIN_JOINTS_FILE
    skeleton = smplx_skeleton("full52", synthetic / STANDIN_JOINTS_FILE)
    # each finger joint lies farther from its wrist than its parent: the chains point away from the hand
    for j in range(22, 52):
        wrist = 20 if j < 37 else 21
        p = SMPLX52_PARENTS[j]
        assert np.linalg.norm(joints[j] - joints[wrist]) > np.linalg.norm(joints[p] - joints[wrist]) - 1e-9
    assert skeleton.num_joints == 52


@pytest.mark.parametrize(("joints", "n_joints"), [("body", 22), ("full", 52)])
def test_batches_hold_the_skeletons_pose_vectors(synthetic, tmp_path, joints, n_joints):
    dm = build(config(synthetic, tmp_path, f"data.finedance.joints={joints}", "data.max_sequences=3"))
    assert isinstance(dm, FineDanceDataModule) and dm.skeleton.num_joints == n_joints
    dm.prepare_data()
    dm.setup("fit")
    batch = next(iter(dm.train_dataloader()))
    assert batch["motion"].shape == (4, 60, 7 + 6 * n_joints)
    assert set(batch) == {"motion", "genre", "music_id", "name", "start"}  # audio=None here: motion only
    assert batch["music_id"] == batch["name"]  # each FineDance id has its own song
    # the un-normalised window is the reader's pose vector: the root translation and the 6D of the raw file
    seq = dm.sequences("train")[0]
    trans, rotmats = motion_parts(load_motion(synthetic / "motion" / f"{seq.name}.npy"), joints)
    assert np.allclose(seq.motion[:, 4:7], trans.numpy(), atol=1e-5)
    positions = forward_kinematics(rotmats, trans, skeleton=dm.skeleton)
    assert positions.shape == (len(trans), n_joints, 3)
    assert seq.genre == FINEDANCE_GENRES.code(seq.genre_index)
    # the genre indices are FineDance's (16 genres), not AIST++'s
    assert all(0 <= g < len(FINEDANCE_GENRES) for g in batch["genre"].tolist())
    assert dm.vocab == FINEDANCE_GENRES and len(dm.vocab) == 16


def test_motion_and_features_are_cached_per_skeleton(synthetic, tmp_path):
    from dgsdp.audio import LibrosaEncoder

    cfg = config(synthetic, tmp_path, "data.max_sequences=2")
    encoder = LibrosaEncoder()
    dm = instantiate(cfg.data, audio_encoder=encoder)
    first = dm.sequences("train")
    assert first[0].audio.shape[1] == 35 and abs(len(first[0].audio) - len(first[0].motion)) <= 2
    cached = sorted(p for p in (tmp_path / "data" / "cache").iterdir() if p.name.startswith("finedance-motion"))
    assert len(cached) == 1 and "smplx22" in cached[0].name
    # a second datamodule reads the cache: no motion is processed again
    again = instantiate(cfg.data, audio_encoder=encoder)
    cache = DiskCache(tmp_path / "data" / "cache", cached[0].name)
    stamp = {p: p.stat().st_mtime_ns for p in cache.dir.iterdir()}
    second = again.sequences("train")
    assert {p: p.stat().st_mtime_ns for p in cache.dir.iterdir()} == stamp
    assert all(np.array_equal(a.motion, b.motion) and np.array_equal(a.audio, b.audio) for a, b in zip(first, second))
    # other rest joints give other contacts: another cache folder, never the stale entries
    other = tmp_path / "other_joints.npy"
    np.save(other, standin_rest_joints() * 1.1)
    instantiate(config(synthetic, tmp_path, "data.max_sequences=2", f"data.smplx_file={other}").data).sequences("train")
    assert len([p for p in (tmp_path / "data" / "cache").iterdir() if p.name.startswith("finedance-motion")]) == 2


def test_style_configs_read_finedance_genres_and_prompts(synthetic, tmp_path):
    cfg = config(synthetic, tmp_path, "style=prompt")
    assert cfg.style.vocab == "finedance"
    embedder = StyleEmbedder(kind="prompt", text_encoder={"_target_": "unused"}, vocab=cfg.style.vocab)
    texts, index = embedder.bank_texts()
    assert embedder.vocab == FINEDANCE_GENRES and set(index) == set(range(16)) and len(texts) >= 16
    assert "Breaking" in texts[0]
    assert StyleEmbedder(kind="onehot", vocab="finedance").dim == 16
    # AIST++ runs keep the 10 AIST++ genres and their prompts
    aist = compose_config("train", [f"paths.root_dir={tmp_path}"])
    assert aist.style.vocab is None
    assert len(StyleEmbedder(kind="prompt", text_encoder={"_target_": "unused"}).bank_texts()[0]) > 0
    assert GenreVocab.named("aistpp").codes[0] == "BR"
    with pytest.raises(ConfigError, match="no genre vocabulary named"):
        GenreVocab.named("aist")


@pytest.mark.parametrize(
    ("overrides", "error", "message"),
    [
        (["data.smplx_file=null"], ConfigError, "data.smplx_file is not set.*SMPLX_NEUTRAL"),
        (["data.smplx_file=/nowhere/SMPLX_NEUTRAL.npz"], DataError, "does not exist.*smpl-x"),
        (["data.finedance.joints=hands"], ConfigError, "body"),
        (["+data.finedance.joints_file=x.npy"], ConfigError, "unknown data.finedance.*data.smplx_file"),
        (["+data.skeleton=smpl24"], ConfigError, "disagrees with data.finedance.joints"),
        (["data.fps=60"], ConfigError, "30 FPS"),
        (["data.finedance.split_scheme=crowd"], ConfigError, "split_scheme"),
    ],
)
def test_bad_settings_are_one_clear_error(synthetic, tmp_path, overrides, error, message):
    with pytest.raises(error, match=message):
        build(config(synthetic, tmp_path, *overrides))


def test_folder_is_checked_before_processing(synthetic, tmp_path):
    dm = build(config(synthetic, tmp_path, "data.finedance.split_scheme=dancer", "data.val_split=val"))
    dm.prepare_data()  # the dancer scheme has a val split
    with pytest.raises(DataError, match="no FineDance dataset"):
        build(config(synthetic, tmp_path, f"data.root={tmp_path / 'nowhere'}")).prepare_data()
    with pytest.raises(ConfigError, match="no split 'val'"):
        build(config(synthetic, tmp_path, "data.val_split=val")).prepare_data()


def test_pose_vectors_match_an_independent_fk_contact_check(synthetic, tmp_path):
    """The contacts of the cached pose vectors come from FK on the configured skeleton: recompute them here."""
    dm = build(config(synthetic, tmp_path, "data.max_sequences=1"))
    seq = dm.sequences("train")[0]
    trans, rotmats = motion_parts(load_motion(synthetic / "motion" / f"{seq.name}.npy"), "body")
    positions = forward_kinematics(rotmats, trans, skeleton=dm.skeleton).float()
    feet = positions[:, list(dm.skeleton.foot_joints)]
    speed = torch.zeros(feet.shape[:2])
    speed[:-1] = (feet[1:] - feet[:-1]).norm(dim=-1)
    assert seq.motion[:, :4].min() >= 0 and seq.motion[:, :4].max() <= 1
    # a foot marked in contact moves slower than one marked free, on average
    contact = seq.motion[:-1, :4] > 0.5
    assert contact.any() and (~contact).any()
    assert speed[:-1][torch.from_numpy(contact)].mean() < speed[:-1][torch.from_numpy(~contact)].mean()
