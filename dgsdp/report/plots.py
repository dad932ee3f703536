"""Bar charts of a report table: one panel per metric, ours (mean ± std over seeds) beside the paper's numbers."""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402


def bar_chart(table, path: str | Path) -> Path:
    """Write ``path`` (PNG) for a :class:`~dgsdp.report.ReportTable`; returns the path."""
    metrics = table.metrics
    n_cols = min(4, len(metrics))
    n_rows = -(-len(metrics) // n_cols)
    fig, axes = plt.subplots(n_rows, n_cols, figsize=(4.2 * n_cols, 3.4 * n_rows), squeeze=False)
    labels = [r.key for r in table.rows]
    x = np.arange(len(labels))
    for ax, metric in zip(axes.flat, metrics):
        stats = [r.stat(metric) for r in table.rows]
        ours = [s[0] if s[0] is not None else np.nan for s in stats]
        err = [s[1] if s[1] is not None else 0.0 for s in stats]
        paper = [r.paper.get(metric, np.nan) for r in table.rows]
        ax.bar(x - 0.2, ours, 0.4, yerr=err, capsize=2, label="ours", color="tab:blue")
        ax.bar(x + 0.2, paper, 0.4, label="paper", color="tab:gray", hatch="//")
        ax.set_title(metric)
        ax.set_xticks(x, labels, rotation=60, ha="right", fontsize=7)
    for ax in list(axes.flat)[len(metrics) :]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(table.title, fontsize=10)
    fig.tight_layout()
    path = Path(path)
    fig.savefig(path, dpi=100)
    plt.close(fig)
    return path
