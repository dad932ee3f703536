"""protocol=finedance: LODGE's feature settings checked against hand computations, and FineDance end to end
(train both joint sets on a tiny synthetic FineDance, generate a 30 s song with hands, export, evaluate)."""

import json

import numpy as np
import pytest
from omegaconf import OmegaConf

from dgsdp.cli.config import compose_config
from dgsdp.errors import ConfigError
from dgsdp.evaluation.protocols import ProtocolSpec
from dgsdp.evaluation.scoring import Scorer
from dgsdp.evaluation.warning_log import WarningLog
from dgsdp.metrics import kinetic_features_batch


def finedance_spec(tmp_path, **changes) -> ProtocolSpec:
    cfg = compose_config("evaluate", ["protocol=finedance"], output_dir=tmp_path)
    return ProtocolSpec.from_config({**OmegaConf.to_container(cfg.protocol, resolve=True), **changes})


def test_finedance_protocol_settings(tmp_path):
    spec = finedance_spec(tmp_path)
    assert spec.splits == ["test"] and spec.stride_seconds is None and spec.reference == "dataset"
    assert round(spec.lengths_seconds[0] * 30) == 1024 and round(spec.reference_seconds * 30) == 1024
    assert (spec.root_relative, spec.feature_joints, spec.feature_upsample, spec.anchor_root) == (True, 22, False, True)
    with pytest.raises(ConfigError, match="feature_joints"):
        finedance_spec(tmp_path, feature_joints=23)
    # the AIST++ protocols keep their settings
    table1 = ProtocolSpec.from_config(
        OmegaConf.to_container(compose_config("evaluate", ["protocol=table1"], output_dir=tmp_path).protocol)
    )
    assert (table1.root_relative, table1.feature_joints, table1.feature_upsample, table1.reference_seconds) == (
        False, 24, True, None,
    )  # fmt: skip


def test_lodge_kinetic_arithmetic_by_hand(tmp_path):
    """A joint sliding along x by d per 30 FPS frame, root still: LODGE's kinetic feature (30 FPS frames, frame time
    1/60, root-relative) has horizontal energy (60 d)^2 for it; the upsampled 60 FPS protocols give (30 d)^2."""
    d, n = 0.01, 40
    joints = np.zeros((n, 24, 3))  # z-up, as the scorer takes them
    joints[:, :, 2] = 1.0  # the whole body 1 m up (anchoring and root-relative remove it)
    joints[:, 5, 0] = d * np.arange(n)
    scorer = Scorer(finedance_spec(tmp_path), mode="paper", classifier_method="logistic", warnings=WarningLog())
    prepared, kin, geo = scorer.features([joints])
    assert prepared[0].shape == (n, 24, 3) and kin.shape == (1, 66) and geo.shape == (1, 32)
    assert kin[0, 3 * 5] == pytest.approx((60 * d) ** 2, rel=1e-9)  # horizontal, joint 5
    assert kin[0, 3 * 5 + 1] == pytest.approx(0.0, abs=1e-12)  # vertical
    others = np.delete(kin[0].reshape(22, 3), 5, axis=0)
    assert np.allclose(others, 0.0)
    upsampled = Scorer(
        finedance_spec(tmp_path, feature_upsample=True, feature_joints=24), mode="paper",
        classifier_method="logistic", warnings=WarningLog(),
    )  # fmt: skip
    prepared60, kin60, _ = upsampled.features([joints])
    assert prepared60[0].shape == (2 * n - 1, 24, 3) and kin60.shape == (1, 72)
    assert kin60[0, 3 * 5] == pytest.approx((30 * d) ** 2, rel=1e-9)


