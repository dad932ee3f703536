"""Evaluation protocols on a tiny trained checkpoint: finite results, the ground-truth row recomputed
independently with the metric functions, long-form, masking and Bailando protocols, defined values for n/a."""

import json
import math
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch
from conftest import compose_eval

from dgsdp.cli.config import compose_config
from dgsdp.cli.evaluate import evaluate
from dgsdp.data.datamodule import load_sequences
from dgsdp.errors import ConfigError, DataError
from dgsdp.evaluation import (
    Evaluator,
    ProtocolSpec,
    Variant,
    WarningLog,
    results_markdown,
    sample_clips,
    summarise,
    upsample_joints,
)
from dgsdp.generation import DanceGenerator
from dgsdp.metrics import (
    GenreClassifier,
    MetricError,
    beat_alignment,
    diversity,
    geometric_features,
    kinetic_features,
    pfc,
)
from dgsdp.motion import pose_to_joints
from dgsdp.sampling import SamplingSettings
from dgsdp.trained import load_model

METRIC_NAMES = ["BeatAlign", "PFC", "FID_k", "FID_g", "Div_k", "Div_g", "StyleAcc"]


def evaluator(run, protocol: dict) -> Evaluator:
    generator = DanceGenerator(load_model(run["checkpoint"]), cache_dir=run["cache"])
    spec = ProtocolSpec.from_config(protocol)
    return Evaluator(generator, spec, data_root=run["root"], cache_dir=run["cache"], progress=False)


def tmp_copy_without_manifest(root) -> Path:
    """A copy of a synthetic dataset's folder without its synthetic.json (as real AIST++ has none): links to its
    files, in a new folder beside it."""
    src = Path(root)
    dst = src.parent / (src.name + "-no-manifest")
    if not dst.exists():
        dst.mkdir()
        for item in src.iterdir():
            if item.name != "synthetic.json":
                (dst / item.name).symlink_to(item.resolve())
    return dst


def rows_by_name(results):
    return {r["name"]: r for r in results["rows"]}


def test_upsample_is_linear_and_keeps_frames():
    joints = np.zeros((3, 24, 3))
    joints[:, 5, 1] = [0.0, 2.0, 6.0]
    up = upsample_joints(joints)
    assert up.shape == (5, 24, 3)
    np.testing.assert_allclose(up[:, 5, 1], [0.0, 1.0, 2.0, 4.0, 6.0])


@pytest.mark.parametrize(
    ("protocol", "names"),
    [
        ("table1", ["w=2", "w=1"]),
        ("table2", ["7.5s", "10s"]),
        ("table3", ["seed_motion", "inbetween", "inpaint", "upper_body", "lower_body"]),
        ("bailando", ["generated"]),
    ],
)
def test_protocol_configs_give_the_paper_rows(tmp_path, protocol, names):
    cfg = compose_config("evaluate", [f"protocol={protocol}"], output_dir=tmp_path)
    from omegaconf import OmegaConf

    spec = ProtocolSpec.from_config(OmegaConf.to_container(cfg.protocol, resolve=True))
    assert [v.name for v in spec.variants()] == names
    assert spec.name == protocol


def test_protocol_rejects_unknown_settings_and_tasks():
    with pytest.raises(ConfigError, match="unknown protocol setting"):
        ProtocolSpec.from_config({"name": "x", "trails": 3})
    with pytest.raises(ConfigError, match="unknown editing task"):
        ProtocolSpec.from_config({"name": "x", "tasks": ["teleport"]})


def test_undefined_metric_is_none_with_a_warning_and_na_in_markdown():
    log = WarningLog()

    def broken():
        raise MetricError("too few dances")

    assert log.guard("w=2", "FID_k", broken) is None
    assert log.guard("w=2", "PFC", lambda: float("nan")) is None
    assert [w["metric"] for w in log.items] == ["FID_k", "PFC"]
    summary = summarise([None, None])
    assert summary["mean"] is None and summary["n"] == 0
    row = {"name": "w=2", "trials": 2, "metrics": {m: summary for m in METRIC_NAMES}}
    md = results_markdown({"protocol": "table1", "rows": [row], "warnings": log.items})
    table = md.split("Warnings")[0]
    assert "| w=2 | n/a | n/a |" in table and "nan" not in table.lower()
    assert "non-finite value nan; reported as n/a" in md


