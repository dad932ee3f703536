"""Gather evaluated runs into the papers' table layout: rows = configs, columns = metrics, mean ± std over seeds,
the published numbers beside ours (``dgsdp/resources/paper_tables.yaml``).
``python -m dgsdp.report <sweep dir | run dirs>`` (installed: ``dgsdp-report``).

A run's evaluation (``results.json``) gives one value per row and metric (its mean over trials). A report row is
``"<run_name>, <evaluation row>"`` (e.g. ``table4_row0, w=2``) or a ground-truth row; its value is the mean and
sample standard deviation (ddof 1) of those values over the runs (seeds) that share it.
"""

from __future__ import annotations

import csv
import io
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from dgsdp.errors import DataError
from dgsdp.evaluation.protocols import METRICS
from dgsdp.evaluation.results import RESULTS_JSON, format_value, markdown_table, read_results
from dgsdp.resources import PAPER_TABLES_FILE

PAPER_TABLES = PAPER_TABLES_FILE


@dataclass
class ReportRow:
    """One row of a report table: values per metric over seeds, and the paper's numbers."""

    key: str
    values: dict[str, list[float]] = field(default_factory=dict)  # metric -> one value per run
    seeds: list[Any] = field(default_factory=list)
    paper: dict[str, float] = field(default_factory=dict)

    def stat(self, metric: str) -> tuple[float | None, float | None, int]:
        """(mean, std, n) over runs; std is the sample std (ddof 1), 0 for one run; (None, None, 0) without values."""
        vals = self.values.get(metric, [])
        if not vals:
            return None, None, 0
        arr = np.asarray(vals, dtype=np.float64)
        return float(arr.mean()), float(arr.std(ddof=1)) if len(arr) > 1 else 0.0, len(arr)


@dataclass
class ReportTable:
    """A paper table: its id (sweep name or protocol), title, metric columns and rows in display order."""

    table_id: str
    title: str
    metrics: list[str]
    rows: list[ReportRow]


def find_results(paths: Iterable[str | Path]) -> list[Path]:
    """Every ``results.json`` at or below ``paths`` (run folders, sweep folders or the files themselves)."""
    found: list[Path] = []
    for p in paths:
        p = Path(p).expanduser()
        if p.is_file():
            found.append(p)
        elif p.is_dir():
            found += sorted(p.rglob(RESULTS_JSON))
        else:
            raise DataError(f"{p} does not exist; give sweep folders, run folders or results.json files")
    if not found:
        raise DataError(
            f"no {RESULTS_JSON} under {', '.join(map(str, paths))}: evaluate the runs first "
            "(python evaluate.py checkpoint=... or train with evaluate=<protocol>)"
        )
    return sorted(set(found))


def read_results_file(path: Path) -> dict[str, Any]:
    """One ``results.json`` with its shape checked: DataError (naming the file) for a binary file, a file of
    another kind, or results whose rows are not what ``evaluate`` writes."""
    try:
        path.read_bytes().decode("utf-8")
    except UnicodeDecodeError:
        raise DataError(
            f"{path} is not a results.json (a binary file, not JSON text); give sweep folders, run folders or the "
            "results.json files that evaluate.py writes"
        ) from None
    except OSError as e:
        raise DataError(f"cannot read {path} ({e})") from e
    try:
        results = read_results(path)
        rows = results["rows"]
        if not isinstance(rows, list) or not all(
            isinstance(r, dict) and isinstance(r.get("metrics"), dict) for r in rows
        ):
            raise TypeError("'rows' must be a list of rows with 'metrics'")
        return results
    except DataError:
        raise
    except (TypeError, KeyError, AttributeError, ValueError) as e:
        raise DataError(f"{path} is not an evaluation result written by evaluate.py ({e})") from e


def load_paper_tables(path: str | Path = PAPER_TABLES) -> dict[str, Any]:
    """The published numbers: {table id: {title, metrics, rows: {row key: {metric: value}}}}."""
    path = Path(path)
    if not path.is_file():
        return {}
    return yaml.safe_load(path.read_text()) or {}


def table_id_of(results: dict[str, Any]) -> str:
    """A run's table: the sweep it belongs to, else its protocol."""
    return (results.get("run") or {}).get("sweep_name") or results["protocol"]


def row_key(results: dict[str, Any], row: dict[str, Any], source: Path) -> str:
    """``"<run_name>, <row>"`` for generated rows (just the run name for a row named ``generated``), the row's own
    name for ground truth."""
    if row.get("kind") == "ground_truth":
        return row["name"]
    run_name = (results.get("run") or {}).get("run_name") or source.parent.name
    return run_name if row["name"] == "generated" else f"{run_name}, {row['name']}"


