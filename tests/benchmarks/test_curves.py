"""Steps to quality (python -m dgsdp.benchmarks.curves): runs and their step checkpoints found, each scored, the
curves' means and bands worked out by hand, and the command end to end on a tiny run that saved checkpoints along
the way and records its training time in them."""

from __future__ import annotations

import json
import math
import os

import pytest
import torch

from dgsdp.benchmarks import curves as cv
from dgsdp.errors import ConfigError


def _fake_run(folder, steps, seconds_per_step=None):
    (folder / "checkpoints").mkdir(parents=True)
    for step in steps:
        record = {"global_step": step}
        if seconds_per_step is not None:
            record["train_seconds"] = step * seconds_per_step
        torch.save(record, folder / "checkpoints" / f"step{step:07d}.ckpt")
    torch.save({"global_step": steps[-1]}, folder / "checkpoints" / "last.ckpt")
    return folder


def test_runs_and_their_step_checkpoints(tmp_path):
    a = _fake_run(tmp_path / "a", [400, 200, 1000], seconds_per_step=0.3)
    b = _fake_run(tmp_path / "b", [200], seconds_per_step=None)
    assert cv.parse_runs([f"row9={a},{b}", f"row13={a}"]) == {"row9": [a, b], "row13": [a]}
    found = cv.run_checkpoints(a)
    assert [c.step for c in found] == [200, 400, 1000]  # by step, last.ckpt left out
    assert [c.seconds for c in found] == pytest.approx([60.0, 120.0, 300.0])
    assert cv.run_checkpoints(b)[0].seconds is None  # a run from before train_seconds: steps only
    for bad, fragment in ((["row9"], "NAME=RUN_FOLDER"), ([f"={a}"], "NAME=RUN_FOLDER"),
                          ([f"x={tmp_path / 'nope'}"], "no such run folder")):  # fmt: skip
        with pytest.raises(ConfigError, match=fragment):
            cv.parse_runs(bad)
    (tmp_path / "empty" / "checkpoints").mkdir(parents=True)
    with pytest.raises(ConfigError, match="save_top_k=-1"):
        cv.run_checkpoints(tmp_path / "empty")


def test_style_figures_take_the_raw_model_and_the_worst_list():
    result = {"raw": {"genre_acc": 0.5, "modifiers_right": 0.75, "speed_spearman": -0.2, "text_acc": 0.4,
                      "text_by_list": {"aistpp": {"text_acc": 0.4}, "aistpp_third": {"text_acc": 0.1}}},
              "finished": {"genre_acc": 0.99}}  # fmt: skip
    figures = cv.style_figures(result)
    assert figures == {"genre_acc": 0.5, "modifiers_right": 0.75, "speed_spearman": -0.2, "text_acc/aistpp": 0.4,
                       "text_acc/aistpp_third": 0.1, "text_acc_min": 0.1}  # fmt: skip


def _points():
    """Two recipes; row9 has two runs (a third point lacks the figure), row13 one run without recorded time."""

    def point(recipe, seed, step, minutes, acc):
        return {"recipe": recipe, "seed_index": seed, "step": step, "minutes": minutes,
                "figures": {"genre_acc": acc}}  # fmt: skip

    return [point("row9", 0, 250, 1.0, 0.2), point("row9", 1, 250, 2.0, 0.4), point("row9", 0, 500, 3.0, 0.6),
            point("row9", 1, 500, 5.0, math.nan), point("row13", 0, 250, None, 0.9)]  # fmt: skip


def test_curves_mean_and_band_over_runs_by_hand():
    by_step = cv.curves(_points(), "genre_acc", "step")
    assert by_step["row9"]["x"].tolist() == [250, 500]
    assert by_step["row9"]["mean"] == pytest.approx([0.3, 0.6])
    assert by_step["row9"]["low"] == pytest.approx([0.2, 0.6]) and by_step["row9"]["high"] == pytest.approx([0.4, 0.6])
    assert by_step["row9"]["runs"].tolist() == [2, 1]
    by_minutes = cv.curves(_points(), "genre_acc", "minutes")
    assert by_minutes["row9"]["x"] == pytest.approx([1.5, 3.0])  # the runs' mean minutes at each step
    assert "row13" not in by_minutes and by_step["row13"]["mean"].tolist() == [0.9]
    assert cv.curves(_points(), "FID_k", "step") == {}


