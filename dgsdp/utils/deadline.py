"""A time limit for one piece of work in this thread (a studio request): long loops check it and stop.

``with time_limit(600, "..."):`` sets the limit; the sampling loop and the video's frame loop call
:func:`check_time`, which raises :class:`TimeLimitError` (with the message given) once the limit has passed, and
the video's ffmpeg wait ends at it (:func:`seconds_left`). Outside a ``time_limit`` block nothing is limited.
"""

from __future__ import annotations

import math
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager

from dgsdp.errors import DgsdpError


class TimeLimitError(DgsdpError):
    """The work ran past its time limit and was stopped."""


_local = threading.local()


@contextmanager
def time_limit(seconds: float, message: str) -> Iterator[None]:
    """Limit the work in this block (this thread) to ``seconds``; ``message`` is the error's text past it."""
    if not seconds > 0:
        raise ValueError(f"a time limit must be positive, got {seconds}")
    previous = getattr(_local, "limit", None)
    _local.limit = (time.monotonic() + float(seconds), message)
    try:
        yield
    finally:
        _local.limit = previous


def seconds_left() -> float:
    """Seconds until this thread's time limit (infinite without one)."""
    limit = getattr(_local, "limit", None)
    return math.inf if limit is None else limit[0] - time.monotonic()


def check_time() -> None:
    """Raise :class:`TimeLimitError` when this thread's time limit has passed."""
    limit = getattr(_local, "limit", None)
    if limit is not None and time.monotonic() > limit[0]:
        raise TimeLimitError(limit[1])
