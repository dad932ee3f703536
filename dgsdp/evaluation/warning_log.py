"""The warnings of one evaluation: metrics that fell back to a defined value, per row (deduplicated)."""

from __future__ import annotations

import logging
import math
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field

from dgsdp.metrics import MetricError, MetricWarning

log = logging.getLogger(__name__)


@dataclass
class WarningLog:
    """Messages of metrics that fell back to a defined value, per row (deduplicated)."""

    items: list[dict[str, str]] = field(default_factory=list)

    def add(self, row: str, metric: str, message: str) -> None:
        entry = {"row": row, "metric": metric, "message": message}
        if entry not in self.items:
            self.items.append(entry)
            log.warning("%s / %s: %s", row, metric, message)

    def guard(self, row: str, metric: str, fn: Callable[[], float]) -> float | None:
        """``fn()``, or None when it raises MetricError; MetricWarnings it raises are recorded."""
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always", MetricWarning)
            try:
                value: float | None = float(fn())
            except MetricError as e:
                self.add(row, metric, f"not computable ({e}); reported as n/a")
                value = None
        for w in caught:
            if issubclass(w.category, MetricWarning):
                self.add(row, metric, str(w.message))
            else:
                warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
        if value is not None and not math.isfinite(value):
            self.add(row, metric, f"non-finite value {value}; reported as n/a")
            value = None
        return value