def test_summarise_mean_and_sample_std():
    s = summarise([1.0, 2.0, None, 4.0])
    assert s["mean"] == pytest.approx(7 / 3)
    assert s["std"] == pytest.approx(np.std([1.0, 2.0, 4.0], ddof=1))
    assert s["n"] == 3


def test_table1_after_training_writes_finite_json_markdown_and_csv(trained_run):
    path = trained_run["evaluation"]["table1"]
    results = json.loads(open(path).read())
    rows = rows_by_name(results)
    assert set(rows) == {"w=2", "w=1", "ground_truth"}
    for name in ("w=2", "w=1"):
        assert rows[name]["trials"] == 2 and rows[name]["n_dances"] == 10
        for metric in METRIC_NAMES:
            summary = rows[name]["metrics"][metric]
            assert summary["n"] == 2 and math.isfinite(summary["mean"]) and math.isfinite(summary["std"])
    assert rows["ground_truth"]["metrics"]["FID_k"]["mean"] is None  # the reference set itself: n/a, not 0
    assert results["run"]["seed"] == 0 and results["protocol"] == "table1"
    md = (trained_run["dir"] / "evaluation" / "table1" / "results.md").read_text()
    assert "| w=2 |" in md and "| ground_truth |" in md and "nan" not in md.lower()
    csv_text = (trained_run["dir"] / "evaluation" / "table1" / "csv" / "metrics.csv").read_text()
    assert "eval/table1/w=2/FID_k" in csv_text


def _independent_features(joints_z_up_30):
    """Upsample to 60 FPS by averaging neighbours, rotate to y-up, anchor the root: written apart from the code."""
    t = len(joints_z_up_30)
    up = np.empty((2 * t - 1, 24, 3))
    up[0::2] = joints_z_up_30
    up[1::2] = 0.5 * (joints_z_up_30[:-1] + joints_z_up_30[1:])
    y_up = np.stack([up[..., 0], up[..., 2], -up[..., 1]], axis=-1)
    return y_up - y_up[0, 0]


def test_ground_truth_row_matches_an_independent_computation(trained_run):
    results = json.loads(open(trained_run["evaluation"]["table1"]).read())
    gt = rows_by_name(results)["ground_truth"]["metrics"]
    cache = trained_run["cache"]
    test = load_sequences(trained_run["root"], "test", cache_dir=cache, progress=False)
    train = load_sequences(trained_run["root"], "train", cache_dir=cache, progress=False)

    def clips(seqs):  # 5 s clips, 2.5 s stride: the 7 s dances give one clip each, starting at frame 0
        return [s.motion[:150] for s in seqs if len(s.motion) >= 150]

    joints = [pose_to_joints(torch.from_numpy(m).double()).numpy() for m in clips(test)]
    prepared = [_independent_features(j) for j in joints]
    kin = np.stack([kinetic_features(p, fps=60) for p in prepared])
    geo = np.stack([geometric_features(p, fps=60) for p in prepared])
    manifest = json.loads((Path(trained_run["root"]) / "synthetic.json").read_text())
    ba = []
    for seq, p in zip(test, prepared):  # BeatAlign against the songs' known beats, not a tracker's
        song = manifest["music"][seq.music_id]
        times = song["first_beat_s"] + np.arange(0, 7.0 * song["bpm"] / 60.0) * 60.0 / song["bpm"]
        beats = np.unique(np.round(times[times < 7.0] * 30).astype(int))
        ba.append(beat_alignment(p, 2 * beats[beats < 150], fps=60))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        expected = {
            "BeatAlign": np.mean(ba),
            "PFC": np.mean([pfc(j, fps=30, up_axis="z") for j in joints]),
            "Div_k": diversity(kin, kin),
            "Div_g": diversity(geo, geo),
        }
        train_joints = [pose_to_joints(torch.from_numpy(m).double()).numpy() for m in clips(train)]
        train_prep = [_independent_features(j) for j in train_joints]
        train_x = np.hstack([
            np.stack([kinetic_features(p, fps=60) for p in train_prep]),
            np.stack([geometric_features(p, fps=60) for p in train_prep]),
        ])  # fmt: skip
        clf = GenreClassifier().fit(train_x, [s.genre_index for s in train])
        expected["StyleAcc"] = clf.accuracy(np.hstack([kin, geo]), [s.genre_index for s in test])
    for metric, value in expected.items():
        assert gt[metric]["mean"] == pytest.approx(value, rel=1e-6, abs=1e-9), metric
    assert expected["BeatAlign"] > 0.1  # the synthetic dances move on the beat: a score that can fail
    assert results["beats"] == "the synthetic songs' known beats (synthetic.json)"
    md = (trained_run["dir"] / "evaluation" / "table1" / "results.md").read_text()
    assert "BeatAlign scored against: the synthetic songs' known beats (synthetic.json)" in md