def test_measure_scores_every_checkpoint_and_the_png(tmp_path):
    a = _fake_run(tmp_path / "a", [2, 4], seconds_per_step=30.0)
    scored = []

    def score(path):
        scored.append(path.name)
        return {"genre_acc": int(path.stem[4:]) / 10, "FID_k": 5.0}

    points = cv.measure({"tiny": [a]}, score, progress=lambda line: None)
    assert scored == ["step0000002.ckpt", "step0000004.ckpt"]
    assert [(p["step"], p["minutes"], p["figures"]["genre_acc"]) for p in points] == [(2, 1.0, 0.2), (4, 2.0, 0.4)]
    png = tmp_path / "c.png"
    assert cv.save_png(points, png) == ["genre_acc", "FID_k"]
    assert png.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and png.stat().st_size > 5000
    with pytest.raises(ConfigError, match="no figure"):
        cv.save_png([{**points[0], "figures": {"genre_acc": math.nan}}], png)


@pytest.mark.timeout(600)
def test_curves_end_to_end_on_a_tiny_run(tmp_path, monkeypatch, capsys):
    """A tiny run saving a checkpoint every 2 steps records its training time in each; the command scores both
    checkpoints with the style benchmark (2 clips, one held-out list), writes the JSON and the PNG, and logs them to
    an offline wandb run."""
    from dgsdp.cli.config import compose_config
    from dgsdp.cli.train import train
    from dgsdp.data.synthetic import generate_synthetic_aistpp

    root = generate_synthetic_aistpp(tmp_path / "data", seed=0, sequences_per_genre=2, seconds=7.0, num_ignored=0)
    overrides = [
        "debug=tiny", f"data.root={root}", "data.synthetic=null", f"paths.cache_dir={tmp_path / 'cache'}",
        "data.progress=false", "logger=none", "~callbacks.progress", "style=prompt", "trainer.max_steps=4",
        "trainer.limit_val_batches=0", "callbacks.model_checkpoint.save_top_k=-1",
        "callbacks.model_checkpoint.every_n_train_steps=2",
    ]  # fmt: skip
    train(compose_config("train", overrides, output_dir=tmp_path / "run"))
    found = cv.run_checkpoints(tmp_path / "run")
    assert [c.step for c in found] == [2, 4]
    assert 0 < found[0].seconds < found[1].seconds < 600
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_DIR", str(tmp_path / "wandb"))
    (tmp_path / "wandb").mkdir()
    png = tmp_path / "out" / "curves.png"
    code = cv.main([
        "--run", f"tiny={tmp_path / 'run'}", "--max-clips", "2", "--heldout", "aistpp", "--data-root", str(root),
        "--png", str(png), "--wandb", "dgsdp-test", "device=cpu", "sampling.steps=2",
        f"paths.cache_dir={tmp_path / 'cache'}",
    ])  # fmt: skip
    assert code == 0, capsys.readouterr().err
    points = json.loads(png.with_suffix(".json").read_text())
    assert [p["step"] for p in points] == [2, 4]
    for p in points:
        figures = p["figures"]
        assert 0.0 <= figures["genre_acc"] <= 1.0 and figures["genre_acc"] * 2 == round(figures["genre_acc"] * 2)
        assert figures["text_acc_min"] == figures["text_acc/aistpp"]
        assert 0 < p["minutes"] < 10
    assert png.stat().st_size > 5000
    assert any((tmp_path / "wandb").rglob("*.wandb")), os.listdir(tmp_path / "wandb")
    assert "curves of genre_acc" in capsys.readouterr().out


def test_the_command_refuses_a_run_without_step_checkpoints(tmp_path, capsys):
    (tmp_path / "run" / "checkpoints").mkdir(parents=True)
    assert cv.main(["--run", f"x={tmp_path / 'run'}", "--png", str(tmp_path / "c.png")]) == 2
    assert "save_top_k=-1" in capsys.readouterr().err and not (tmp_path / "c.png").exists()


def test_the_default_lists_are_the_shipped_held_out_lists():
    from dgsdp.benchmarks.style import HELDOUT_DIR

    assert [f.stem for f in sorted(HELDOUT_DIR.glob("aistpp*.yaml"))] == list(cv.SHIPPED_LISTS)
