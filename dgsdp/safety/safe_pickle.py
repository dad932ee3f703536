"""Reading motion pickles as data: no code from them runs, and numpy builds nothing from their bytes unchecked.

A pickle names Python functions that the reader calls while loading (``os.system``, ``builtins.exec``,
``functools.partial``, ...), so plain ``pickle.load`` on a file someone sent you runs their code. Motion files
(AIST++ ``.pkl``, seed motions, keyframes, evaluation inputs) only ever hold dicts, lists and tuples of strings,
numbers and plain numeric numpy arrays, so :func:`load_pickle` admits exactly the globals those are written with and
refuses any other with an :class:`UnsafePickleError` naming the file and the refused global, before anything is
called.

numpy's own unpickling functions never see a user's bytes either: they trust what a pickle states (an object array
whose shape claims more items than its list holds, a structured dtype whose fields lie outside its items, a dtype
string that hides a size) and read or write memory past the array. Here the names of numpy's functions are bound to
placeholders that only record what the pickle asks for; :class:`_ArrayStub` checks a rebuilt array's shape, dtype
code and raw bytes as data and builds the array with :func:`numpy.frombuffer`. A motion pickle may hold arrays only
in the forms numpy writes them (``_reconstruct`` then ``BUILD``, or protocol 5's ``_frombuffer``), of plain numeric
dtypes (bool, integers, floats, complex; no object, void, structured, sub-array or datetime dtypes), with exactly the
bytes their shape needs; anything else is one :class:`~dgsdp.errors.DataError`.

Plain data can still crash or hang the reader: a dict key nested a million tuples deep, memo-shared tuples that
unfold to 2^64 objects when hashed. So every pickle is first scanned with the bounded scan checkpoints go through
(:mod:`dgsdp.safety.pickle_scan`, its ``"data"`` kind and :data:`~dgsdp.safety.pickle_scan.DATA_LIMITS`).
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
from dgsdp.safety.pickle_scan import DATA_LIMITS, ScanLimits, ScanRefused, ScanReport, scan_stream


class UnsafePickleError(DataError):
    """A pickle asks for a Python global outside the allowlist (it would run code when loaded)."""


def _latin1_encode(text: str, encoding: str = "utf-8") -> bytes:
    """``_codecs.encode`` as pickles of protocol 0-2 use it for bytes: text codecs only (no zlib/base64 tricks)."""
    if not isinstance(text, str) or codecs.lookup(encoding).name not in ("iso8859-1", "utf-8", "ascii"):
        raise pickle.UnpicklingError(f"_codecs.encode({type(text).__name__}, {encoding!r}) is not allowed")
    return codecs.encode(text, encoding)


# --- numpy, as data -------------------------------------------------------------------------------------------
MAX_DIMS = 32
# The dtype codes numpy pickles plain numeric dtypes with: bool, integers, floats, complex numbers.
PLAIN_DTYPE_CODES = frozenset(["b1", "f2", "f4", "f8", "c8", "c16"] + [f"{k}{n}" for k in "iu" for n in (1, 2, 4, 8)])
_BYTE_ORDERS = frozenset("<>|=")


class _Refused(pickle.UnpicklingError):
    """What a placeholder refuses (the reader turns it into one DataError naming the file)."""


class _Stub:
    """A placeholder made while unpickling in place of a numpy object; :func:`_resolve` swaps it for the real one."""

    __slots__ = ()

    def __reduce__(self) -> Any:  # never pickled again, never copied
        raise TypeError(f"{type(self).__name__} is a loading placeholder")


class _NdarrayName(_Stub):
    """What the global ``numpy.ndarray`` stands for: a name ``_reconstruct`` is given, never a class to call."""

    __slots__ = ()

    def __call__(self, *args: Any, **kwargs: Any) -> Any:
        raise _Refused(
            "it builds a numpy array by calling numpy.ndarray directly; motion files hold arrays only as numpy "
            "writes them (_reconstruct, then its state)"
        )


_NDARRAY = _NdarrayName()


class _DtypeStub(_Stub):
    """``numpy.dtype(code, align, copy)`` and its ``BUILD`` state, checked when an array or scalar uses it."""

    __slots__ = ("code", "state", "built")

    def __init__(self, code: Any) -> None:
        self.code, self.state, self.built = code, None, None

    def __setstate__(self, state: Any) -> None:
        if self.state is not None:
            raise _Refused("it sets a numpy dtype's state twice")
        self.state = state

    def dtype(self) -> np.dtype:
        if self.built is None:
            self.built = _plain_dtype(self.code, self.state)
        return self.built


def _plain_dtype(code: Any, state: Any) -> np.dtype:
    """A plain numeric dtype from its pickled code (``"f8"``) and state ``(version, byte order, subarray, names,
    fields, elsize, alignment, flags[, metadata])``; anything that is not one is refused."""
    if not isinstance(code, str) or code not in PLAIN_DTYPE_CODES:
        raise _Refused(
            f"it holds a numpy array of dtype {str(code)[:40]!r}; motion files hold only plain numeric arrays "
            "(bool, integers, floats, complex: no object, void, structured, sub-array or text dtypes)"
        )
    dtype = np.dtype(code)
    if state is None:
        return dtype
    plain = (
        isinstance(state, tuple)
        and len(state) in (8, 9)
        and state[0] in (3, 4)
        and state[1] in _BYTE_ORDERS
        and state[2:5] == (None, None, None)
        and state[5:7] == (-1, -1)
        and state[7] == 0
        and (len(state) == 8 or state[8] is None)
    )
    if not plain:
        raise _Refused(
            f"it gives the numpy dtype {code!r} fields, a sub-array, a size or flags of its own; motion files hold "
            "only plain numeric arrays"
        )
    return dtype.newbyteorder(state[1]) if state[1] in "<>" else dtype


def _dtype_of(value: Any) -> np.dtype:
    if not isinstance(value, _DtypeStub):
        raise _Refused(f"it gives a numpy array a dtype that is a {type(value).__name__}, not a numpy dtype")
    return value.dtype()


def _shape_of(value: Any) -> tuple[int, ...]:
    if not isinstance(value, tuple) or len(value) > MAX_DIMS or not all(type(n) is int and n >= 0 for n in value):
        raise _Refused(f"it gives a numpy array a shape that is not a tuple of at most {MAX_DIMS} integers >= 0")
    return value


def _array_from_bytes(data: Any, dtype: np.dtype, shape: tuple[int, ...], fortran: bool) -> np.ndarray:
    """The array ``shape`` of ``dtype`` whose elements are ``data``'s bytes, exactly as many as it needs (so its
    size is bounded by the file's); a fresh, writable copy."""
    if not isinstance(data, bytes | bytearray):
        raise _Refused(
            f"it gives a numpy array its elements as a {type(data).__name__}, not as raw bytes (object arrays are "
            "not motion data)"
        )
    count = math.prod(shape)
    if count * dtype.itemsize != len(data):
        raise _Refused(
            f"it rebuilds a numpy array of shape {shape} and dtype {dtype.str} ({count * dtype.itemsize:,} bytes) "
            f"from {len(data):,} bytes"
        )
    order = "F" if fortran else "C"
    return np.frombuffer(data, dtype=dtype, count=count).reshape(shape, order=order).copy(order=order)


