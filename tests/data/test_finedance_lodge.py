"""LODGE's FineDance conventions (dgsdp.data.finedance_lodge) and data.finedance's LODGE options, checked against
values worked out by hand and against FineDance's raw columns."""

import math
import re
import shutil

import numpy as np
import pytest
import torch
from hydra.errors import InstantiationException
from hydra.utils import instantiate

from dgsdp.cli.config import compose_config
from dgsdp.data import finedance as fd
from dgsdp.data import finedance_lodge as lodge
from dgsdp.data.datamodule import Sequence, window_starts
from dgsdp.data.synthetic_finedance import STANDIN_JOINTS_FILE, generate_synthetic_finedance, standin_rest_joints
from dgsdp.errors import ConfigError, DataError
from dgsdp.motion import forward_kinematics, sixd_to_matrix
from dgsdp.motion.skeleton import smplx_skeleton

SMALL = {"sequences_per_genre": 2, "min_seconds": 3.0, "max_seconds": 4.0, "sample_rate_hz": 8000}
IDENTITY_6D = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0]
# the first two rows of the +90 degree turn about x: a body standing upright in the project's z-up world
STANDING_ROOT_6D_Z_UP = [1.0, 0.0, 0.0, 0.0, 0.0, -1.0]
ELBOW = 18
# a 30 degree turn about z, first two rows
ELBOW_6D = [math.cos(math.pi / 6), -math.sin(math.pi / 6), 0.0, math.sin(math.pi / 6), math.cos(math.pi / 6), 0.0]
PELVIS = (0.01, 0.25, -0.02)


@pytest.fixture(scope="module")
def synthetic(tmp_path_factory):
    return generate_synthetic_finedance(tmp_path_factory.mktemp("finedance") / "fd", **SMALL)


@pytest.fixture(scope="module")
def synthetic_skeleton(synthetic):
    return fd.finedance_skeleton("body", synthetic / STANDIN_JOINTS_FILE)


def rest_joints(feet=(0.03, 0.03), ankles=(0.06, 0.06)):
    """Rest joints (52, 3), y-up, with a known pelvis and known heights of the ankles (7, 8) and feet (10, 11)."""
    joints = standin_rest_joints().copy()
    joints[0] = PELVIS
    joints[7, 1], joints[8, 1] = ankles
    joints[10, 1], joints[11, 1] = feet
    return joints


def skeleton_of(joints, tmp_path):
    path = tmp_path / "joints.npy"
    np.save(path, joints)
    return smplx_skeleton("body22", path)


def standing(heights, x=1.0, y=2.0):
    """The project's pose vectors of a body in its rest pose standing upright (z-up) at root translation
    (x, y, h) for each h, with the left elbow turned (a joint that does not move the feet)."""
    out = np.zeros((len(heights), 139), dtype=np.float32)
    out[:, 4], out[:, 5], out[:, 6] = x, y, heights
    out[:, 7:13] = STANDING_ROOT_6D_Z_UP
    out[:, 13:] = np.tile(IDENTITY_6D, 21)
    out[:, 7 + 6 * ELBOW : 13 + 6 * ELBOW] = ELBOW_6D
    return out


# --- the 139-d conversion, by hand ------------------------------------------------------------------------------


def test_to_lodge_turns_the_axes_and_measures_heights_above_y0(tmp_path):
    skeleton = skeleton_of(rest_joints(), tmp_path)
    heights = [0.0, 0.03, 0.045, 0.07]
    ours = standing(heights)
    out = lodge.to_lodge(ours, skeleton, pelvis_m=PELVIS, ground=False)
    # z-up (x, y, z) -> y-up (x, z, -y)
    assert np.allclose(out[:, 4:7], [[1.0, h, -2.0] for h in heights], atol=1e-6)
    # the upright body's root orientation is the identity in a y-up world; other joints are kept as they are
    assert np.allclose(out[:, 7:13], IDENTITY_6D, atol=1e-6)
    assert np.array_equal(out[:, 13:], ours[:, 13:])
    # LODGE's heights: translation + each joint's rest height (its FK adds the pelvis): ankles h + 0.06 against
    # 0.12, feet h + 0.03 against 0.05
    assert out[:, 0].tolist() == out[:, 1].tolist() == [1.0, 1.0, 1.0, 0.0]  # 0.06 0.09 0.105 0.13
    assert out[:, 2].tolist() == out[:, 3].tolist() == [1.0, 0.0, 0.0, 0.0]  # 0.03 0.06 0.075 0.10


