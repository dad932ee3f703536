"""The per-thread time limit of a studio request."""

import math
import threading
import time

import pytest

from dgsdp.utils.deadline import TimeLimitError, check_time, seconds_left, time_limit


def test_a_time_limit_stops_work_in_its_thread_only():
    check_time()  # no limit: nothing happens
    assert seconds_left() == math.inf
    other: list[float] = []
    with time_limit(0.05, "stopped after 0.05 s"):
        assert 0 < seconds_left() <= 0.05
        check_time()
        time.sleep(0.08)
        thread = threading.Thread(target=lambda: other.append(seconds_left()))
        thread.start()
        thread.join()
        with pytest.raises(TimeLimitError, match="stopped after 0.05 s"):
            check_time()
    assert other == [math.inf]  # another thread (another user's request) is not limited
    assert seconds_left() == math.inf  # and the limit ends with its block
    with pytest.raises(ValueError, match="positive"):
        with time_limit(0, "x"):
            pass