class _ArrayStub(_Stub):
    """``_reconstruct(ndarray, (0,), b"b")``: an array whose shape, dtype and bytes come with ``BUILD``."""

    __slots__ = ("array",)

    def __init__(self) -> None:
        self.array: np.ndarray | None = None

    def __setstate__(self, state: Any) -> None:
        if self.array is not None:
            raise _Refused("it sets a numpy array's state twice")
        if not isinstance(state, tuple) or len(state) not in (4, 5) or (len(state) == 5 and state[0] != 1):
            raise _Refused("it gives a numpy array a state other than numpy's (version, shape, dtype, order, data)")
        shape, dtype, fortran, data = state[-4:]
        if type(fortran) is not bool and fortran not in (0, 1):
            raise _Refused("it gives a numpy array an order flag that is not a boolean")
        array = _array_from_bytes(data, _dtype_of(dtype), _shape_of(shape), bool(fortran))
        # numpy's own unpickler gives arrays of this form in the machine's byte order
        self.array = array if array.dtype.isnative else array.astype(array.dtype.newbyteorder("="), order="K")


class _BuiltStub(_Stub):
    """An array or scalar already built from checked data; a state given to it is refused."""

    __slots__ = ("value",)

    def __init__(self, value: Any) -> None:
        self.value = value

    def __setstate__(self, state: Any) -> None:
        raise _Refused("it sets the state of a numpy array built from a buffer or of a numpy scalar")


def _reconstruct(cls: Any, shape: Any, typecode: Any) -> _ArrayStub:
    """numpy's ``multiarray._reconstruct`` as numpy's pickles call it: ``(ndarray, (0,), b"b")``."""
    if cls is not _NDARRAY or shape != (0,) or typecode not in (b"b", "b"):
        raise _Refused(
            "it calls numpy's _reconstruct with arguments numpy never writes (only ndarray, (0,) and 'b'; the "
            "shape and dtype come with the array's state)"
        )
    return _ArrayStub()


