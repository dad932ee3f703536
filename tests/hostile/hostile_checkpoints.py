"""Hand-made checkpoint files that crash, hang or exhaust memory in a plain ``torch.load(weights_only=True)``.

Pickles are written instruction by instruction (the objects they describe cannot be built or pickled in the test
process: hashing the keys would crash or never finish) and packed the way ``torch.save`` packs them: a zip archive
``archive/data.pkl`` + ``archive/data/<key>`` entries, or the legacy stream of pickles followed by raw storage bytes.
Each maker writes ``path`` and returns it; :data:`HOSTILE` names them with the words their refusal must contain.
"""

from __future__ import annotations

import pickle
import struct
import sys
import zipfile
from collections.abc import Callable
from pathlib import Path

import torch

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "interop"))
from edge_format import fitted_normalizer, motion_data, write_edge_checkpoint  # noqa: E402

P = pickle  # opcode constants: P.MARK, P.TUPLE1, ...


def b_int(n: int) -> bytes:
    if 0 <= n < 256:
        return P.BININT1 + bytes([n])
    if -(2**31) <= n < 2**31:
        return P.BININT + struct.pack("<i", n)
    data = pickle.encode_long(n)
    return P.LONG1 + bytes([len(data)]) + data


def b_str(text: str) -> bytes:
    data = text.encode()
    return P.BINUNICODE + struct.pack("<I", len(data)) + data


def b_global(module: str, name: str) -> bytes:
    return P.GLOBAL + f"{module}\n{name}\n".encode()


def b_tuple(*items: bytes) -> bytes:
    return P.MARK + b"".join(items) + P.TUPLE


def put(i: int) -> bytes:
    return P.BINPUT + bytes([i]) if i < 256 else P.LONG_BINPUT + struct.pack("<I", i)


def get(i: int) -> bytes:
    return P.BINGET + bytes([i]) if i < 256 else P.LONG_BINGET + struct.pack("<I", i)


def b_storage(numel: int, key: str = "0", kind: str = "FloatStorage", legacy: bool = False) -> bytes:
    """A persistent id of torch storage ``key`` with ``numel`` elements."""
    pid = [b_str("storage"), b_global("torch", kind), b_str(key), b_str("cpu"), b_int(numel)]
    return b_tuple(*pid, *([P.NONE] if legacy else [])) + P.BINPERSID


def b_tensor(storage: bytes, size: tuple[int, ...], stride: tuple[int, ...], offset: int = 0) -> bytes:
    """``torch._utils._rebuild_tensor_v2(storage, offset, size, stride, False, OrderedDict())``."""
    ordered = b_global("collections", "OrderedDict") + P.EMPTY_TUPLE + P.REDUCE
    args = b_tuple(
        storage, b_int(offset), b_tuple(*map(b_int, size)), b_tuple(*map(b_int, stride)), P.NEWFALSE, ordered
    )
    return b_global("torch._utils", "_rebuild_tensor_v2") + args + P.REDUCE


def b_dict(*pairs: tuple[bytes, bytes]) -> bytes:
    return P.EMPTY_DICT + (P.MARK + b"".join(k + v for k, v in pairs) + P.SETITEMS if pairs else b"")


def pickled(body: bytes) -> bytes:
    return P.PROTO + b"\x02" + body + P.STOP


def torch_zip(path: Path, data_pkl: bytes, records: dict[str, bytes] | None = None, compress: bool = False) -> Path:
    """Pack a pickle (and storage records) the way torch.save does."""
    method = zipfile.ZIP_DEFLATED if compress else zipfile.ZIP_STORED
    with zipfile.ZipFile(path, "w", compression=method) as z:
        z.writestr("archive/data.pkl", data_pkl)
        z.writestr("archive/byteorder", "little")
        for key, data in (records or {}).items():
            z.writestr(f"archive/data/{key}", data)
        z.writestr("archive/version", "3\n")
    return path


def legacy_file(path: Path, main: bytes, keys: list[str], data: bytes) -> Path:
    """torch's legacy format: magic number, protocol, system info, the object, the storage keys, raw storages."""
    magic = pickle.dumps(0x1950A86A20F9469CFC6C, protocol=2)
    info = pickle.dumps({"protocol_version": 1001, "little_endian": True, "type_sizes": {"int": 4, "long": 4}}, 2)
    path.write_bytes(magic + pickle.dumps(1001, protocol=2) + info + main + pickle.dumps(keys, protocol=2) + data)
    return path