def test_to_lodge_grounds_the_first_frame_feet(tmp_path):
    skeleton = skeleton_of(rest_joints(), tmp_path)
    heights = [0.0, 0.03, 0.045, 0.07]
    out = lodge.to_lodge(standing(heights), skeleton, pelvis_m=PELVIS)
    # both feet at 0.03 in the first frame: the floor is 0.03, so every height drops by 0.03
    assert np.allclose(out[:, 5], [h - 0.03 for h in heights], atol=1e-6)
    assert out[:, 0].tolist() == out[:, 1].tolist() == [1.0, 1.0, 1.0, 1.0]  # 0.03 0.06 0.075 0.10
    assert out[:, 2].tolist() == out[:, 3].tolist() == [1.0, 1.0, 1.0, 0.0]  # 0 0.03 0.045 0.07


@pytest.mark.parametrize(
    ("feet", "floor"),
    [((0.03, 0.045), 0.0375), ((0.03, 0.10), 0.03), ((0.12, 0.05), 0.05)],  # < 2 cm apart: mean; else the lower
)
def test_grounding_rule_on_the_two_feet(tmp_path, feet, floor):
    assert float(lodge.ground_height(*feet)) == pytest.approx(floor)
    skeleton = skeleton_of(rest_joints(feet=feet), tmp_path)
    out = lodge.to_lodge(standing([0.2]), skeleton, pelvis_m=PELVIS)
    assert out[0, 5] == pytest.approx(0.2 - (0.2 + floor), abs=1e-6)


def test_ground_in_the_projects_frame(tmp_path):
    skeleton = skeleton_of(rest_joints(), tmp_path)
    # the project's FK puts the root at the translation: feet at z = 0.2 + (0.03 - 0.25) = -0.02
    grounded = lodge.ground(standing([0.2, 0.5]), skeleton)
    assert np.allclose(grounded[:, 6], [0.22, 0.52], atol=1e-6)
    joints = forward_kinematics(sixd_to_matrix(torch.from_numpy(grounded[:1, 7:]).double().reshape(1, 22, 6)),
                                torch.from_numpy(grounded[:1, 4:7]).double(), skeleton=skeleton)  # fmt: skip
    assert joints[0, [10, 11], 2].abs().max() < 1e-6


def test_finedance_file_in_lodges_layout_is_its_raw_columns(synthetic, synthetic_skeleton):
    """What LODGE's preprocessing writes from a raw file: contacts, FineDance's translation (grounded) and 6D."""
    skeleton, pelvis = synthetic_skeleton, np.load(synthetic / STANDIN_JOINTS_FILE)[0]
    raw = fd.load_motion(synthetic / "motion" / "063.npy")

    def fk(rotmats, trans):
        return forward_kinematics(rotmats, trans, skeleton=skeleton)

    ours = fd.pose_vector(raw, "body", fk)
    kept = lodge.to_lodge(ours, skeleton, pelvis_m=pelvis, ground=False)
    assert np.allclose(kept[:, 4:7], raw[:, :3], atol=1e-6) and np.allclose(kept[:, 7:], raw[:, 3:135], atol=1e-6)
    # grounding by hand: FK straight from the raw y-up columns, plus the pelvis, as LODGE's FK places the body
    rotmats = sixd_to_matrix(torch.from_numpy(raw[:, 3:135]).double().reshape(-1, 22, 6))
    heights = fk(rotmats, torch.from_numpy(raw[:, :3]).double())[:, [7, 8, 10, 11], 1].numpy() + pelvis[1]
    left, right = heights[0, 2], heights[0, 3]
    floor = (left + right) / 2 if abs(left - right) < 0.02 else min(left, right)
    out = lodge.to_lodge(ours, skeleton, pelvis_m=pelvis)
    assert np.allclose(out[:, 5], raw[:, 1] - floor, atol=1e-5)
    above = heights - floor
    expected = np.stack([above[:, 0] < 0.12, above[:, 1] < 0.12, above[:, 2] < 0.05, above[:, 3] < 0.05], axis=1)
    assert np.array_equal(out[:, :4], expected.astype(np.float32))
    # ...and back: the project's vector, its height moved by the floor
    back = lodge.from_lodge(out, skeleton)
    assert np.allclose(back[:, 7:], ours[:, 7:], atol=1e-5) and np.array_equal(back[:, :4], ours[:, :4])
    assert np.allclose(back[:, 6], ours[:, 6] - floor, atol=1e-5)
    assert np.allclose(lodge.from_lodge(kept, skeleton), ours, atol=1e-5)


