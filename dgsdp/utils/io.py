"""Atomic file writes and a content-keyed on-disk cache.

Every cache in the project (processed datasets, audio features, text embeddings) goes through
:class:`DiskCache`, so that a killed process never leaves a file that a later run would read:
data is written to a temporary file in the same folder and renamed into place only when complete.
"""

from __future__ import annotations

import contextlib
import hashlib
import json
import logging
import os
import re
import secrets
import socket
import struct
import time
import zipfile
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np

log = logging.getLogger(__name__)


TEMP_SUFFIX = ".tmp"
STALE_TEMP_SECONDS = 24 * 3600
"""A temporary file of another machine (shared folder) is removed only after this long untouched."""
_TAG = re.compile(r"\.(?P<host>[A-Za-z0-9_-]+)-(?P<pid>\d+)-[0-9a-f]{8}\.tmp$")


def temp_tag() -> str:
    """``<host>-<pid>``: tells which live process owns a temporary file, so others can clean up after a kill."""
    host = re.sub(r"[^A-Za-z0-9_-]+", "_", socket.gethostname()) or "host"
    return f"{host}-{os.getpid()}"


def _host_tag() -> str:
    return temp_tag().rsplit("-", 1)[0]


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # exists, owned by someone else
        return True
    return True


def owner_gone(tag: str, path: Path, now: float | None = None) -> bool:
    """Whether the process named by a :func:`temp_tag` (``<host>-<pid>``) that wrote ``path`` no longer runs: on this
    machine it has exited; for another machine's file, ``path`` has not been touched for a day."""
    host, _, pid = tag.rpartition("-")
    if not pid.isdigit():
        return False
    if host == _host_tag():
        return int(pid) != os.getpid() and not _pid_alive(int(pid))
    try:
        return (now or time.time()) - path.stat().st_mtime > STALE_TEMP_SECONDS
    except OSError:
        return False


def is_stale_temp(path: Path, now: float | None = None) -> bool:
    """Whether a temporary file written by :func:`atomic_path` was left by a process that no longer runs."""
    m = _TAG.search(path.name)
    return m is not None and owner_gone(f"{m['host']}-{m['pid']}", path, now)


def remove_stale_temps(folder: str | os.PathLike) -> int:
    """Delete the temporary files that killed processes left in ``folder`` (not recursive); returns how many."""
    removed = 0
    folder = Path(folder)
    if not folder.is_dir():
        return 0
    for path in folder.glob(f".*{TEMP_SUFFIX}"):
        if path.is_file() and is_stale_temp(path):
            with contextlib.suppress(OSError):
                path.unlink()
                removed += 1
    if removed:
        log.info("removed %d temporary file(s) left by an interrupted run in %s", removed, folder)
    return removed