# --- the files -----------------------------------------------------------------------------------------------------
def deep_key_pickle(levels: int = 1_000_000) -> bytes:
    """A pickle of a dict whose key is nested ``levels`` tuples deep (hashing it overflows the C stack)."""
    return pickled(P.EMPTY_DICT + b_int(0) + P.TUPLE1 * levels + b_int(1) + P.SETITEM)


def shared_pair_pickle(levels: int = 64) -> bytes:
    """A pickle of a dict whose key is ``x = (x, x)`` ``levels`` times through the memo (2^levels hash calls)."""
    body = P.EMPTY_DICT + b_int(0) + put(0)
    for i in range(levels):
        body += get(i) + P.TUPLE2 + put(i + 1)
    return pickled(body + b_int(1) + P.SETITEM)


def deep_key(path: Path) -> Path:
    """The issue's first file: a dict key nested 10^6 tuples deep (hashing it overflows the C stack)."""
    return torch_zip(path, deep_key_pickle())


def shared_pair_key(path: Path, levels: int = 64) -> Path:
    """The issue's second file: ``x = (x, x)`` 64 times through the memo, used as a key (2^64 hash calls)."""
    return torch_zip(path, shared_pair_pickle(levels))


def broadcast_view(path: Path) -> Path:
    """The issue's third file: EDGE's format with a scaler statistic that is one stored float viewed as 2^50
    elements with stride 0 (a few KB on disk; a copy of it asks for 4 PB)."""

    def make(Normalizer, MinMaxScaler):
        n = fitted_normalizer(Normalizer, MinMaxScaler, motion_data(n=1, seq=2))
        n.scaler.scale_ = torch.ones(1).expand(2**50)
        return n

    write_edge_checkpoint(path, 35, normalizer=make, d=8, layers=1, heads=2, ff=8, seq=2)
    return path


def _edge_scaler_with(**attributes) -> Callable[[Path], Path]:
    def write(path: Path) -> Path:
        def make(Normalizer, MinMaxScaler):
            n = fitted_normalizer(Normalizer, MinMaxScaler, motion_data(n=1, seq=2))
            for name, value in attributes.items():
                setattr(n.scaler, name, value)
            return n

        write_edge_checkpoint(path, 35, normalizer=make, d=8, layers=1, heads=2, ff=8, seq=2)
        return path

    return write


def wrapped_broadcast_view(path: Path) -> Path:
    """The stride-0 view inside ``torch._tensor._rebuild_from_type_v2`` (the rebuild of tensor subclasses), which
    calls the inner rebuild itself."""
    inner = b_global("torch._utils", "_rebuild_tensor_v2")
    ordered = b_global("collections", "OrderedDict") + P.EMPTY_TUPLE + P.REDUCE
    view = b_tuple(b_storage(1), b_int(0), b_tuple(b_int(2**50)), b_tuple(b_int(0)), P.NEWFALSE, ordered)
    call = (
        b_global("torch._tensor", "_rebuild_from_type_v2")
        + b_tuple(inner, b_global("torch", "Tensor"), view, P.EMPTY_DICT)
        + P.REDUCE
    )
    return torch_zip(path, pickled(b_dict((b_str("w"), call))), {"0": bytes(4)})


def huge_storage(path: Path) -> Path:
    """A storage declared with 2^50 floats in a file of a few hundred bytes."""
    return torch_zip(path, pickled(b_dict((b_str("w"), b_tensor(b_storage(2**50), (4,), (1,))))), {"0": bytes(16)})


def view_past_storage(path: Path) -> Path:
    """A 4-element storage viewed as 1000 elements."""
    return torch_zip(path, pickled(b_dict((b_str("w"), b_tensor(b_storage(4), (1000,), (1,))))), {"0": bytes(16)})


def zip_bomb(path: Path) -> Path:
    """A tiny checkpoint with a 200 MB deflated entry beside it."""
    torch_zip(path, pickled(b_dict()), compress=True)
    with zipfile.ZipFile(path, "a", compression=zipfile.ZIP_DEFLATED) as z:
        z.writestr("archive/data/0", bytes(200 << 20))
    return path


