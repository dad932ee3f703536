"""Push report tables to wandb as one ``report`` run per table group (offline unless configured online)."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Any

log = logging.getLogger(__name__)


def push_tables(tables: list, results: list[dict[str, Any]], out_dir: Path) -> str | None:
    """Log every table as a ``wandb.Table`` (and its bar chart) to a run in the runs' project and group.

    Offline by default (``DGSDP_WANDB_OFFLINE``, as the training logger; ``WANDB_MODE`` wins); a failure is
    logged, never raised. Returns the wandb run folder, or None.
    """
    try:
        import wandb
    except ImportError:
        log.warning("wandb is not installed; the report is not pushed")
        return None
    project = next((r["run"].get("wandb_project") for r in results if (r.get("run") or {}).get("wandb_project")), None)
    group = next((r["run"].get("sweep_name") for r in results if (r.get("run") or {}).get("sweep_name")), None)
    offline = os.environ.get("DGSDP_WANDB_OFFLINE", "true").lower() != "false"
    mode = os.environ.get("WANDB_MODE") or ("offline" if offline else "online")
    try:
        run = wandb.init(
            project=project or "dgsdp", group=group, job_type="report", name=f"report-{group or 'runs'}",
            dir=str(out_dir), mode=mode, reinit=True,
        )  # fmt: skip
        for table in tables:
            columns = ["row", "n_seeds"] + [f"{m}{s}" for m in table.metrics for s in ("", "_std", "_paper")]
            data = []
            for row in table.rows:
                cells: list[Any] = [row.key, len(row.seeds)]
                for m in table.metrics:
                    mean, std, _ = row.stat(m)
                    cells += [mean, std, row.paper.get(m)]
                data.append(cells)
            payload: dict[str, Any] = {f"report/{table.table_id}": wandb.Table(columns=columns, data=data)}
            chart = out_dir / f"{table.table_id}.png"
            if chart.is_file():
                payload[f"report/{table.table_id}_chart"] = wandb.Image(str(chart))
            run.log(payload)
        folder = str(run.dir)
        run.finish()
        return folder
    except Exception as e:  # noqa: BLE001 - the report on disk is the product; a dashboard failure must not lose it
        log.warning("could not push the report to wandb (%s: %s)", type(e).__name__, e)
        return None