def _create_temp(path: Path) -> Path:
    """A new empty file next to ``path`` with the permissions a plain ``open`` would give (umask applied)."""
    for _ in range(100):
        tmp = path.with_name(f".{path.name}.{temp_tag()}-{secrets.token_hex(4)}{TEMP_SUFFIX}")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        os.close(fd)
        return tmp
    raise FileExistsError(f"cannot create a temporary file next to {path}")


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` only if the block succeeds.

    The temporary name carries the host and process id, so a later run can tell a file left by a killed process
    (:func:`remove_stale_temps`) from one another process is still writing. The file gets the normal permissions
    of a new file (``0666`` minus the umask), not the ``0600`` of ``tempfile.mkstemp``."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp_path = _create_temp(path)
    try:
        yield tmp_path
        os.replace(tmp_path, path)
    finally:
        if tmp_path.exists():
            tmp_path.unlink()


def atomic_write_bytes(path: str | os.PathLike, data: bytes) -> None:
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            f.write(data)
            f.flush()
            os.fsync(f.fileno())


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    atomic_write_bytes(path, text.encode("utf-8"))


def atomic_save_npz(path: str | os.PathLike, arrays: Mapping[str, np.ndarray]) -> None:
    """Write a dict of arrays as an uncompressed ``.npz`` atomically."""
    with atomic_path(path) as tmp:
        with open(tmp, "wb") as f:
            np.savez(f, **arrays)
            f.flush()
            os.fsync(f.fileno())


def stable_hash(obj: Any, length: int = 16) -> str:
    """Hash of a JSON-serialisable object (dict keys sorted), for cache keys."""
    blob = json.dumps(obj, sort_keys=True, default=str).encode("utf-8")
    return hashlib.sha256(blob).hexdigest()[:length]


def file_hash(path: str | os.PathLike, length: int = 16, chunk_bytes: int = 1 << 20) -> str:
    """SHA-256 of a file's bytes (content key: renamed or moved files still hit the cache)."""
    h = hashlib.sha256()
    with open(path, "rb") as f:
        while chunk := f.read(chunk_bytes):
            h.update(chunk)
    return h.hexdigest()[:length]


def mmap_npz(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """Memory-map every array of an uncompressed ``.npz`` (as :func:`atomic_save_npz` writes them): read-only
    arrays whose pages are read on first touch and shared by every process mapping the file (loader workers,
    the ranks of a data-parallel run on one machine). Raises ValueError for compressed or non-numeric members."""
    arrays: dict[str, np.ndarray] = {}
    with zipfile.ZipFile(path) as archive, open(path, "rb") as f:
        for info in archive.infolist():
            if info.compress_type != zipfile.ZIP_STORED or not info.filename.endswith(".npy"):
                raise ValueError(f"{path}: {info.filename} is compressed or not an array")
            f.seek(info.header_offset)
            local_header = f.read(30)
            if local_header[:4] != b"PK\x03\x04":
                raise ValueError(f"{path}: bad zip entry {info.filename}")
            name_bytes, extra_bytes = struct.unpack("<HH", local_header[26:30])
            f.seek(info.header_offset + 30 + name_bytes + extra_bytes)
            version = np.lib.format.read_magic(f)
            if version == (1, 0):
                shape, fortran, dtype = np.lib.format.read_array_header_1_0(f)
            else:
                shape, fortran, dtype = np.lib.format.read_array_header_2_0(f)
            if dtype.hasobject:
                raise ValueError(f"{path}: {info.filename} holds Python objects")
            name = info.filename[: -len(".npy")]
            if int(np.prod(shape)) == 0:
                arrays[name] = np.empty(shape, dtype=dtype)
            else:
                order = "F" if fortran else "C"
                arrays[name] = np.memmap(path, dtype=dtype, mode="r", offset=f.tell(), shape=shape, order=order)
    return arrays


class DiskCache:
    """A folder of ``.npz`` entries keyed by strings; entries appear atomically or not at all.

    ``namespace`` separates kinds of entries (e.g. ``"librosa-<settings hash>"``) so that a changed setting
    never reads data computed under another one.
    """

    def __init__(self, root: str | os.PathLike, namespace: str) -> None:
        self.dir = Path(root) / namespace
        self.hits = 0
        self.misses = 0
        self.corrupt = 0
        remove_stale_temps(self.dir)

    def path(self, key: str) -> Path:
        return self.dir / f"{key}.npz"

    def __contains__(self, key: str) -> bool:
        return self.path(key).is_file()

    def load(self, key: str, required: tuple[str, ...] = (), mmap: bool = False) -> dict[str, np.ndarray] | None:
        """The entry's arrays, or None on a miss. A corrupt entry (garbage bytes, a truncated zip, missing
        ``required`` arrays) is reported once as a warning, removed, and treated as a miss. ``mmap``: memory-mapped
        read-only (see :func:`mmap_npz`), for large entries read in slices (audio features of whole songs)."""
        p = self.path(key)
        if not p.is_file():
            return None
        if mmap:
            try:
                mapped = mmap_npz(p)
                if all(k in mapped for k in required):
                    return mapped
            except (OSError, ValueError, zipfile.BadZipFile, struct.error):
                pass  # read it the ordinary way below (which drops a corrupt entry)
        try:
            with np.load(p, allow_pickle=False) as z:
                arrays = {k: z[k] for k in z.files}
            missing = [k for k in required if k not in arrays]
            if missing:
                raise ValueError(f"no {', '.join(missing)} array")
            return arrays
        except Exception as e:  # noqa: BLE001 - BadZipFile, ValueError, EOFError, OSError, zlib.error, ...
            log.warning("cache entry %s is corrupt (%s: %s); removed, it will be recomputed", p, type(e).__name__, e)
            self.corrupt += 1
            p.unlink(missing_ok=True)
            return None

    def save(self, key: str, arrays: Mapping[str, np.ndarray]) -> None:
        atomic_save_npz(self.path(key), arrays)

    def get_or_compute(
        self,
        key: str,
        compute: Callable[[], Mapping[str, np.ndarray]],
        required: tuple[str, ...] = (),
        mmap: bool = False,
    ) -> dict[str, np.ndarray]:
        """The cached arrays of ``key``, or ``compute()``'s, saved; ``required`` arrays must be in a valid entry."""
        found = self.load(key, required, mmap=mmap)
        if found is not None:
            self.hits += 1
            return found
        self.misses += 1
        arrays = {k: np.asarray(v) for k, v in compute().items()}
        self.save(key, arrays)
        return arrays