def many_instructions(path: Path) -> Path:
    """A list of 600,000 small integers (more pickle instructions than the limit)."""
    return torch_zip(path, pickled(P.EMPTY_LIST + P.MARK + b_int(1) * 600_000 + P.APPENDS))


def many_storages(path: Path) -> Path:
    """60,000 empty storages (just under the instruction limit), whose data entries are missing: the scan's
    bookkeeping must stay linear in their number."""
    views = b"".join(b_storage(0, key=str(i)) for i in range(60_000))
    return torch_zip(path, pickled(P.EMPTY_LIST + P.MARK + views + P.APPENDS))


def shared_arguments(path: Path) -> Path:
    """100,000 calls of one function on one 1,000-number tuple fetched from the memo (10^8 objects unfolded; checking
    each call's sizes must not walk the tuple each time)."""
    body = P.EMPTY_LIST + b_global("builtins", "bytearray") + put(0) + P.MARK + b_int(1) * 1000 + P.TUPLE + put(1)
    body += P.MARK + (get(0) + get(1) + P.REDUCE) * 100_000 + P.APPENDS
    return torch_zip(path, pickled(body))


def self_containing_list(path: Path) -> Path:
    return torch_zip(path, pickled(P.EMPTY_LIST + put(0) + get(0) + P.APPEND))


def bytearray_bomb(path: Path) -> Path:
    """``bytearray(2**40)``: a global torch allows, called with a size far larger than the file."""
    return torch_zip(
        path, pickled(b_dict((b_str("x"), b_global("builtins", "bytearray") + b_tuple(b_int(2**40)) + P.REDUCE)))
    )


def legacy_huge_storage(path: Path) -> Path:
    """The legacy (non-zip) format, declaring a 2^40-float storage with 16 bytes of data after it."""
    main = pickled(b_dict((b_str("w"), b_tensor(b_storage(2**40, legacy=True), (4,), (1,)))))
    return legacy_file(path, main, ["0"], struct.pack("<q", 4) + bytes(16))


def broadcast_state(path: Path) -> Path:
    """A project-style checkpoint whose one weight is a stored float viewed as 2^50 elements (stride 0)."""
    torch.save({"hyper_parameters": {}, "state_dict": {"w": torch.ones(1).expand(2**50)}}, path)
    return path


def not_a_checkpoint(path: Path) -> Path:
    path.write_bytes(b"PK\x03\x04" + b"this is no zip archive" * 10)
    return path


HOSTILE: dict[str, tuple[Callable[[Path], Path], str]] = {
    "deep key": (deep_key, "nested more than 100 levels"),
    "shared (x, x) key": (shared_pair_key, "unfolds to more than"),
    "stride-0 view of 2^50": (broadcast_view, "larger than the whole"),
    "scaler clip is a tensor": (_edge_scaler_with(clip=torch.ones(2)), "clip"),
    "scaler feature_range of strings": (_edge_scaler_with(feature_range=("a", "b")), "feature_range"),
    "stride-0 view in a subclass rebuild": (wrapped_broadcast_view, "larger than the whole"),
    "storage of 2^50 floats": (huge_storage, "bytes of tensor storage"),
    "view past its storage": (view_past_storage, "reaches element 999"),
    "zip bomb": (zip_bomb, "zip bomb"),
    "600k instructions": (many_instructions, "instructions (the limit)"),
    "stride-0 weight": (broadcast_state, "larger than the whole"),
    "60k empty storages": (many_storages, "data entry is missing"),
    "100k calls sharing their arguments": (shared_arguments, "unfolds to more than"),
    "list containing itself": (self_containing_list, "contains itself"),
    "bytearray(2^40)": (bytearray_bomb, "builtins.bytearray with sizes"),
    "legacy format, huge storage": (legacy_huge_storage, "bytes of tensor storage"),
    "PK header, no zip": (not_a_checkpoint, "not a readable zip"),
}
"""name -> (maker, a fragment of its refusal). The first five are the issue's files."""
HEAVY = ("600k instructions", "60k empty storages", "100k calls sharing their arguments")
"""Files that take a second or more of scanning; the scan is the same for every loader, so tests run them once."""
EDGE_ONLY = ("stride-0 view of 2^50", "scaler clip is a tensor", "scaler feature_range of strings")
"""Files that are EDGE checkpoints (EDGE's normaliser classes): other loaders refuse them for those classes."""
