"""Reading motion pickles without running code from them.

A pickle names Python functions that the reader calls while loading (``os.system``, ``builtins.exec``,
``functools.partial``, ...), so plain ``pickle.load`` on a file someone sent you runs their code. Motion files
(AIST++ ``.pkl``, seed motions, keyframes, evaluation inputs) only ever hold dicts, lists and tuples of strings,
numbers and numpy arrays, so :func:`load_pickle` admits exactly the globals that numpy and Python need to rebuild
those (numpy's array and scalar reconstructors, ``numpy.dtype``, ``set``...) and refuses any other with an
:class:`UnsafePickleError` naming the file and the refused global, before anything is called.
"""

from __future__ import annotations

import codecs
import collections
import io
import os
import pickle
from pathlib import Path
from typing import Any

import numpy as np

from dgsdp.errors import DataError

MAX_BYTES_ALLOCATION = 1 << 30
"""Largest ``bytes(n)`` a pickle may ask for (1 GiB), so a tiny file cannot demand unbounded memory."""


class UnsafePickleError(DataError):
    """A pickle asks for a Python global outside the allowlist (it would run code when loaded)."""


def _latin1_encode(text: str, encoding: str = "utf-8") -> bytes:
    """``_codecs.encode`` as pickles of protocol 0-2 use it for bytes: text codecs only (no zlib/base64 tricks)."""
    if not isinstance(text, str) or codecs.lookup(encoding).name not in ("iso8859-1", "utf-8", "ascii"):
        raise pickle.UnpicklingError(f"_codecs.encode({type(text).__name__}, {encoding!r}) is not allowed")
    return codecs.encode(text, encoding)


def _bytes(*args: Any) -> bytes:
    if args and isinstance(args[0], int) and not 0 <= args[0] <= MAX_BYTES_ALLOCATION:
        raise pickle.UnpicklingError(f"bytes({args[0]}) asks for too much memory")
    return bytes(*args)


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
        for name, obj in (("set", set), ("frozenset", frozenset), ("complex", complex), ("bytes", _bytes),
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


def loads(data: bytes, source: str = "pickle") -> Any:
    """Unpickle ``data`` admitting only plain data and numpy arrays; ``source`` names it in errors."""
    return _load(io.BytesIO(data), source)


def load_pickle(path: str | os.PathLike, what: str = "motion file") -> Any:
    """Read a pickle file admitting only plain data and numpy arrays.

    Raises :class:`UnsafePickleError` (a :class:`DataError`) for a refused global and :class:`DataError` for a
    missing, truncated or otherwise unreadable file, naming the file."""
    path = Path(path)
    source = f"{what} {path}"
    if not path.is_file():
        raise DataError(f"{source} does not exist; check the path")
    with open(path, "rb") as f:
        return _load(f, source)


def _load(file: io.BufferedIOBase, source: str) -> Any:
    try:
        return _RestrictedUnpickler(file, source).load()
    except DataError:
        raise
    except Exception as e:  # noqa: BLE001 - truncated or corrupt data raises many types (EOFError, ValueError, ...)
        raise DataError(
            f"cannot read {source} ({type(e).__name__}: {e}); it is truncated or not a pickle. "
            "Re-download or re-export it"
        ) from e
