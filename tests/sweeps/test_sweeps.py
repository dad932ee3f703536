"""Every sweep file launches the expected jobs through Hydra's real sweeper; empty sweeps fail loudly; a 2-row sweep
trains, evaluates and reports (slow)."""

import json
import subprocess
import sys

import pytest

from dgsdp.cli.sweep import SWEEPS_DIR, available_sweeps, launch, sweep_grid
from dgsdp.errors import ConfigError

EXPECTED = {
    "table1": {("edge", s) for s in range(3)} | {("dgsdp", s) for s in range(3)},
    "table2": {("edge", s) for s in range(3)} | {("dgsdp", s) for s in range(3)},
    "table3": {("edge", s) for s in range(3)} | {("dgsdp", s) for s in range(3)},
    "table4": {(f"table4_row{r}", s) for r in range(6) for s in range(3)},
    "table5": {(f"table5_row{r}", s) for r in range(1, 7) for s in range(3)},
    "quickstart": {(f"quickstart_row{r}", s) for r in range(23) for s in range(3)},
}
EVALUATE = {"table1": "table1", "table2": "table2", "table3": "table3", "table4": "table1", "table5": "table1"}
EVALUATE["quickstart"] = "table1"


def test_every_paper_table_has_a_sweep_file():
    assert set(EXPECTED) <= set(available_sweeps())


# Launching composes every job through Hydra (about a second each): the default suite launches the smallest table,
# the slow suite every sweep; the grid test below checks every file's rows and seeds in the default suite.
LAUNCHED_BY_DEFAULT = {"table1"}


@pytest.mark.parametrize("name", sorted(EXPECTED))
def test_every_sweep_file_grids_the_expected_rows_and_seeds(name):
    grid = sweep_grid(SWEEPS_DIR / f"{name}.yaml", [])
    assert set(grid) == {"experiment", "seed"}
    assert {(e, int(s)) for e in grid["experiment"] for s in grid["seed"]} == EXPECTED[name]


@pytest.mark.parametrize(
    "name", [n if n in LAUNCHED_BY_DEFAULT else pytest.param(n, marks=pytest.mark.slow) for n in sorted(EXPECTED)]
)
def test_sweep_launches_the_expected_jobs(tmp_path, name):
    result = launch(name, ["hydra/launcher=basic", f"hydra.sweep.dir={tmp_path}", "debug=tiny"], dry_run=True)
    records = [json.loads((d / "sweep_job.json").read_text()) for d in result["jobs"]]
    assert {(r["experiment"], r["seed"]) for r in records} == EXPECTED[name]
    assert len(records) == len(EXPECTED[name]) == result["expected_jobs"]
    assert all(r["sweep_name"] == name and r["evaluate"] == EVALUATE[name] for r in records)
    assert all(r["run_name"] == r["experiment"] for r in records)  # experiment files name their row
    assert all("debug=tiny" in r["overrides"] for r in records)  # appended overrides reach every job


def test_command_line_grid_overrides_replace_the_files(tmp_path):
    result = launch("table4", ["hydra/launcher=basic", f"hydra.sweep.dir={tmp_path}", "seed=7"], dry_run=True)
    assert result["expected_jobs"] == 6 and len(result["jobs"]) == 6


def test_a_sweep_matching_no_config_fails_loudly(tmp_path):
    (tmp_path / "sweeps").mkdir()
    empty = tmp_path / "sweeps" / "empty.yaml"
    empty.write_text("# @package _global_\nhydra:\n  sweeper:\n    params:\n      experiment: glob(table9_*)\n")
    with pytest.raises(ConfigError, match="matches no config"):
        sweep_grid(empty, [])
    with pytest.raises(ConfigError, match="matches no config"):
        launch(str(empty), ["hydra/launcher=basic", f"hydra.sweep.dir={tmp_path / 'out'}"], dry_run=True)
    assert not (tmp_path / "out").exists()
    with pytest.raises(ConfigError, match="not found"):
        sweep_grid(SWEEPS_DIR / "table1.yaml", ["experiment=edge,table9_row1"])
    with pytest.raises(ConfigError, match="no sweep"):
        launch("table9", [], dry_run=True)


def test_cli_exits_non_zero_for_an_empty_sweep(tmp_path, repo_root):
    (tmp_path / "sweeps").mkdir()
    empty = tmp_path / "sweeps" / "empty.yaml"
    empty.write_text("hydra:\n  sweeper:\n    params:\n      experiment: glob(nothing_*)\n")
    proc = subprocess.run(
        [sys.executable, "-m", "dgsdp.sweep", str(empty), "--dry-run"], cwd=tmp_path, capture_output=True, text=True,
        env={"PYTHONPATH": str(repo_root), "PATH": "/usr/bin:/bin", "HF_HUB_OFFLINE": "1", "WANDB_MODE": "offline"},
    )  # fmt: skip
    assert proc.returncode != 0 and "matches no config" in proc.stderr


@pytest.mark.slow
def test_two_row_sweep_trains_evaluates_and_reports(tmp_path):
    """Real launch (joblib, 2 in parallel) from another working directory; the report has both rows."""
    from dgsdp.data.synthetic import generate_synthetic_aistpp
    from dgsdp.report import write_report

    root = generate_synthetic_aistpp(tmp_path / "data", sequences_per_genre=2, seconds=7.0, num_ignored=0)
    (tmp_path / "sweeps").mkdir()
    sweep = tmp_path / "sweeps" / "two.yaml"
    sweep.write_text(
        "# @package _global_\nsweep_name: two\nevaluate: table1\n"
        "hydra:\n  sweeper:\n    params:\n      style: none,onehot\n"
    )
    out = tmp_path / "multirun"
    result = launch(str(sweep), [
        f"hydra.sweep.dir={out}", "debug=tiny", f"data.root={root}", "data.synthetic=null",
        f"paths.cache_dir={tmp_path / 'cache'}", "data.progress=false", "trainer.limit_val_batches=0",
        "callbacks.progress.refresh_rate=0", "audio=librosa",
        'evaluate_overrides=["sampling.steps=2","protocol.trials=1","progress=false","protocol.guidance_weights=[2.0]"]',
    ], jobs=2)  # fmt: skip
    assert len(result["jobs"]) == 2
    written = write_report([out], tmp_path / "report", wandb="off")
    (table,) = written["tables"]
    keys = [r.key for r in table.rows]
    assert "librosa-none-modulation, w=2" in keys and "librosa-onehot-modulation, w=2" in keys
    md = written["markdown"].read_text()
    assert "librosa-none-modulation, w=2" in md and "librosa-onehot-modulation, w=2" in md
    assert written["plots"][0].stat().st_size > 0
