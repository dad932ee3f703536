"""Reading motion pickles without running code from them.

A pickle names Python functions that the reader calls while loading (``os.system``, ``builtins.exec``,
``functools.partial``, ...), so plain ``pickle.load`` on a file someone sent you runs their code. Motion files
(AIST++ ``.pkl``, seed motions, keyframes, evaluation inputs) only ever hold dicts, lists and tuples of strings,
numbers and numpy arrays, so :func:`load_pickle` admits exactly the globals that numpy and Python need to rebuild
those (numpy's array and scalar reconstructors, ``numpy.dtype``, ``set``...) and refuses any other with an
:class:`UnsafePickleError` naming the file and the refused global, before anything is called.

Plain data can still crash or hang the reader: a dict key nested a million tuples deep, memo-shared tuples that
unfold to 2^64 objects when hashed, a numpy object array whose shape claims more items than its list holds. So
every pickle is first scanned with the bounded scan checkpoints go through (:mod:`dgsdp.utils.pickle_scan`, its
``"data"`` kind and :data:`~dgsdp.utils.pickle_scan.DATA_LIMITS`), and every numpy dtype it made is checked before
the result is returned (a structured dtype whose fields lie outside its items would read memory past them).
"""

from __future__ import annotations

import codecs
import collections
import io
import math
import mmap
import os
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.errors import DataError
from dgsdp.utils.pickle_scan import DATA_LIMITS, ScanLimits, ScanRefused, ScanReport, scan_stream


class UnsafePickleError(DataError):
    """A pickle asks for a Python global outside the allowlist (it would run code when loaded)."""


def _latin1_encode(text: str, encoding: str = "utf-8") -> bytes:
    """``_codecs.encode`` as pickles of protocol 0-2 use it for bytes: text codecs only (no zlib/base64 tricks)."""
    if not isinstance(text, str) or codecs.lookup(encoding).name not in ("iso8859-1", "utf-8", "ascii"):
        raise pickle.UnpicklingError(f"_codecs.encode({type(text).__name__}, {encoding!r}) is not allowed")
    return codecs.encode(text, encoding)


def _numpy_globals() -> dict[str, Any]:
    from numpy._core import multiarray, numeric  # numpy >= 2; pickles of numpy 1 name numpy.core.*

    found = {
        "multiarray._reconstruct": multiarray._reconstruct,
        "multiarray.scalar": multiarray.scalar,
        "numeric._frombuffer": numeric._frombuffer,
    }
    out = {}
    for package in ("numpy._core", "numpy.core"):
        for name, obj in found.items():
            module, attr = name.split(".")
            out[f"{package}.{module}.{attr}"] = obj
    out["numpy.ndarray"] = np.ndarray
    out["numpy.dtype"] = np.dtype
    return out


def _allowed_globals() -> dict[str, Any]:
    allowed: dict[str, Any] = {}
    for builtins_module in ("builtins", "__builtin__"):
        for name, obj in (("set", set), ("frozenset", frozenset), ("complex", complex), ("bytes", bytes),
                          ("bytearray", bytearray), ("slice", slice), ("range", range)):  # fmt: skip
            allowed[f"{builtins_module}.{name}"] = obj
    allowed["_codecs.encode"] = _latin1_encode
    allowed["collections.OrderedDict"] = collections.OrderedDict
    allowed.update(_numpy_globals())
    return allowed


ALLOWED_GLOBALS: dict[str, Any] = _allowed_globals()
"""``"module.name"`` -> the object a pickle gets for it; everything else is refused."""


class _RestrictedUnpickler(pickle.Unpickler):
    def __init__(self, file: io.BufferedIOBase, source: str) -> None:
        super().__init__(file)
        self.source = source

    def find_class(self, module: str, name: str) -> Any:
        key = f"{module}.{name}"
        if key in ALLOWED_GLOBALS:
            return ALLOWED_GLOBALS[key]
        raise UnsafePickleError(
            f"{self.source} was refused: it asks to call {key}, which could run code on this machine. "
            "Motion files may hold only dicts, lists, strings, numbers and numpy arrays; re-export the motion "
            "as such (or as a .npy array) and do not open files from this source with other tools either."
        )

    def persistent_load(self, pid: Any) -> Any:
        raise UnsafePickleError(f"{self.source} was refused: it uses persistent ids, which motion files never do")


