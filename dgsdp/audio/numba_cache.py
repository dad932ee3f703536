"""librosa whose numba cache no two processes write at once.

librosa compiles its numba functions on first use and keeps them on disk (``cache=True``). numba writes a cached
function as an index file and a data file in separate steps, so two processes compiling the same function at once
can leave the halves of different processes, after which every process that loads them dies with SIGSEGV (numba
issue 10128, open upstream; librosa issue 1998). Four processes started together on an empty cache, each computing
one song's features, crashed that way in almost every round; parallel sweeps (``python -m dgsdp.sweep ... --jobs
N``), data-parallel ranks, the studio's workers and a test run beside a training run all start such processes.

So every use of librosa in the project goes through :data:`librosa` here, a stand-in for the module. Its first
attribute access in a process (:func:`prepare`):

1. points numba at a cache of the project's own, one folder per Python, numba and librosa version
   (:func:`cache_dir`; a ``NUMBA_CACHE_DIR`` set by the user is kept), so a cache left broken elsewhere is not read;
2. takes an inter-process file lock on that folder;
3. imports librosa's modules (their explicitly typed functions compile or load at import) and computes the features
   the project uses on a short made-up signal in float32 and float64, so that each function compiles into the cache
   or loads from it with no other process writing;
4. turns caching off for librosa's numba functions in this process (a type signature first met later is compiled in
   memory and never written), and releases the lock.

A process that dies in step 3 leaves whole files only (numba writes each through a temporary file and a rename) and
no other process was writing, so the next run finds a cache it can load. Waiting for the lock takes as long as one
process's compilation the first time (tens of seconds on 2 cores); once the cache is filled, steps 2-4 took 4.7 s on a
busy 2-core machine, most of it importing librosa's modules, which a process computing features imports anyway.
"""

from __future__ import annotations

import importlib
import logging
import os
import sys
import tempfile
import threading
import time
from pathlib import Path
from types import ModuleType
from typing import Any

log = logging.getLogger(__name__)

LOCK_TIMEOUT_S = 1800.0  # another process compiling holds it for seconds; an hour-long wait means something is wrong
# librosa's modules that need packages the project does not use (matplotlib's display) are not imported
_SKIPPED_MODULES = ("librosa.display",)

_prepared = False
_guard = threading.Lock()


def cache_dir() -> Path:
    """Where librosa's numba functions are cached: ``NUMBA_CACHE_DIR`` if the user set it, else a folder of the
    project's own under ``$XDG_CACHE_HOME`` (``~/.cache``), one per Python, numba and librosa version (the system's
    temporary folder when the home folder cannot be written)."""
    given = os.environ.get("NUMBA_CACHE_DIR")
    if given:
        return Path(given)
    import librosa as real_librosa
    import numba

    key = f"py{sys.version_info[0]}{sys.version_info[1]}-numba{numba.__version__}-librosa{real_librosa.__version__}"
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "dgsdp" / "numba"
    try:
        (base / key).mkdir(parents=True, exist_ok=True)
        return base / key
    except OSError:
        fallback = Path(tempfile.gettempdir()) / f"dgsdp-numba-{os.getuid() if hasattr(os, 'getuid') else 'user'}"
        return fallback / key


def prepare() -> None:
    """Fill or load librosa's numba cache under an inter-process lock, then stop this process writing to it (the
    module docstring says why); runs once per process, on the first use of :data:`librosa`."""
    global _prepared
    if _prepared:
        return
    with _guard:
        if _prepared:
            return
        from filelock import FileLock, Timeout

        folder = cache_dir()
        folder.mkdir(parents=True, exist_ok=True)
        _use_cache_dir(folder)
        lock = FileLock(str(folder / "dgsdp-numba.lock"))
        start = time.perf_counter()
        try:
            lock.acquire(timeout=5)
        except Timeout:
            log.info("waiting for another process compiling librosa's numba functions in %s", folder)
            try:
                lock.acquire(timeout=LOCK_TIMEOUT_S)
            except Timeout:
                raise RuntimeError(
                    f"waited {LOCK_TIMEOUT_S:.0f} s for the lock on librosa's numba cache {folder}; if no other "
                    f"process of this project is running, delete {folder / 'dgsdp-numba.lock'} and try again"
                ) from None
        try:
            _import_librosa_modules()
            _compute_features()
            stopped = _stop_caching()
        finally:
            lock.release()
        log.debug("librosa's numba cache ready in %.1f s (%d functions)", time.perf_counter() - start, stopped)
        _prepared = True