def test_beat_align_scores_against_the_known_beats(trained_run):
    """A dance that moves on a synthetic song's known beats scores higher against them than the same dance shifted
    by half a beat; the clips carry those beats apart from the tracker's, and a dataset without synthetic.json
    (real AIST++) scores against the tracker's and says so."""
    from dgsdp.evaluation import ClipSource

    spec = ProtocolSpec.from_config({"name": "t", "lengths_seconds": [5], "splits": ["test"]})
    source = ClipSource(spec, data_root=trained_run["root"], cache_dir=trained_run["cache"], audio_encoder=None,
                        seed=0, warnings=WarningLog(), progress=False)  # fmt: skip
    clips = source.clips(source.load_split("test", with_music=False), 5.0)
    higher = 0
    for clip in clips:
        known = clip.known_beats_30fps
        assert known is not None and np.array_equal(clip.scoring_beats_30fps, known)
        period = 30 * 60.0 / source._manifest["music"][clip.seq.music_id]["bpm"]
        assert np.allclose(np.diff(known), period, atol=1.0)  # one beat per period, to the nearest frame
        joints = pose_to_joints(torch.from_numpy(clip.motion).double()).numpy()
        half = int(round(period / 2))
        shifted = np.concatenate([np.repeat(joints[:1], half, axis=0), joints[:-half]])  # half a beat later
        on = beat_alignment(upsample_joints(joints), 2 * known, fps=60)
        off = beat_alignment(upsample_joints(shifted), 2 * known, fps=60)
        higher += on > off
    assert higher == len(clips)
    assert "known beats" in source.beat_source
    real = tmp_copy_without_manifest(trained_run["root"])
    other = ClipSource(spec, data_root=real, cache_dir=trained_run["cache"], audio_encoder=None, seed=0,
                       warnings=WarningLog(), progress=False)  # fmt: skip
    assert other.known_beats(clips[0].seq) is None and "librosa's beat tracker" in other.beat_source


def test_longform_and_masking_protocols(trained_run, tmp_path):
    # The 7 s synthetic dances fit 6 s long-form clips (two 5 s windows with a 2.5 s stride).
    cfg = compose_eval(trained_run, tmp_path / "t2", "protocol=table2", "protocol.lengths_seconds=[6.0]",
                       "protocol.trials=1", "protocol.max_dances=4")  # fmt: skip
    rows = rows_by_name(evaluate(cfg)["results"])
    assert set(rows) == {"6s", "ground_truth, 6s"}
    assert all(math.isfinite(rows["6s"]["metrics"][m]["mean"]) for m in METRIC_NAMES)
    assert (tmp_path / "t2" / "results.md").is_file()

    cfg = compose_eval(trained_run, tmp_path / "t3", "protocol=table3", "protocol.trials=1", "protocol.max_dances=4")
    rows = rows_by_name(evaluate(cfg)["results"])
    assert set(rows) == {"seed_motion", "inbetween", "inpaint", "upper_body", "lower_body", "ground_truth"}
    for task in ("seed_motion", "upper_body"):
        assert all(math.isfinite(rows[task]["metrics"][m]["mean"]) for m in ("BeatAlign", "PFC", "Div_k", "FID_g"))


def test_masked_rows_keep_the_given_motion(trained_run):
    ev = evaluator(trained_run, {"name": "t", "tasks": ["seed_motion"], "seed_frames": 20})
    clips = ev.source.clips(ev.source.load_split("test"), 5.0)[:2]
    variant = Variant(5.0, 2.0, "seed_motion", "seed_motion")
    joints = sample_clips(ev.generator, clips, variant, ev.spec, SamplingSettings(steps=2), seed=0, trial=0)
    for clip, j in zip(clips, joints):
        real = pose_to_joints(torch.from_numpy(clip.motion).double()).numpy()
        np.testing.assert_allclose(j[:20], real[:20], atol=1e-4)
        assert np.abs(j[40:] - real[40:]).max() > 1e-2  # the rest is generated


