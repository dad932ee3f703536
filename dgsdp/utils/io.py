"""Atomic file writes and a content-keyed on-disk cache.

Every cache in the project (processed datasets, audio features, text embeddings) goes through
:class:`DiskCache`, so that a killed process never leaves a file that a later run would read:
data is written to a temporary file in the same folder and renamed into place only when complete.
"""

from __future__ import annotations

import hashlib
import json
import os
import struct
import tempfile
import zipfile
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np


@contextmanager
def atomic_path(path: str | os.PathLike) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; rename it onto ``path`` only if the block succeeds."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    os.close(fd)
    tmp_path = Path(tmp)
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

    def path(self, key: str) -> Path:
        return self.dir / f"{key}.npz"

    def __contains__(self, key: str) -> bool:
        return self.path(key).is_file()

    def load(self, key: str, mmap: bool = False) -> dict[str, np.ndarray] | None:
        """The entry's arrays, or None. ``mmap``: memory-mapped read-only (see :func:`mmap_npz`), for large
        entries read in slices (audio features of whole songs)."""
        p = self.path(key)
        if not p.is_file():
            return None
        if mmap:
            try:
                return mmap_npz(p)
            except (OSError, ValueError, zipfile.BadZipFile, struct.error):
                pass  # read it the ordinary way below (which drops a corrupt entry)
        try:
            with np.load(p, allow_pickle=False) as z:
                return {k: z[k] for k in z.files}
        except (OSError, ValueError, EOFError):
            # A corrupt entry (e.g. disk full at write time on a filesystem without atomic rename) is a miss.
            p.unlink(missing_ok=True)
            return None

    def save(self, key: str, arrays: Mapping[str, np.ndarray]) -> None:
        atomic_save_npz(self.path(key), arrays)

    def get_or_compute(
        self, key: str, compute: Callable[[], Mapping[str, np.ndarray]], mmap: bool = False
    ) -> dict[str, np.ndarray]:
        found = self.load(key, mmap=mmap)
        if found is not None:
            self.hits += 1
            return found
        self.misses += 1
        arrays = {k: np.asarray(v) for k, v in compute().items()}
        self.save(key, arrays)
        return arrays
