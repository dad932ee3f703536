"""librosa's numba cache under parallel processes (dgsdp.audio.numba_cache): processes started together on an empty
cache, each computing a song's features, all exit 0, and so does one started after them; a process killed while it
fills the cache leaves one the next processes can load. On the code before the lock, four processes started 0.6 s
apart on an empty cache crashed with SIGSEGV in almost every round, and so did the one after them."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[2]
CHILD = """
import sys
import numpy as np
from dgsdp.audio.librosa_encoder import LibrosaEncoder
sr = 22050
t = np.arange(8 * sr) / sr
noise = np.random.default_rng(int(sys.argv[1])).standard_normal(t.size)
wave = 0.3 * np.sin(2 * np.pi * 220 * t) + 0.2 * noise * (np.sin(2 * np.pi * 2 * t) > 0.9)
features = LibrosaEncoder().encode(wave.astype(np.float32), sr)
assert features.shape == (240, 35), features.shape
print("features", features.shape)
"""


def _start(cache: Path, seed: int) -> subprocess.Popen:
    env = {**os.environ, "NUMBA_CACHE_DIR": str(cache), "PYTHONPATH": str(REPO), "HF_HUB_OFFLINE": "1"}
    return subprocess.Popen([sys.executable, "-c", CHILD, str(seed)], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)  # fmt: skip


def _finish(proc: subprocess.Popen) -> tuple[int, str]:
    out, _ = proc.communicate(timeout=600)
    return proc.returncode, out


def _round(cache: Path, together: int = 4) -> list[tuple[int, str]]:
    """``together`` processes started 0.6 s apart on ``cache``, then one more alone: their exit codes and output."""
    procs = []
    for i in range(together):
        procs.append(_start(cache, i))
        time.sleep(0.6)
    results = [_finish(p) for p in procs]
    results.append(_finish(_start(cache, 99)))
    return results


def _assert_all_ok(results: list[tuple[int, str]], what: str) -> None:
    codes = [code for code, _ in results]
    failed = [out[-1500:] for code, out in results if code != 0]
    assert codes == [0] * len(results), f"{what}: exit codes {codes} (-11: SIGSEGV); {failed[:1]}"
    assert all("features (240, 35)" in out for _, out in results)


@pytest.mark.slow
def test_processes_started_together_on_an_empty_cache(tmp_path):
    """Four processes 0.6 s apart on an empty NUMBA_CACHE_DIR, each computing an 8 s song's features, then one
    more: all exit 0, and the cache holds librosa's compiled functions and the lock."""
    cache = tmp_path / "numba"
    _assert_all_ok(_round(cache), "one round")
    assert (cache / "dgsdp-numba.lock").exists()
    assert len(list(cache.rglob("*.nbi"))) >= 10  # indexes of librosa's cached functions, written here


def test_a_process_waits_for_the_lock_before_it_touches_the_cache():
    """While another process holds the cache's lock, a process about to use librosa waits (it says so) and goes on
    once the lock is released. The crash the lock prevents needs an empty cache and minutes to show: the slow tests
    start processes together on fresh caches."""
    import queue
    import threading

    from filelock import FileLock

    from dgsdp.audio.numba_cache import cache_dir, prepare

    prepare()  # this process fills or loads the cache first, so the child's own work is only loading it
    folder = cache_dir()
    env = {**os.environ, "NUMBA_CACHE_DIR": str(folder), "PYTHONPATH": str(REPO), "HF_HUB_OFFLINE": "1"}
    child = "import logging; logging.basicConfig(level=logging.INFO)\n" + CHILD
    lines: queue.Queue[str] = queue.Queue()
    with FileLock(str(folder / "dgsdp-numba.lock")):
        proc = subprocess.Popen([sys.executable, "-c", child, "5"], env=env, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)  # fmt: skip
        threading.Thread(target=lambda: [lines.put(line) for line in proc.stdout], daemon=True).start()
        seen, deadline = [], time.monotonic() + 120
        while not any("waiting for another process" in line for line in seen) and time.monotonic() < deadline:
            try:
                seen.append(lines.get(timeout=1))
            except queue.Empty:
                assert proc.poll() is None, f"the child ended while the lock was held: {''.join(seen)[-1500:]}"
        assert any("waiting for another process" in line for line in seen), "".join(seen)[-1500:]
        assert proc.poll() is None  # still waiting: nothing computed under another process's lock
    assert proc.wait(timeout=300) == 0
    time.sleep(0.2)  # the reader thread's last lines
    while not lines.empty():
        seen.append(lines.get())
    assert any("features (240, 35)" in line for line in seen), "".join(seen)[-1500:]


@pytest.mark.slow
def test_rounds_and_a_process_killed_while_filling_the_cache(tmp_path):
    """Three rounds on fresh caches; then a process killed (SIGKILL) while it fills a fresh cache under the lock,
    and a round after it on that cache: every process exits 0."""
    for i in range(3):
        _assert_all_ok(_round(tmp_path / f"numba{i}"), f"round {i}")
    cache = tmp_path / "killed"
    victim = _start(cache, 7)
    deadline = time.monotonic() + 120
    while not list(cache.rglob("*.nbi")) and time.monotonic() < deadline:  # it is writing the cache
        time.sleep(0.05)
    victim.send_signal(signal.SIGKILL)
    victim.communicate(timeout=60)
    assert victim.returncode == -signal.SIGKILL
    _assert_all_ok(_round(cache, together=2), "after the killed process")


def test_prepare_stops_this_process_writing_the_cache(tmp_path, monkeypatch):
    """After the first use, librosa's numba functions in this process have numba's null cache: a type met later is
    compiled in memory, never written beside another process's files."""
    from numba.core.caching import NullCache
    from numba.core.dispatcher import Dispatcher

    from dgsdp.audio.numba_cache import librosa, prepare

    prepare()
    assert librosa.__version__  # the stand-in reaches the module
    dispatchers = [
        v for name, m in list(sys.modules.items()) if name.startswith("librosa.") and m is not None
        for v in list(vars(m).values()) if isinstance(v, Dispatcher)
    ]  # fmt: skip
    assert len(dispatchers) >= 10
    assert all(isinstance(d._cache, NullCache) for d in dispatchers)
    assert os.environ["NUMBA_CACHE_DIR"]


def test_cache_folder_keeps_the_users_and_names_the_versions(tmp_path, monkeypatch):
    import librosa as real_librosa
    import numba

    from dgsdp.audio.numba_cache import cache_dir

    monkeypatch.setenv("NUMBA_CACHE_DIR", str(tmp_path / "mine"))
    assert cache_dir() == tmp_path / "mine"
    monkeypatch.delenv("NUMBA_CACHE_DIR")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "xdg"))
    folder = cache_dir()
    assert folder.parent == tmp_path / "xdg" / "dgsdp" / "numba" and folder.is_dir()
    py = f"py{sys.version_info[0]}{sys.version_info[1]}"
    assert folder.name == f"{py}-numba{numba.__version__}-librosa{real_librosa.__version__}"


def test_the_package_uses_librosa_only_through_the_lock():
    """Every module of the package reaches librosa through dgsdp.audio.numba_cache (an import elsewhere would
    compile outside the lock)."""
    direct = [
        f"{py.relative_to(REPO)}:{i}"
        for py in (REPO / "dgsdp").rglob("*.py")
        if py.name != "numba_cache.py"
        for i, line in enumerate(py.read_text().splitlines(), 1)
        if re.match(r"\s*(import librosa|from librosa\b)", line)
    ]
    assert direct == []