def build_tables(result_files: Sequence[Path], paper: dict[str, Any] | None = None) -> list[ReportTable]:
    """Group results by table and row; attach the paper's numbers. Rows: the paper's order, then ours."""
    paper = load_paper_tables() if paper is None else paper
    grouped: dict[str, dict[str, ReportRow]] = {}
    metric_order: dict[str, list[str]] = {}
    for path in result_files:
        results = read_results_file(path)
        tid = table_id_of(results)
        rows = grouped.setdefault(tid, {})
        metric_order.setdefault(tid, list(results.get("metrics", METRICS)))
        seed = (results.get("run") or {}).get("seed")
        for row in results["rows"]:
            key = row_key(results, row, path)
            entry = rows.setdefault(key, ReportRow(key))
            entry.seeds.append(seed)
            for metric, summary in row["metrics"].items():
                if summary.get("mean") is not None:
                    entry.values.setdefault(metric, []).append(float(summary["mean"]))
    tables = []
    for tid, rows in grouped.items():
        published = paper.get(tid) or {}
        paper_rows = published.get("rows") or {}
        metrics = list(published.get("metrics") or metric_order[tid])
        metrics += [m for m in metric_order[tid] if m not in metrics]
        ordered: list[ReportRow] = []
        for key, numbers in paper_rows.items():
            entry = rows.pop(key, ReportRow(key))
            entry.paper = {k: float(v) for k, v in (numbers or {}).items()}
            ordered.append(entry)
        ordered += [rows[k] for k in sorted(rows, key=lambda k: (k.startswith("ground_truth"), k))]
        tables.append(ReportTable(tid, published.get("title") or f"Protocol {tid}", metrics, ordered))
    return sorted(tables, key=lambda t: t.table_id)


def table_markdown(table: ReportTable) -> str:
    """The table as markdown: per metric our mean ± std over seeds and the paper's number."""
    with_paper = {m for m in table.metrics if any(m in r.paper for r in table.rows)}
    header = ["row", "seeds"]
    for m in table.metrics:
        header += [m, f"{m} (paper)"] if m in with_paper else [m]
    lines = []
    for row in table.rows:
        cells = [row.key, str(len(row.seeds))]
        for m in table.metrics:
            mean, std, n = row.stat(m)
            cells.append(format_value(m, mean, std, n) if n else "-")
            if m in with_paper:
                cells.append(format_value(m, row.paper[m]) if m in row.paper else "-")
        lines.append(cells)
    return f"## {table.title}\n\n" + markdown_table(header, lines)


def table_csv(tables: Sequence[ReportTable]) -> str:
    """Long-format CSV: table, row, metric, mean, std, n_seeds, paper."""
    buf = io.StringIO()
    writer = csv.writer(buf)
    writer.writerow(["table", "row", "metric", "mean", "std", "n_seeds", "paper"])
    for table in tables:
        for row in table.rows:
            for m in table.metrics:
                mean, std, n = row.stat(m)
                writer.writerow([
                    table.table_id, row.key, m, "" if mean is None else repr(mean), "" if std is None else repr(std),
                    n, repr(row.paper[m]) if m in row.paper else "",
                ])  # fmt: skip
    return buf.getvalue()


def write_report(
    paths: Iterable[str | Path], out_dir: str | Path, *, plots: bool = True, wandb: str = "auto"
) -> dict[str, Any]:
    """Gather ``results.json`` files below ``paths`` and write ``report.md``, ``report.csv`` and one bar chart per
    table (``<table>.png``) into ``out_dir``; push the tables to wandb (``auto``: when a run was logged there)."""
    from dgsdp.utils.io import atomic_write_text

    files = find_results(list(paths))
    tables = build_tables(files)
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    md = "# Results\n\n" + "\n".join(table_markdown(t) for t in tables)
    md += f"\nValues: mean ± sample std over seeds of each run's mean over trials ({len(files)} evaluation(s)).\n"
    atomic_write_text(out / "report.md", md)
    atomic_write_text(out / "report.csv", table_csv(tables))
    written: dict[str, Any] = {"markdown": out / "report.md", "csv": out / "report.csv", "plots": [], "tables": tables}
    if plots:
        from dgsdp.report.plots import bar_chart

        written["plots"] = [bar_chart(t, out / f"{t.table_id}.png") for t in tables]
    logged = [read_results_file(f) for f in files]
    if wandb == "on" or (wandb == "auto" and any("WandbLogger" in r.get("loggers", []) for r in logged)):
        from dgsdp.report.wandb_push import push_tables

        written["wandb"] = push_tables(tables, logged, out)
    return written


__all__ = ["ReportRow", "ReportTable", "build_tables", "find_results", "table_csv", "table_markdown", "write_report"]
