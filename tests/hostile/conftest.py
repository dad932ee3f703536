"""Hostile inputs: files an attacker or a broken tool could hand the project. Every case must end in one clear
error (a DgsdpError subclass whose message says what is wrong) or a valid result, and attacker code must never
run: payloads create a marker file that each test asserts does not exist.

``TALLY`` counts the hostile inputs tried, refused cleanly, and code executed; ``pytest -s tests/hostile`` prints it.
"""

from __future__ import annotations

import os
from collections import Counter
from pathlib import Path

import pytest

TALLY: Counter = Counter()


@pytest.fixture
def marker(tmp_path: Path) -> Path:
    """A file that attacker code in a payload would create; asserted absent after each case."""
    path = tmp_path / "ATTACKER_CODE_RAN"
    yield path
    TALLY["code executed"] += path.exists()
    assert not path.exists(), "a hostile file ran code while being loaded"


def refused(exc_info: pytest.ExceptionInfo, *fragments: str) -> None:
    """Assert the error is the project's own and its message names what is wrong; count the case."""
    from dgsdp.errors import DgsdpError

    TALLY["tried"] += 1
    assert isinstance(exc_info.value, DgsdpError), f"raw {type(exc_info.value).__name__}: {exc_info.value}"
    message = str(exc_info.value)
    for fragment in fragments:
        assert fragment.lower() in message.lower(), f"{fragment!r} not in {message!r}"
    TALLY["refused cleanly"] += 1


def accepted() -> None:
    """Count a hostile-looking input that is valid and gave a valid result."""
    TALLY["tried"] += 1
    TALLY["valid result"] += 1


def pytest_terminal_summary(terminalreporter, exitstatus, config) -> None:  # noqa: ARG001
    if TALLY["tried"]:
        terminalreporter.write_line(
            f"hostile inputs: {TALLY['tried']} tried, {TALLY['refused cleanly']} refused cleanly, "
            f"{TALLY['valid result']} valid results, {TALLY['code executed']} ran code"
        )


def shell_touch(marker: Path) -> str:
    return f"touch {os.fspath(marker)!s}"