def _use_cache_dir(folder: Path) -> None:
    """numba reads its cache folder when a function is decorated (at librosa's module imports), from its config;
    the environment carries it to child processes."""
    os.environ["NUMBA_CACHE_DIR"] = str(folder)
    from numba.core import config

    config.reload_config()
    config.CACHE_DIR = str(folder)


def _import_librosa_modules() -> None:
    import pkgutil

    import librosa as real_librosa

    for info in pkgutil.walk_packages(real_librosa.__path__, "librosa."):
        if info.name in _SKIPPED_MODULES or info.name.startswith(tuple(f"{m}." for m in _SKIPPED_MODULES)):
            continue
        try:
            importlib.import_module(info.name)
        except ImportError as e:  # a module needing an optional package this install lacks
            log.debug("librosa module %s not imported: %s", info.name, e)


def _compute_features() -> None:
    """What the project computes with librosa (the encoders' features, both beat trackers, resampling), on 2 s of
    a made-up signal in both float widths, so each numba function meets the types it will meet."""
    import warnings

    import librosa as real_librosa
    import numpy as np

    sr, hop = 15360, 512
    t = np.arange(2 * sr) / sr
    clicks = (np.sin(2 * np.pi * 2 * t) > 0.95).astype(np.float64)
    signal = 0.3 * np.sin(2 * np.pi * 220 * t) + 0.2 * clicks * np.random.default_rng(0).standard_normal(t.size)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for y in (signal.astype(np.float32), signal):
            envelope = real_librosa.onset.onset_strength(y=y, sr=sr, hop_length=hop)
            real_librosa.feature.mfcc(y=y, sr=sr, n_mfcc=20, hop_length=hop)
            real_librosa.feature.chroma_cens(y=y, sr=sr, hop_length=hop)
            real_librosa.onset.onset_detect(onset_envelope=envelope, sr=sr, hop_length=hop)
            tempo = real_librosa.feature.tempo(onset_envelope=envelope, sr=sr, hop_length=hop)
            real_librosa.beat.beat_track(onset_envelope=envelope, sr=sr, hop_length=hop, start_bpm=float(tempo[0]))
            real_librosa.util.peak_pick(envelope, pre_max=3, post_max=3, pre_avg=3, post_avg=5, delta=0.1, wait=5)
            real_librosa.resample(y, orig_sr=sr, target_sr=22050, res_type="soxr_hq")


def _stop_caching() -> int:
    """Turn off numba's disk cache for every librosa function in this process; returns how many."""
    from numba.core.caching import NullCache
    from numba.core.dispatcher import Dispatcher

    stopped = 0
    for name, module in list(sys.modules.items()):
        if not (name == "librosa" or name.startswith("librosa.")) or module is None:
            continue
        for value in list(vars(module).values()):
            if isinstance(value, ModuleType | type):  # lazily loaded modules raise on any attribute
                continue
            for dispatcher in (value, getattr(value, "_dispatcher", None)):
                if isinstance(dispatcher, Dispatcher) and not isinstance(dispatcher._cache, NullCache):
                    dispatcher._cache = NullCache()
                    stopped += 1
            builder = getattr(value, "gufunc_builder", None)  # guvectorize without fixed signatures
            if builder is not None and not isinstance(getattr(builder, "cache", None), NullCache):
                builder.cache = NullCache()
                stopped += 1
    return stopped


class _Librosa(ModuleType):
    """The librosa module, reached after :func:`prepare`."""

    def __getattr__(self, name: str) -> Any:
        prepare()
        import librosa as real_librosa

        return getattr(real_librosa, name)

    def __dir__(self) -> list[str]:
        import librosa as real_librosa

        return dir(real_librosa)


librosa = _Librosa("librosa")
"""Use as the librosa module (``from dgsdp.audio.numba_cache import librosa``); the first use runs :func:`prepare`."""

__all__ = ["cache_dir", "librosa", "prepare"]