def loads(data: bytes, source: str = "pickle", limits: ScanLimits = DATA_LIMITS) -> Any:
    """Unpickle ``data`` admitting only plain data and numpy arrays, after the bounded scan; ``source`` names it in
    errors."""
    return _load(io.BytesIO(data), len(data), source, limits)


def load_pickle(path: str | os.PathLike, what: str = "motion file", limits: ScanLimits = DATA_LIMITS) -> Any:
    """Read a pickle file admitting only plain data and numpy arrays, after the bounded scan.

    Raises :class:`UnsafePickleError` (a :class:`DataError`) for a refused global and :class:`DataError` for a
    missing, truncated, unreadable or unbounded file (a scan limit), naming the file; nothing is built from a file
    the scan refuses."""
    path = Path(path)
    source = f"{what} {path}"
    if not path.is_file():
        raise DataError(f"{source} does not exist; check the path")
    try:
        size = path.stat().st_size
        if size == 0:
            raise DataError(f"cannot read {source}: it is empty. Nothing was loaded")
        # memory-mapped: the scan and the unpickler read only what the file holds, whatever lengths it declares
        with open(path, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as stream:
            return _load(stream, size, source, limits)
    except OSError as e:
        raise DataError(f"cannot read {source}: {e}") from e


def _load(file: Any, size: int, source: str, limits: ScanLimits) -> Any:
    try:
        scan_stream(file, ScanReport(file_bytes=size), limits, "data")
    except ScanRefused as e:
        raise DataError(f"cannot read {source}: {e}. Nothing was loaded") from None
    file.seek(0)
    try:
        value = _RestrictedUnpickler(file, source).load()
    except DataError:
        raise
    except Exception as e:  # noqa: BLE001 - truncated or corrupt data raises many types (EOFError, ValueError, ...)
        raise DataError(
            f"cannot read {source} ({type(e).__name__}: {e}); it is truncated or not a pickle. "
            "Re-download or re-export it"
        ) from e
    _check_dtypes(value, source)
    return value


def _check_dtypes(value: Any, source: str) -> None:
    """Refuse a result holding a numpy dtype whose fields or sub-array reach outside its items: numpy rebuilds a
    pickled dtype from its stated fields, offsets and size without checking that they fit, and any read of such an
    array reads memory past it. Walks the result once (its size and nesting are bounded by the scan)."""
    todo, seen = [value], set()
    while todo:
        x = todo.pop()
        if id(x) in seen:
            continue
        seen.add(id(x))
        if isinstance(x, dict):
            todo.extend(x.keys())
            todo.extend(x.values())
        elif isinstance(x, list | tuple | set | frozenset):
            todo.extend(x)
        elif isinstance(x, np.ndarray | np.generic | np.dtype):
            dtype = x if isinstance(x, np.dtype) else x.dtype
            problem = _dtype_problem(dtype)
            if problem:
                raise DataError(f"cannot read {source}: {problem}. Nothing was loaded")
            if isinstance(x, np.ndarray) and dtype.hasobject:
                todo.extend(x.ravel(order="K").tolist())


def _dtype_problem(dtype: np.dtype, depth: int = 0) -> str:
    """Why a dtype's layout is impossible (a field or sub-array outside its items), or ""."""
    if depth > 32:
        return "a numpy dtype nests more than 32 levels of fields"
    if dtype.names is not None:
        fields = dtype.fields or {}
        for name in dtype.names:
            if name not in fields:
                return f"a numpy structured dtype names a field {name!r} it does not define"
        for name, (sub, offset, *_) in fields.items():
            if offset < 0 or offset + sub.itemsize > dtype.itemsize:
                return (
                    f"a numpy structured dtype puts field {name!r} ({sub.itemsize} bytes at offset {offset}) outside "
                    f"its {dtype.itemsize}-byte items"
                )
            problem = _dtype_problem(sub, depth + 1)
            if problem:
                return problem
    if dtype.subdtype is not None:
        base, shape = dtype.subdtype
        if base.itemsize * math.prod(shape) > dtype.itemsize:
            return f"a numpy sub-array dtype of shape {shape} does not fit its {dtype.itemsize}-byte items"
        return _dtype_problem(base, depth + 1)
    return ""