def test_evaluation_scores_the_raw_model_unless_cleanup_is_on(trained_run):
    ev = evaluator(trained_run, {"name": "t", "tasks": ["seed_motion"], "seed_frames": 20})
    clips = ev.source.clips(ev.source.load_split("test"), 5.0)[:2]
    variant = Variant(5.0, 2.0, "seed_motion", "seed_motion")
    settings = SamplingSettings(steps=2)
    raw = sample_clips(ev.generator, clips, variant, ev.spec, settings, seed=0, trial=0)
    assert not ev.cleanup
    cleaned = sample_clips(ev.generator, clips, variant, ev.spec, settings, seed=0, trial=0, cleanup=True)
    floor = ev.generator.floor_height
    for clip, r, c in zip(clips, raw, cleaned):
        real = pose_to_joints(torch.from_numpy(clip.motion).double()).numpy()
        np.testing.assert_allclose(c[:20], real[:20], atol=1e-4)  # the given frames stay given
        assert c[40:, :, 2].min() >= floor - 0.01  # past the blend from the given frames: nothing below the floor
        assert np.abs(c - r).max() > 0 or r[40:, :, 2].min() >= floor - 0.01


def test_finished_dances_say_whether_the_judge_saw_the_scored_beats(trained_run):
    """cleanup=true retimes each dance onto its clip's (librosa's) beats and judges the retime on those beats: on a
    dataset without known beats (real AIST++) BeatAlign is scored against the same beats, and the results say so;
    against a synthetic dataset's known beats, the judge did not see them. The raw model's results say nothing."""
    protocol = {"name": "t", "lengths_seconds": [5.0], "splits": ["test"], "trials": 1, "max_dances": 4}
    generator = DanceGenerator(load_model(trained_run["checkpoint"]), cache_dir=trained_run["cache"])
    spec = ProtocolSpec.from_config(protocol)
    settings = SamplingSettings(steps=2)
    for root, saw in ((tmp_copy_without_manifest(trained_run["root"]), True), (trained_run["root"], False)):
        ev = Evaluator(generator, spec, data_root=root, cache_dir=trained_run["cache"], sampling=settings,
                       progress=False, cleanup=True)  # fmt: skip
        results = ev.run()
        finishing = results["finishing"]
        assert finishing["cleanup"] and finishing["judge_saw_scoring_beats"] is saw
        text = finishing["description"]
        assert "a judge on those same beats" in text
        assert ("not an independent check" in text) is saw
        assert ("neither the retime nor its judge saw" in text) is not saw
        assert f"Finishing: {text}" in results_markdown(results)
    assert "no row is retimed" in ev.finishing(retimed=False, judged_scoring_beats=False)["description"]
    raw = Evaluator(generator, spec, data_root=trained_run["root"], cache_dir=trained_run["cache"], sampling=settings,
                    progress=False).run()  # fmt: skip
    assert raw["finishing"] is None and "Finishing:" not in results_markdown(raw)


def test_subsets_cover_every_genre(trained_run):
    ev = evaluator(trained_run, {"name": "t", "clips_per_trial": 10})
    clips = ev.source.clips(
        ev.source.load_split("test", with_music=False), 2.0
    )  # 7 s dances, 2 s clips every 2.5 s: 3 per dance
    assert len(clips) == 30
    for trial in range(3):
        idx = ev.source.subset(clips, trial)
        assert len(idx) == 10 and len({clips[i].seq.genre_index for i in idx}) == 10
    assert ev.source.subset(clips, 0) != ev.source.subset(clips, 1)


def test_bailando_protocol_uses_the_dataset_pool_and_skips_missing_splits(trained_run, tmp_path):
    cfg = compose_eval(trained_run, tmp_path / "b", "protocol=bailando")
    results = evaluate(cfg)["results"]
    rows = rows_by_name(results)
    assert set(rows) == {"generated", "ground_truth"}
    assert rows["ground_truth"]["n_dances"] == 10  # the synthetic set has no val split: the 10 test dances
    assert math.isfinite(rows["ground_truth"]["metrics"]["FID_k"]["mean"])  # real test dances vs the whole pool
    assert any("'val' skipped" in w["message"] for w in results["warnings"])


