"""The report on fake run folders: table layout, means and stds over seeds worked by hand, paper numbers, files."""

import csv
import json

import pytest

from dgsdp.errors import DataError
from dgsdp.report import build_tables, find_results, write_report
from dgsdp.report.__main__ import main as report_main

METRICS = ["BeatAlign", "PFC", "FID_k", "FID_g", "Div_k", "Div_g", "StyleAcc"]


def fake_run(folder, run_name, seed, values, sweep="table4", gt_div_k=9.0):
    """A results.json with one generated row 'w=2' whose metric means are ``values`` and a ground-truth row."""

    def summary(v):
        return {"mean": v, "std": 0.0 if v is not None else None, "n": 1 if v is not None else 0, "values": [v]}

    rows = [
        {"name": "w=2", "kind": "generated", "trials": 1, "metrics": {m: summary(values.get(m)) for m in METRICS}},
        {"name": "ground_truth", "kind": "ground_truth", "trials": 1,
         "metrics": {m: summary(gt_div_k if m == "Div_k" else None) for m in METRICS}},
    ]  # fmt: skip
    results = {
        "protocol": "table1", "metrics": METRICS, "rows": rows, "warnings": [], "loggers": ["CSVLogger"],
        "run": {"run_name": run_name, "seed": seed, "sweep_name": sweep},
    }  # fmt: skip
    path = folder / "evaluation" / "table1" / "results.json"
    path.parent.mkdir(parents=True)
    path.write_text(json.dumps(results))
    return path


@pytest.fixture
def sweep_dir(tmp_path):
    d = tmp_path / "sweep"
    fake_run(d / "0", "table4_row0", 0, {"BeatAlign": 0.30, "FID_k": 30.0, "Div_k": 6.0, "StyleAcc": 0.5})
    fake_run(d / "1", "table4_row0", 1, {"BeatAlign": 0.34, "FID_k": 34.0, "Div_k": 7.0, "StyleAcc": 0.7})
    fake_run(d / "2", "table4_row0", 2, {"BeatAlign": 0.32, "FID_k": 38.0, "Div_k": 8.0, "StyleAcc": 0.6})
    fake_run(d / "3", "table4_row1", 0, {"BeatAlign": 0.20, "FID_k": 50.0, "Div_k": 4.0}, gt_div_k=11.0)
    return d


def test_table_means_and_stds_over_seeds(sweep_dir):
    (table,) = build_tables(find_results([sweep_dir]))
    assert table.table_id == "table4"
    rows = {r.key: r for r in table.rows}
    row0 = rows["table4_row0, w=2"]
    assert row0.stat("FID_k") == pytest.approx((34.0, 4.0, 3))  # mean of 30, 34, 38; sample std 4
    assert row0.stat("BeatAlign") == pytest.approx((0.32, 0.02, 3))
    assert row0.stat("Div_k") == pytest.approx((7.0, 1.0, 3))
    assert row0.stat("PFC") == (None, None, 0)
    assert rows["table4_row1, w=2"].stat("FID_k") == (50.0, 0.0, 1)
    assert rows["ground_truth"].stat("Div_k")[0] == pytest.approx(9.5)  # (9 + 9 + 9 + 11) / 4
    assert row0.paper["FID_k"] == 34.32 and rows["table4_row1, w=2"].paper["Div_k"] == 4.41
    keys = [r.key for r in table.rows]
    assert keys[:6] == [f"table4_row{i}, w=2" for i in range(6)]  # the paper's order, then ours
    assert keys[-1] == "ground_truth"
    assert "StyleAcc" in table.metrics


def test_report_files_markdown_csv_and_plot(sweep_dir, tmp_path):
    written = write_report([sweep_dir], tmp_path / "out", wandb="off")
    md = written["markdown"].read_text()
    assert "| table4_row0, w=2 | 3 | 0.3200 ± 0.0200 | 0.3100 |" in md
    assert "34.00 ± 4.00 | 34.32 |" in md
    assert "| table4_row2, w=2 | 0 | - | 0.2900 |" in md  # a paper row we did not run
    rows = list(csv.DictReader(written["csv"].open()))
    fid = next(r for r in rows if r["row"] == "table4_row0, w=2" and r["metric"] == "FID_k")
    assert float(fid["mean"]) == 34.0 and float(fid["std"]) == 4.0 and fid["n_seeds"] == "3"
    assert float(fid["paper"]) == 34.32
    png = written["plots"][0]
    assert png.name == "table4.png" and png.read_bytes()[:4] == b"\x89PNG"


def test_cli_and_errors(sweep_dir, tmp_path, capsys):
    report_main([str(sweep_dir), "--no-plots", "--wandb", "off"])
    assert (sweep_dir / "report" / "report.md").is_file()
    assert "table4_row0, w=2" in capsys.readouterr().out
    (tmp_path / "empty").mkdir()
    with pytest.raises(DataError, match="no results.json"):
        find_results([tmp_path / "empty"])
    with pytest.raises(SystemExit):
        report_main([str(tmp_path / "missing")])


def test_wandb_push_is_offline_safe(sweep_dir, tmp_path, monkeypatch):
    monkeypatch.setenv("WANDB_MODE", "offline")
    monkeypatch.setenv("WANDB_SILENT", "true")
    written = write_report([sweep_dir], tmp_path / "w", plots=False, wandb="on")
    assert written["wandb"] is not None and "wandb" in written["wandb"]