def test_root_relative_moves_every_joint_but_the_root(tmp_path):
    """A body translating as a whole: root-relative joints stand still, so only the root has kinetic energy
    (horizontal and vertical columns; the third, energy expenditure, follows the reference's arithmetic)."""
    n = 30
    rng = np.random.default_rng(0)
    pose = rng.normal(0, 0.3, (24, 3))
    joints = np.repeat(pose[None], n, axis=0) + np.linspace(0, 1, n)[:, None, None] * np.array([1.0, 0.5, 0.0])
    _, kin, _ = Scorer(
        finedance_spec(tmp_path), mode="paper", classifier_method="logistic", warnings=WarningLog()
    ).features([joints])
    per_joint = kin[0].reshape(22, 3)
    assert per_joint[0, 0] > 0 and np.allclose(per_joint[1:, :2], 0.0, atol=1e-20)
    # without root_relative every joint carries the translation's energy
    no_rel = finedance_spec(tmp_path, root_relative=False)
    _, kin_abs, _ = Scorer(no_rel, mode="paper", classifier_method="logistic", warnings=WarningLog()).features([joints])
    y_up = joints[..., [0, 2, 1]] * np.array([1, 1, -1])  # z-up -> y-up, as the metrics rotate
    expected = kinetic_features_batch([y_up - y_up[:1, :1]], fps=60, up_axis="y")[0, :66]
    assert np.allclose(kin_abs[0], expected) and np.all(kin_abs[0].reshape(22, 3)[:, 0] > 0)


@pytest.mark.slow
def test_finedance_end_to_end(tmp_path):
    import pygltflib

    from dgsdp.cli.evaluate import evaluate
    from dgsdp.cli.generate import generate
    from dgsdp.cli.train import train
    from dgsdp.data.synthetic_finedance import STANDIN_JOINTS_FILE, generate_synthetic_finedance
    from dgsdp.data.synthetic_music import synthesize_music, wav_bytes

    root = generate_synthetic_finedance(
        tmp_path / "fd", sequences_per_genre=2, min_seconds=3.0, max_seconds=4.0, sample_rate_hz=8000
    )
    cache = tmp_path / "cache"
    checkpoints = {}
    for joints in ("body", "full"):
        cfg = compose_config(
            "train",
            [
                "data=finedance", f"data.root={root}", f"data.smplx_file={root / STANDIN_JOINTS_FILE}",
                f"data.finedance.joints={joints}", "data.window_seconds=2.0", "debug=tiny", "style=onehot",
                "trainer.max_steps=3", f"paths.cache_dir={cache}", "data.progress=false", "logger=csv",
                "callbacks.progress.refresh_rate=0",
            ],
            output_dir=tmp_path / f"run_{joints}",
        )  # fmt: skip
        result = train(cfg)
        assert result["global_step"] == 3
        checkpoints[joints] = result["checkpoint"]

    audio, _ = synthesize_music("BR", 100.0, 30.0, first_beat_s=0.3, sample_rate_hz=8000, rng=np.random.default_rng(0))
    song = tmp_path / "song30.wav"
    song.write_bytes(wav_bytes(audio, 8000))
    out = tmp_path / "gen"
    generate(
        compose_config(
            "generate",
            [
                f"checkpoint={checkpoints['full']}",
                f"music={song}",
                "style=Breaking",
                "formats=[npy,bvh,glb]",
                "sampling.steps=2",
                "device=cpu",
                "progress=false",
                f"output_dir={out}",
                f"paths.output_dir={out}",
                f"paths.cache_dir={cache}",
            ],
        )  # fmt: skip
    )
    motion = np.load(out / "song30.npy")
    assert motion.shape == (900, 7 + 6 * 52)
    bvh = (out / "song30.bvh").read_text()
    assert sum(line.split()[0] in ("ROOT", "JOINT") for line in bvh.splitlines() if line.strip()) == 52
    assert "Frames: 900" in bvh and "right_thumb3" in bvh
    glb = pygltflib.GLTF2().load(str(out / "song30.glb"))
    assert [len(skin.joints) for skin in glb.skins] == [52]

    for joints in ("body", "full"):
        eval_dir = tmp_path / f"eval_{joints}"
        evaluate(
            compose_config(
                "evaluate",
                [
                    f"checkpoint={checkpoints[joints]}",
                    "protocol=finedance",
                    "sampling.steps=2",
                    "device=cpu",
                    "progress=false",
                    f"paths.cache_dir={cache}",
                    "logger=none",
                ],
                output_dir=eval_dir,
            )  # fmt: skip
        )
        results = json.loads((eval_dir / "results.json").read_text())
        rows = {row["name"]: row for row in results["rows"]}
        assert set(rows) == {"generated", "ground_truth"} and rows["generated"]["n_dances"] == 16
        for name in rows:
            for metric in ("BeatAlign", "FID_k", "FID_g", "Div_k", "Div_g"):
                assert np.isfinite(rows[name]["metrics"][metric]["mean"]), (joints, name, metric)