def _frombuffer(buffer: Any, dtype: Any, shape: Any, order: Any) -> _BuiltStub:
    """numpy's ``numeric._frombuffer`` as protocol 5 pickles call it for contiguous arrays."""
    if order not in ("C", "F"):
        raise _Refused("it rebuilds a numpy array from a buffer with an order other than 'C' or 'F'")
    return _BuiltStub(_array_from_bytes(buffer, _dtype_of(dtype), _shape_of(shape), order == "F"))


def _scalar(dtype: Any, data: Any = None) -> _BuiltStub:
    """numpy's ``multiarray.scalar(dtype, bytes)``: one plain numeric number."""
    return _BuiltStub(_array_from_bytes(data, _dtype_of(dtype), (), False)[()])


def _dtype(code: Any, align: Any = False, copy: Any = False) -> _DtypeStub:
    """``numpy.dtype(code, align, copy)``: recorded, checked when used."""
    if align not in (False, 0) or copy not in (True, False, 0, 1):
        raise _Refused("it makes a numpy dtype with alignment, which motion files never have")
    return _DtypeStub(code)


def _numpy_globals() -> dict[str, Any]:
    found = {"multiarray._reconstruct": _reconstruct, "multiarray.scalar": _scalar, "numeric._frombuffer": _frombuffer}
    out: dict[str, Any] = {"numpy.ndarray": _NDARRAY, "numpy.dtype": _dtype}
    for package in ("numpy._core", "numpy.core"):  # numpy >= 2 and numpy 1 name them so
        for name, obj in found.items():
            out[f"{package}.{name}"] = obj
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
"""``"module.name"`` -> what a pickle gets for it (numpy's names: placeholders); everything else is refused."""


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
    """Read a pickle file admitting only plain data and plain numeric numpy arrays, after the bounded scan.

    Raises :class:`UnsafePickleError` (a :class:`DataError`) for a refused global and :class:`DataError` for a
    missing, truncated, unreadable or unbounded file (a scan limit) or an array numpy does not write, naming the
    file; nothing is returned from a file that is refused."""
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
        file.seek(0)
        return _resolve(_RestrictedUnpickler(file, source).load(), {})
    except ScanRefused as e:
        raise DataError(f"cannot read {source}: {e}. Nothing was loaded") from None
    except _Refused as e:
        raise DataError(f"cannot read {source}: {e}. Nothing was loaded") from None
    except DataError:
        raise
    except MemoryError:
        raise DataError(
            f"cannot read {source}: it needs more memory than this machine has. Nothing was loaded"
        ) from None
    except Exception as e:  # noqa: BLE001 - truncated or corrupt data raises many types (EOFError, ValueError, ...)
        raise DataError(
            f"cannot read {source} ({type(e).__name__}: {e}); it is truncated or not a pickle. "
            "Re-download or re-export it"
        ) from e


_LEAF_TYPES = frozenset((int, float, str, bytes, bool, complex, type(None)))


def _resolve(value: Any, done: dict[int, Any]) -> Any:
    """``value`` with every placeholder swapped for the numpy object it stands for; lists and dicts are changed in
    place and shared objects stay shared (``done``: id -> result). The scan bounds the nesting (no object holds
    itself), so the recursion is shallow."""
    if type(value) in _LEAF_TYPES:
        return value
    key = id(value)
    if key in done:
        return done[key]
    if isinstance(value, _Stub):
        if isinstance(value, _ArrayStub):
            if value.array is None:
                raise _Refused("it starts a numpy array that it never gives a shape, dtype and data")
            out: Any = value.array
        elif isinstance(value, _BuiltStub):
            out = value.value
        elif isinstance(value, _DtypeStub):
            out = value.dtype()
        else:
            raise _Refused("it holds the name numpy.ndarray itself, which motion data never does")
    elif isinstance(value, list):
        done[key] = value
        value[:] = [_resolve(v, done) for v in value]
        out = value
    elif isinstance(value, dict):
        done[key] = value
        items = [(_resolve(k, done), _resolve(v, done)) for k, v in value.items()]
        value.clear()
        value.update(items)
        out = value
    elif isinstance(value, tuple | set | frozenset):
        items = [_resolve(v, done) for v in value]
        same = all(a is b for a, b in zip(items, value, strict=True))
        out = value if same else type(value)(items)
    else:
        out = value
    done[key] = out
    return out
