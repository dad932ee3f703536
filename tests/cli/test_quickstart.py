"""The quick start end to end on a tiny model: stage progress, two dances with the default sampler, the hint."""

import pytest

from dgsdp import quickstart


@pytest.mark.slow
def test_quickstart_runs_end_to_end_and_prints_its_stages(tmp_path, monkeypatch, capsys):
    monkeypatch.setenv("DGSDP_HOME", str(tmp_path))
    monkeypatch.chdir(tmp_path)
    code = quickstart.main(["debug=tiny", "trainer.max_steps=2", "logger=none"])
    out = capsys.readouterr().out
    assert code == 0, out
    assert "[1/2] training the small model for 2 steps" in out and "[1/2] trained in" in out
    assert "[2/2] danced in" in out and "total:" in out
    assert "sampling.guidance.music=<w>" in out  # the hint explains guidance
    assert f"dgsdp-train experiment={quickstart.QUICKSTART_EXPERIMENT} distill.teacher=" in out  # a faster student
    dances = sorted(p.relative_to(tmp_path) for p in tmp_path.glob("outputs/quickstart/*/dances/*/*.npy"))
    assert [p.parent.name for p in dances] == ["free_text", "genre"]


def test_quickstart_trains_row_20_unless_an_experiment_is_named():
    assert quickstart.training_overrides(["seed=1"]) == ["experiment=quickstart_row20", "seed=1"]
    assert quickstart.training_experiment(["seed=1"]) == "quickstart_row20"
    ours = ["experiment=quickstart_row21", "seed=2"]
    assert quickstart.training_overrides(ours) == ours  # one experiment, never two
    assert quickstart.training_experiment(ours) == quickstart.STYLE_EXPERIMENT == "quickstart_row21"