def test_full_joints_convert_the_same_way(synthetic):
    skeleton = fd.finedance_skeleton("full", synthetic / STANDIN_JOINTS_FILE)
    raw = fd.load_motion(synthetic / "motion" / "063.npy")
    ours = fd.pose_vector(raw, "full", lambda r, t: forward_kinematics(r, t, skeleton=skeleton))
    out = lodge.to_lodge(ours, skeleton, pelvis_m=(0.0, 0.0, 0.0), ground=False)
    assert out.shape == (len(raw), 319) and np.allclose(out[:, 7:], raw[:, 3:], atol=1e-6)


def test_bad_input_is_one_clear_error(synthetic_skeleton):
    with pytest.raises(DataError, match=r"expected \(T, 139\)"):
        lodge.to_lodge(np.zeros((5, 135)), synthetic_skeleton, pelvis_m=PELVIS)
    with pytest.raises(DataError, match="NaN"):
        lodge.from_lodge(np.full((5, 139), np.nan), synthetic_skeleton)
    with pytest.raises(DataError, match="pelvis_m"):
        lodge.to_lodge(standing([0.0]), synthetic_skeleton, pelvis_m=(0.0, 1.0))


# --- static windows ---------------------------------------------------------------------------------------------


def test_window_variation_is_the_mean_standard_deviation():
    rng = np.random.default_rng(0)
    x = rng.normal(3.0, 0.2, size=(200, 145)).cumsum(axis=0) * 0.01
    starts = [0, 7, 50, 140]
    direct = [x[s : s + 60, :139].std(axis=0).mean() for s in starts]
    assert np.allclose(lodge.window_variation(x, starts, 60), direct, rtol=1e-9, atol=1e-12)
    with pytest.raises(ValueError, match="exceed"):
        lodge.window_variation(x, [150], 60)


def test_moving_windows_drop_a_still_pose_and_keep_a_dance(synthetic, synthetic_skeleton):
    still = standing([0.9] * 90)
    assert not lodge.moving_windows(still, synthetic_skeleton, [0, 30], 60).any()
    raw = fd.load_motion(synthetic / "motion" / "063.npy")
    ours = fd.pose_vector(raw, "body", lambda r, t: forward_kinematics(r, t, skeleton=synthetic_skeleton))
    starts = window_starts(len(ours), 60, 15)
    as_lodge = lodge.to_lodge(ours, synthetic_skeleton, pelvis_m=(0.0, 0.0, 0.0))
    expected = [as_lodge[s : s + 60].std(axis=0).mean() > 0.07 for s in starts]
    assert lodge.moving_windows(ours, synthetic_skeleton, starts, 60).tolist() == expected


# --- command line -----------------------------------------------------------------------------------------------


def test_command_line_converts_files_and_folders(synthetic, synthetic_skeleton, tmp_path, capsys):
    joints = synthetic / STANDIN_JOINTS_FILE
    raw = fd.load_motion(synthetic / "motion" / "063.npy")
    ours = fd.pose_vector(raw, "body", lambda r, t: forward_kinematics(r, t, skeleton=synthetic_skeleton))
    (tmp_path / "ours").mkdir()
    np.save(tmp_path / "ours" / "063.npy", ours)
    np.save(tmp_path / "ours" / "098.npy", ours[:40])
    assert lodge.main(["to-lodge", str(tmp_path / "ours"), str(tmp_path / "lodge"), "--smplx-file", str(joints)]) == 0
    assert "wrote 2 file(s)" in capsys.readouterr().out
    written = np.load(tmp_path / "lodge" / "063.npy")
    pelvis = np.load(joints)[0]
    assert np.array_equal(written, lodge.to_lodge(ours, synthetic_skeleton, pelvis_m=pelvis))
    assert np.load(tmp_path / "lodge" / "098.npy").shape == (40, 139)
    args = ["to-lodge", str(tmp_path / "ours" / "063.npy"), str(tmp_path / "kept.npy"), "--smplx-file", str(joints)]
    assert lodge.main([*args, "--no-ground"]) == 0
    assert np.allclose(np.load(tmp_path / "kept.npy")[:, 4:7], raw[:, :3], atol=1e-6)
    back = tmp_path / "back.npy"
    assert lodge.main(["from-lodge", str(tmp_path / "kept.npy"), str(back), "--smplx-file", str(joints)]) == 0
    assert np.allclose(np.load(back), ours, atol=1e-5)