def test_clear_errors(trained_run, tmp_path):
    with pytest.raises(ConfigError, match="checkpoint="):
        evaluate(compose_config("evaluate", ["progress=false"], output_dir=tmp_path))
    cfg = compose_eval(trained_run, tmp_path / "x", "protocol=table2", "protocol.trials=1")
    with pytest.raises(DataError, match="lengths_seconds"):
        evaluate(cfg)  # 7.5 s and 10 s clips do not fit the 7 s dances


def test_protocols_and_sweeps_sample_as_the_papers_and_say_so(tmp_path):
    from omegaconf import OmegaConf

    from dgsdp.evaluation.results import results_markdown
    from dgsdp.resources import SWEEPS_DIR

    papers = compose_config("evaluate", [], output_dir=tmp_path).sampling
    assert (papers.method, papers.steps, papers.eta, papers.clip_x0, papers.longform) == ("ddim", 50, 1.0, 1.0, "edge")
    assert papers.guidance.music == 2.0
    fast = compose_config("evaluate", ["sampling=dpmpp_2m"], output_dir=tmp_path).sampling
    assert (fast.method, fast.steps, fast.longform, fast.clip_x0) == ("dpmpp_2m", 10, "fuse", None)
    assert (papers.project_rotations, fast.project_rotations) == ("none", "root")
    fast_line = results_markdown({"protocol": "table1", "rows": [], "metrics": [],
                                  "settings": {"sampling": OmegaConf.to_container(fast)}})  # fmt: skip
    assert "Sampling: dpmpp_2m, 10 steps, long-form fuse, x0 clip of the run, root rotations projected\n" in fast_line
    for sweep in sorted(SWEEPS_DIR.glob("table*.yaml")):
        assert OmegaConf.load(sweep).evaluate_overrides[0] == "sampling=edge", sweep.name
    results = {"protocol": "table1", "rows": [], "metrics": [],
               "settings": {"sampling": OmegaConf.to_container(papers)}}  # fmt: skip
    assert "Sampling: ddim, 50 steps, eta 1, long-form edge, x0 clip 1 (the papers' sampling" in results_markdown(
        results
    )
    assert "student" not in results_markdown(results)
    student = results_markdown({**results, "run": {"guidance_student": True}})
    assert "sampling=edge); a guidance-distilled student, one pass per step" in student


def test_beat_align_of_a_model_fed_the_independent_tracker(eval_data):
    """A model fed the independent tracker's beats (``audio.beat_tracker=flux``) is scored against librosa's
    tracker, which it was not fed, and the results say so: the clips' beats are librosa's beats of the song, not
    the beat column of the model's own features (here a made-up column, every 7th frame)."""
    import dataclasses

    from dgsdp.audio import FeatureCache, LibrosaEncoder
    from dgsdp.evaluation import ClipSource
    from dgsdp.metrics import music_beats_from_features

    real = tmp_copy_without_manifest(eval_data["root"])
    spec = ProtocolSpec.from_config({"name": "t", "lengths_seconds": [5], "splits": ["test"]})
    librosa = LibrosaEncoder()
    for fed, encoder in (("flux", LibrosaEncoder(beat_tracker="flux")), ("librosa", librosa)):
        source = ClipSource(spec, data_root=real, cache_dir=eval_data["cache"], audio_encoder=encoder, seed=0,
                            warnings=WarningLog(), progress=False)  # fmt: skip
        seq = source.load_split("test", with_music=False)[0]
        made_up = np.zeros((len(seq.motion), 35), np.float32)
        made_up[::7, 34] = 1.0
        seq = dataclasses.replace(seq, audio=made_up)
        beats = source.music_beats(seq)
        if fed == "flux":
            feats = FeatureCache(eval_data["cache"]).features_for_file(librosa, source.music_file(seq),
                                                                       music_id=seq.music_id)  # fmt: skip
            expected = music_beats_from_features(feats)
            assert np.array_equal(beats, expected) and not np.array_equal(beats, np.arange(0, len(made_up), 7))
            assert "fed the 'flux' tracker's beats" in source.beat_source
            assert source.beat_source.startswith("librosa's beat tracker")
        else:  # the model's own column holds librosa's beats: it is read, not recomputed
            assert np.array_equal(beats, np.arange(0, len(made_up), 7))
            assert "fed the" not in source.beat_source
