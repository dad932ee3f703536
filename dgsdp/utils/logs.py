"""Logging set-up shared by the entry points.

Importing Lightning puts console handlers of its own on its loggers: ``lightning`` prints "INFO: ..." and still
passes records up, and ``lightning.pytorch`` / ``lightning.fabric`` print on their own when the root logger had no
handler at import time. Once the root logger is configured (Hydra's job logging, ``logging.basicConfig``) every
Lightning line would then be printed twice, or miss the run's log file. The Hydra entry points remove those
handlers in ``conf/hydra/default.yaml`` (``job_logging.loggers``); other entry points call
:func:`lightning_logs_through_root` after configuring logging.
"""

from __future__ import annotations

import logging

LIGHTNING_LOGGERS = ("lightning", "lightning.pytorch", "lightning.fabric")


def lightning_logs_through_root() -> None:
    """Send Lightning's log records once, through the root logger's handlers (when it has any).

    Imports Lightning first (its import installs the handlers); without root handlers nothing changes, so that
    Lightning's own console output stays.
    """
    import lightning  # noqa: F401

    if not logging.getLogger().handlers:
        return
    for name in LIGHTNING_LOGGERS:
        logger = logging.getLogger(name)
        for handler in list(logger.handlers):
            logger.removeHandler(handler)
        logger.propagate = True