@pytest.mark.parametrize(
    ("make", "message"),
    [
        (None, "does not exist"),
        (lambda p: np.save(p, np.zeros((10, 151), np.float32)), r"shape \(10, 151\).*\(T, 139\)"),
        (lambda p: np.save(p, np.array([{"a": 1}], dtype=object)), "not a plain .npy"),
        (lambda p: np.save(p, np.zeros((10, 315), np.float32)), "raw FineDance motion.*pose_vector"),
    ],
)
def test_command_line_errors_are_one_line(synthetic, tmp_path, capsys, make, message):
    source = tmp_path / "in.npy"
    if make is not None:
        make(source)
    joints = str(synthetic / STANDIN_JOINTS_FILE)
    assert lodge.main(["to-lodge", str(source), str(tmp_path / "out.npy"), "--smplx-file", joints]) == 2
    err = capsys.readouterr().err
    assert err.startswith("error: ") and err.count("\n") == 1
    assert re.search(message, err)


# --- data.finedance options -------------------------------------------------------------------------------------


def build(synthetic, tmp_path, *overrides):
    cfg = compose_config(
        "train",
        [
            "data=finedance", f"data.root={synthetic}", f"data.smplx_file={synthetic / STANDIN_JOINTS_FILE}",
            f"paths.root_dir={tmp_path}", "data.window_seconds=2.0", "data.progress=false", "data.batch_size=4",
            *overrides,
        ],
    )  # fmt: skip
    try:
        return instantiate(cfg.data)
    except InstantiationException as e:
        raise e.__cause__ from None


def test_trim_starts_cuts_lodges_ten_starts(synthetic, tmp_path):
    plain = {
        s.name: s for s in build(synthetic, tmp_path).sequences("train") + build(synthetic, tmp_path).sequences("test")
    }
    dm = build(synthetic, tmp_path, "data.finedance.trim_starts=true")
    trimmed = {s.name: s for s in dm.sequences("train") + dm.sequences("test")}
    # 014 loses 3 frames; 153 (52 s) and the test id 211 (22 s) are longer cuts than the synthetic dances
    assert "014" in plain and np.array_equal(trimmed["014"].motion, plain["014"].motion[3:])
    assert {"153", "211"} <= set(plain) and not {"153", "211"} & set(trimmed)
    assert all(np.array_equal(trimmed[k].motion, plain[k].motion) for k in trimmed if k != "014")


def test_trim_start_cuts_music_features_and_waveforms_alike():
    motion = np.arange(20 * 139, dtype=np.float32).reshape(20, 139)
    features = np.arange(20 * 2, dtype=np.float32).reshape(20, 2)
    cut = fd.trim_start(Sequence("014", "BR", 0, "014", motion, features))
    assert np.array_equal(cut.motion, motion[3:]) and np.array_equal(cut.audio, features[3:])
    wave = np.arange(20 * 100, dtype=np.float32)  # 3000 Hz: 100 samples a frame
    assert np.array_equal(fd.trim_start(Sequence("014", "BR", 0, "014", motion, wave), 3000).audio, wave[300:])
    assert fd.trim_start(Sequence("153", "BR", 0, "153", motion, None)) is None  # 1560 frames cut from 20
    unchanged = Sequence("063", "BR", 0, "063", motion, features)
    assert fd.trim_start(unchanged) is unchanged


def test_ground_puts_each_first_frame_on_the_floor(synthetic, tmp_path):
    copy = shutil.copytree(synthetic, tmp_path / "fd")
    lifted = fd.read_split(copy, "train")[0]
    raw = fd.load_motion(copy / "motion" / f"{lifted}.npy")
    raw[:, 1] += 0.3  # FineDance is y-up: this dance now floats 30 cm above the others
    np.save(copy / "motion" / f"{lifted}.npy", raw)
    plain = build(copy, tmp_path).sequences("train")
    dm = build(copy, tmp_path, "data.finedance.ground=true")
    for before, after in zip(plain, dm.sequences("train")):
        first = torch.from_numpy(after.motion[:1]).double()
        joints = forward_kinematics(
            sixd_to_matrix(first[:, 7:].reshape(1, 22, 6)), first[:, 4:7], skeleton=dm.skeleton
        )[0]  # fmt: skip
        left, right = joints[10, 2].item(), joints[11, 2].item()
        floor = (left + right) / 2 if abs(left - right) < 0.02 else min(left, right)
        assert abs(floor) < 1e-5
        assert np.array_equal(np.delete(after.motion, 6, axis=1), np.delete(before.motion, 6, axis=1))
        if before.name == lifted:
            assert np.allclose(after.motion[:, 6], before.motion[:, 6] - 0.3, atol=2e-3)


def test_drop_static_leaves_out_lodges_static_training_windows(synthetic, tmp_path):
    plain = build(synthetic, tmp_path)
    plain.setup("fit")
    dm = build(synthetic, tmp_path, "data.finedance.drop_static=true")
    dm.setup("fit")
    expected = []
    for i, seq in enumerate(dm.sequences("train")):
        as_lodge = lodge.to_lodge(seq.motion, dm.skeleton, pelvis_m=(0.0, 0.0, 0.0))
        expected += [
            (i, s) for s in window_starts(len(seq.motion), 60, 15) if as_lodge[s : s + 60].std(axis=0).mean() > 0.07
        ]
    assert dm.datasets["train"].index == expected
    assert 0 < len(expected) < len(plain.datasets["train"].index)  # the synthetic dances have still stretches
    assert dm.datasets["val"].index == plain.datasets["val"].index  # only training windows are dropped
    dm.setup("fit")  # a second setup drops nothing more
    assert dm.datasets["train"].index == expected


def test_lodge_split_scheme_reads_all_twenty_test_ids(synthetic, tmp_path):
    copy = shutil.copytree(synthetic, tmp_path / "fd")
    for new in ("120", "130"):  # FineDance@Genre test ids on FineDance's ignore list
        for folder, suffix in (("motion", "npy"), ("music_wav", "wav"), ("label_json", "json")):
            shutil.copy(copy / folder / f"063.{suffix}", copy / folder / f"{new}.{suffix}")
    genre, lodge_test = fd.read_split(copy, "test"), fd.read_split(copy, "test", "lodge")
    assert set(lodge_test) - set(genre) == {"120", "130"} and set(genre) <= set(lodge_test)
    assert set(lodge_test) <= set(lodge.TEST_IDS) and len(lodge.TEST_IDS) == 20
    assert fd.read_split(copy, "train", "lodge") == fd.read_split(copy, "train")
    assert "202" not in fd.read_split(copy, "train", "lodge") + lodge_test  # still ignored
    dm = build(copy, tmp_path, "data.finedance.split_scheme=lodge")
    assert {s.name for s in dm.sequences("test")} == set(lodge_test)
    # the evaluation reads the scheme a checkpoint records: protocol=finedance then scores the 20 ids
    from dgsdp.evaluation import ClipSource, ProtocolSpec, WarningLog

    spec = ProtocolSpec.from_config({"name": "t", "lengths_seconds": [2], "splits": ["test"]})
    source = ClipSource(spec, data_root=copy, cache_dir=tmp_path / "cache", audio_encoder=None, seed=0,
                        warnings=WarningLog(), progress=False, skeleton=dm.skeleton, split_scheme="lodge")  # fmt: skip
    assert {s.name for s in source.load_split("test", with_music=False)} == set(lodge_test)


@pytest.mark.parametrize("option", ["trim_starts", "ground", "drop_static"])
def test_options_must_be_booleans(synthetic, tmp_path, option):
    with pytest.raises(ConfigError, match=f"data.finedance.{option} must be true or false"):
        build(synthetic, tmp_path, f"data.finedance.{option}=sometimes")
