"""Loading a checkpoint file we were given: a bounded scan of its pickle stream, then torch's weights-only loader.

``torch.load(weights_only=True)`` runs no code from a file, but it still builds whatever the pickle describes: a
dict key nested a million tuples deep crashes the interpreter when it is hashed, a shared ``(x, x)`` fetched 64
levels deep through the pickle's memo hashes 2^64 times, a 2 KB file can declare petabytes of tensor storage or a
stride-0 view of 2^50 elements. :func:`scan_checkpoint` walks the pickle's instructions first
(:func:`pickletools.genops`, which builds no objects), keeping only a light record of what each instruction would
make, and refuses a file whose nesting, unfolded size, instruction count, declared storage or tensor views exceed
:data:`LIMITS`, or whose zip entries unpack to far more than the file. :func:`load_checkpoint` is the one way this
package opens a checkpoint file (project checkpoints, EDGE's, Jukebox weights): scan, then ``torch.load`` with
weights only, every failure as one :class:`~dgsdp.errors.CheckpointError` naming the file. docs/security.md
explains the limits.
"""

from __future__ import annotations

import _compat_pickle
import contextlib
import io
import math
import mmap
import pickle
import pickletools
import re
import tarfile
import zipfile
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from dgsdp.errors import CheckpointError, UnsafeCheckpointError


@dataclass(frozen=True)
class ScanLimits:
    """Bounds on a checkpoint's pickle stream (docs/security.md gives the measured values they sit above)."""

    max_opcodes: int = 500_000  # pickle instructions; a paper-size training checkpoint has 63,494
    max_depth: int = 100  # containers inside containers (and calls); project checkpoints nest 6 to 9 deep
    max_unfolded: int = 2_000_000  # objects, each shared (memo) reference counted every time it is used: 31,462
    max_view_ratio: float = 4.0  # all tensor views together, in bytes, at most this many times the file
    max_zip_ratio: float = 2.0  # zip entries' unpacked size at most this many times the file (torch stores them)


LIMITS = ScanLimits()

ZIP_MAGIC = b"PK\x03\x04"  # torch.load takes a file for a zip archive when it starts with a local file header
# The pickle instructions torch's weights-only unpickler executes; it refuses every other one.
TORCH_OPCODES = frozenset(
    "GLOBAL NEWOBJ REDUCE BUILD APPEND APPENDS SETITEM SETITEMS MARK TUPLE TUPLE1 TUPLE2 TUPLE3 NONE NEWFALSE "
    "NEWTRUE EMPTY_TUPLE EMPTY_LIST EMPTY_DICT EMPTY_SET BININT BININT1 BININT2 BINFLOAT BINUNICODE "
    "SHORT_BINSTRING BINPERSID BINGET LONG_BINGET BINPUT LONG_BINPUT LONG1 PROTO STOP".split()
)
# Tensor rebuilds whose (storage, offset, size, stride, ...) arguments are checked against their storage.
VIEW_REBUILDS = frozenset(f"torch._utils._rebuild_tensor{v}" for v in ("", "_v2", "_v3"))
FROM_TYPE_REBUILD = "torch._tensor._rebuild_from_type_v2"  # tensor subclasses: calls another rebuild itself
# Rebuilds that only wrap a tensor made by one of the above.
WRAPPING_REBUILDS = frozenset(
    (
        "torch._utils._rebuild_parameter",
        "torch._utils._rebuild_parameter_with_state",
    )
)
MAX_DIMS = 64


class _Refused(Exception):
    """A reason to refuse the file (turned into a CheckpointError naming it)."""


class _Node:
    """What one pickle instruction would make: a kind, a small value (ints, short strings, global names, storage
    facts), the nodes it holds, and its nesting depth and unfolded size as far as known when it was made."""

    __slots__ = ("kind", "value", "children", "depth", "unfolded")

    def __init__(self, kind: str, value: Any = None, children: list[_Node] | None = None) -> None:
        self.kind, self.value, self.children = kind, value, children
        if children:
            self.depth = 1 + max(c.depth for c in children)
            self.unfolded = 1 + sum(c.unfolded for c in children)
        else:
            self.depth, self.unfolded = 1, 1


_LEAF = _Node("leaf")  # None, booleans, floats: nothing to check in them


@dataclass
class ScanReport:
    """What the scan measured (for the limits' documentation and for tests)."""

    file_bytes: int
    opcodes: int = 0
    depth: int = 0
    unfolded: int = 0
    max_memo_fetches: int = 0  # most fetches of any one memo entry
    storages: int = 0
    storage_bytes: int = 0
    view_bytes: int = 0
    largest_view_bytes: int = 0


class _PickleScan:
    """Runs the pickle machine on light nodes for one or more consecutive pickles of a file."""

    def __init__(self, report: ScanReport, limits: ScanLimits) -> None:
        self.report, self.limits = report, limits
        self.composites: list[_Node] = []  # every node holding others (its figures are settled by finish)
        self.storages: dict[str, int] = {}  # storage key -> bytes declared
        self.memo_fetches: dict[int, int] = {}
        self.products: dict[int, int] = {}  # id of a tuple node -> the product of its integers (int_product)

    # --- the machine ------------------------------------------------------------------------------------------
    def run(self, stream: Any) -> _Node:
        """Scan one pickle (up to its STOP) from ``stream``; returns the node of the object it would return."""
        stack: list[_Node] = []
        marks: list[list[_Node]] = []
        memo: dict[int, _Node] = {}
        report, max_opcodes, fetches = self.report, self.limits.max_opcodes, self.memo_fetches
        try:
            for opcode, arg, _ in pickletools.genops(stream):
                report.opcodes += 1
                if report.opcodes > max_opcodes:
                    raise _Refused(f"its pickle has more than {max_opcodes:,} instructions (the limit)")
                name = opcode.name
                if name in ("BINPUT", "LONG_BINPUT"):  # the most frequent instructions first
                    memo[arg] = stack[-1]
                elif name in ("BINGET", "LONG_BINGET"):
                    if arg not in memo:
                        raise _Refused(f"its pickle fetches memo entry {arg}, which it never stored")
                    fetches[arg] = fetches.get(arg, 0) + 1
                    stack.append(memo[arg])
                elif name in ("BININT", "BININT1", "BININT2", "LONG1"):
                    stack.append(_Node("int", arg))
                elif name not in TORCH_OPCODES:
                    raise _Refused(f"its pickle uses the instruction {name}, which PyTorch checkpoints never contain")
                elif name == "MARK":
                    marks.append(stack)
                    stack = []
                elif name in ("TUPLE", "APPENDS", "SETITEMS"):
                    items, stack = stack, marks.pop()
                    if name == "TUPLE":
                        stack.append(self.made(_Node("tuple", None, items)))
                    else:
                        self.grow(stack[-1], items)
                elif name in ("TUPLE1", "TUPLE2", "TUPLE3"):
                    n = int(name[-1])
                    items = stack[-n:]
                    if len(items) != n:
                        raise IndexError
                    del stack[-n:]
                    stack.append(self.made(_Node("tuple", None, items)))
                elif name in ("APPEND", "SETITEM", "BUILD"):
                    n = 2 if name == "SETITEM" else 1
                    items = stack[-n:]
                    if len(items) != n:
                        raise IndexError
                    del stack[-n:]
                    if name == "BUILD":
                        self.check_build(stack[-1], items[0])
                    self.grow(stack[-1], items)
                elif name in ("REDUCE", "NEWOBJ"):
                    args = stack.pop()
                    func = stack.pop()
                    self.check_call(func, args)
                    stack.append(self.made(_Node("call", func.value if func.kind == "global" else None, [func, args])))
                elif name in ("EMPTY_LIST", "EMPTY_DICT", "EMPTY_SET"):
                    stack.append(self.made(_Node("container", None, [])))
                elif name == "EMPTY_TUPLE":
                    stack.append(self.made(_Node("tuple", None, [])))
                elif name in ("BINUNICODE", "SHORT_BINSTRING"):
                    text = arg if isinstance(arg, str) else arg.decode("latin-1")
                    stack.append(_Node("str", text if len(text) <= 256 else None))
                elif name == "GLOBAL":
                    module, _, attr = arg.partition(" ")
                    module, attr = _compat_pickle.NAME_MAPPING.get((module, attr), (module, attr))
                    module = _compat_pickle.IMPORT_MAPPING.get(module, module)
                    stack.append(_Node("global", f"{module}.{attr}"))
                elif name == "BINPERSID":
                    stack.append(self.storage(stack.pop()))
                elif name in ("NONE", "NEWFALSE", "NEWTRUE", "BINFLOAT"):
                    stack.append(_LEAF)
                elif name == "STOP":
                    root = stack.pop()
                    if stack or marks:
                        raise _Refused("its pickle stops with objects left over; it is malformed")
                    return root
                # PROTO: nothing to do
        except _Refused:
            raise
        except IndexError as e:  # stack or mark underflow
            raise _Refused("its pickle takes more objects than it made; it is malformed") from e
        except (ValueError, EOFError, OverflowError, UnicodeDecodeError) as e:
            raise _Refused(f"it is truncated or not a PyTorch checkpoint (its pickle: {e})") from e
        raise _Refused("its pickle ends without a STOP instruction; it is truncated")

    def made(self, node: _Node) -> _Node:
        """Check a new node's depth and unfolded size as far as known now (exact unless it holds a list or dict
        that grows later)."""
        self.composites.append(node)
        self.check_size(node.depth, node.unfolded)
        return node

    def grow(self, target: _Node, items: list[_Node]) -> None:
        """Items added to a list, dict or object; its parents' figures are settled by :meth:`finish`."""
        if target.children is None:  # torch refuses this too; nothing more to learn from the file
            raise _Refused("its pickle adds items to a number or string; it is malformed")
        target.kind = "container"
        target.children.extend(items)
        target.depth = max(target.depth, 1 + max(i.depth for i in items))
        target.unfolded += sum(i.unfolded for i in items)
        self.check_size(target.depth, target.unfolded)

    def check_size(self, depth: int, unfolded: int) -> None:
        if depth > self.limits.max_depth:
            raise _Refused(
                f"its objects are nested more than {self.limits.max_depth} levels deep (the limit; checkpoints "
                "nest about 10); reading it would crash the interpreter"
            )
        if unfolded > self.limits.max_unfolded:
            raise _Refused(
                f"it reuses stored objects (pickle memo) so that its data unfolds to more than "
                f"{self.limits.max_unfolded:,} objects (the limit); reading it would not finish"
            )

    def finish(self) -> None:
        """Exact depth and unfolded size of everything made, now that every container is complete (all of it, not
        only what the result holds: an object dropped on the way was still built and hashed)."""
        done: dict[int, tuple[int, int]] = {}
        for start in self.composites:
            if id(start) in done:
                continue
            path: list[tuple[_Node, Iterator[_Node]]] = [(start, iter(start.children or ()))]
            on_path = {id(start)}
            while path:
                node, children = path[-1]
                child = next(children, None)
                if child is None:
                    path.pop()
                    on_path.discard(id(node))
                    depth, unfolded = 1, 1
                    for c in node.children or ():
                        d, u = done.get(id(c), (c.depth, c.unfolded))
                        depth, unfolded = max(depth, d + 1), min(unfolded + u, self.limits.max_unfolded + 1)
                    done[id(node)] = (depth, unfolded)
                    self.check_size(depth, unfolded)
                    self.report.depth = max(self.report.depth, depth)
                    self.report.unfolded = max(self.report.unfolded, unfolded)
                elif id(child) in on_path:
                    raise _Refused("an object in its pickle contains itself, which checkpoints never do")
                elif child.children and id(child) not in done:
                    path.append((child, iter(child.children or ())))
                    on_path.add(id(child))
        self.report.max_memo_fetches = max(self.memo_fetches.values(), default=0)

    # --- storages, views and calls ------------------------------------------------------------------------------
    def storage(self, pid: _Node) -> _Node:
        """A persistent id: torch's ``('storage', storage type, key, location, numel[, view])``."""
        items = pid.children if pid.kind == "tuple" else None
        if not items or len(items) not in (5, 6) or items[0].kind != "str" or items[0].value != "storage":
            raise _Refused("it refers to outside objects other than tensor storage")
        kind, key, numel = items[1], items[2], items[4]
        if kind.kind != "global" or key.kind not in ("str", "int") or numel.kind != "int" or numel.value < 0:
            raise _Refused("it declares a tensor storage without a type, key or element count")
        itemsize = _itemsize(kind.value)
        nbytes = numel.value * itemsize
        key_text = str(key.value)
        before = self.storages.get(key_text, 0)
        self.storages[key_text] = max(before, nbytes)
        self.report.storage_bytes += max(nbytes - before, 0)
        if self.report.storage_bytes > self.report.file_bytes:
            raise _Refused(
                f"it declares {self.report.storage_bytes:,} bytes of tensor storage in a "
                f"{self.report.file_bytes:,}-byte file (storage can never exceed the file's own size)"
            )
        if len(items) == 6 and items[5].kind == "tuple":  # legacy files: a view into a larger storage
            view = [c.value if c.kind == "int" else None for c in items[5].children or ()]
            if len(view) != 3 or view[1] is None or view[2] is None or view[1] < 0 or view[1] + view[2] > numel.value:
                raise _Refused("it declares a storage view outside its storage")
            return _Node("storage", (view[2], itemsize))
        return _Node("storage", (numel.value, itemsize))

    def check_call(self, func: _Node, args: _Node) -> None:
        """Tensor rebuilds: views within their storage; any other call: no allocation larger than the file."""
        name = func.value if func.kind == "global" else None
        items = args.children if args.kind == "tuple" else None
        if name in VIEW_REBUILDS:
            self.check_view(
                items, _dtype_itemsize(items[6]) if name.endswith("_v3") and items and len(items) > 6 else 0
            )
        elif name == FROM_TYPE_REBUILD:  # (rebuild function, tensor type, its arguments, state): torch calls it
            if not items or len(items) < 3 or items[0].kind != "global" or items[0].value == FROM_TYPE_REBUILD:
                raise _Refused(f"it calls {FROM_TYPE_REBUILD} without a tensor rebuild and its arguments")
            self.check_call(items[0], items[2])
        elif name in WRAPPING_REBUILDS:
            pass  # wraps a tensor built (and checked) by one of the above
        elif name is not None and name.startswith(("torch._utils._rebuild", "torch._tensor._rebuild")):
            raise _Refused(f"it builds tensors with {name} (sparse, quantised, meta or other tensors), which "
                           "model checkpoints never hold")  # fmt: skip
        else:
            if self.int_product(args) > self.report.file_bytes:
                raise _Refused(
                    f"it calls {name or 'a constructor'} with sizes asking for more than the file's "
                    f"{self.report.file_bytes:,} bytes"
                )

    def int_product(self, node: _Node) -> int:
        """The product of the integers in a call's arguments, inside tuples too, capped above the file's size.
        Remembered per tuple (tuples never change), so arguments shared through the memo cost nothing more."""
        if node.kind == "int":
            return max(abs(node.value), 1)
        if node.kind != "tuple" or not node.children:
            return 1
        known = self.products.get(id(node))
        if known is None:
            known = 1
            for child in node.children:  # depth is bounded: tuples are checked when made
                known = min(known * self.int_product(child), self.report.file_bytes + 1)
            self.products[id(node)] = known
        return known

    def check_build(self, target: _Node, state: _Node) -> None:
        """``BUILD`` on a tensor with ``(storage, offset, size, stride)``: the legacy way of making a view."""
        if state.kind == "tuple" and state.children and state.children[0].kind == "storage":
            self.check_view(state.children)

    def check_view(self, items: list[_Node] | None, dtype_itemsize: int = 0) -> None:
        """A view (storage, offset, size, stride, ...) within its storage and the file; ``dtype_itemsize``: the
        element size of a view with its own dtype (``_rebuild_tensor_v3``) over the storage's bytes."""
        if not items or len(items) < 4 or items[0].kind != "storage":
            raise _Refused("it rebuilds a tensor without a storage, offset, size and stride")
        numel, itemsize = items[0].value
        if dtype_itemsize:
            numel, itemsize = numel * itemsize // dtype_itemsize, dtype_itemsize
        offset = items[1].value if items[1].kind == "int" else None
        size, stride = (_int_tuple(n) for n in items[2:4])
        if offset is None or size is None or stride is None or len(size) != len(stride):
            raise _Refused("it rebuilds a tensor whose offset, size or stride are not plain integers")
        if offset < 0 or any(s < 0 for s in size) or any(s < 0 for s in stride):
            raise _Refused("it rebuilds a tensor with a negative offset, size or stride")
        elements = math.prod(size)
        if elements:
            last = offset + sum((s - 1) * st for s, st in zip(size, stride, strict=True))
            if last >= numel:
                raise _Refused(f"a tensor view reaches element {last:,} of a storage of {numel:,} elements")
        nbytes = elements * itemsize
        if nbytes > self.report.file_bytes:
            raise _Refused(
                f"a tensor view of {elements:,} elements ({nbytes:,} bytes, stride 0 repeating its storage) is "
                f"larger than the whole {self.report.file_bytes:,}-byte file"
            )
        self.report.view_bytes += nbytes
        self.report.largest_view_bytes = max(self.report.largest_view_bytes, nbytes)
        if self.report.view_bytes > self.limits.max_view_ratio * self.report.file_bytes:
            raise _Refused(
                f"its tensor views add up to {self.report.view_bytes:,} bytes, more than "
                f"{self.limits.max_view_ratio:g} times the file's {self.report.file_bytes:,} bytes (the limit)"
            )


def _itemsize(storage_type: str) -> int:
    """Bytes per element of a storage type global (``torch.FloatStorage``, ``torch.UntypedStorage``...)."""
    itemsize = _STORAGE_ITEMSIZES.get(storage_type)
    if itemsize is None:
        raise _Refused(f"it declares tensor storage of an unknown type {storage_type}")
    return itemsize


# torch's own table of the storage types its loader accepts (the one its weights-only unpickler builds on)
_STORAGE_ITEMSIZES = {
    f"torch.{name}": dtype.itemsize for dtype, name in torch.storage._dtype_to_storage_type_map().items()
}
_STORAGE_ITEMSIZES.update({"torch.UntypedStorage": 1, "torch.storage.UntypedStorage": 1})


def _dtype_itemsize(node: _Node) -> int:
    """Bytes per element of a dtype global (``torch.float32``)."""
    module, _, name = str(node.value).rpartition(".")
    dtype = getattr(torch, name, None) if node.kind == "global" and module == "torch" else None
    if not isinstance(dtype, torch.dtype):
        raise _Refused(f"it rebuilds a tensor with an unknown dtype {node.value}")
    return dtype.itemsize


def _int_tuple(node: _Node) -> tuple[int, ...] | None:
    """A tensor's size or stride: a tuple of at most MAX_DIMS integers, or None."""
    if node.kind != "tuple" or len(node.children or ()) > MAX_DIMS or any(c.kind != "int" for c in node.children or ()):
        return None
    return tuple(c.value for c in node.children or ())


# --- files ---------------------------------------------------------------------------------------------------------
def scan_checkpoint(path: str | Path, limits: ScanLimits = LIMITS, what: str = "checkpoint") -> ScanReport:
    """Check a checkpoint file's pickle stream against ``limits`` without building anything from it.

    Raises a CheckpointError naming the file (``what``: its kind, for the message) and the exceeded limit; returns
    the measurements otherwise."""
    p = Path(path)
    try:
        return _scan(p, limits)
    except _Refused as e:
        raise CheckpointError(f"cannot read {what} {p}: {e}. Nothing was loaded") from None
    except OSError as e:
        raise CheckpointError(f"cannot read {what} {p}: {e}") from e


def _scan(p: Path, limits: ScanLimits) -> ScanReport:
    report = ScanReport(file_bytes=p.stat().st_size)
    scan = _PickleScan(report, limits)
    with open(p, "rb") as f:
        is_zip = f.read(len(ZIP_MAGIC)) == ZIP_MAGIC
    if is_zip:
        _scan_zip(p, scan)
    else:
        _scan_legacy(p, scan)
    report.storages = len(scan.storages)
    return report


def _scan_zip(p: Path, scan: _PickleScan) -> None:
    """torch's zip format: ``<folder>/data.pkl`` plus one stored entry per storage (``<folder>/data/<key>``)."""
    size = scan.report.file_bytes
    try:
        archive = zipfile.ZipFile(p)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError) as e:
        raise _Refused(f"it is truncated or not a PyTorch checkpoint (not a readable zip archive: {e})") from e
    with archive:
        infos = archive.infolist()
        names = [i.filename for i in infos]
        if not names or "/" not in names[0]:
            raise _Refused("its zip archive is not a PyTorch checkpoint (no folder holding data.pkl)")
        if len(set(names)) != len(names):
            raise _Refused("its zip archive holds two entries with the same name")
        unpacked = sum(i.file_size for i in infos)
        if unpacked > scan.limits.max_zip_ratio * size:
            raise _Refused(
                f"its zip entries unpack to {unpacked:,} bytes, more than {scan.limits.max_zip_ratio:g} times the "
                f"file's {size:,} bytes (a zip bomb; PyTorch stores entries uncompressed)"
            )
        folder = names[0].split("/", 1)[0]  # torch reads the folder of the archive's first entry
        entries = {i.filename: i for i in infos}
        pickle_entry = entries.get(f"{folder}/data.pkl")
        if pickle_entry is None:
            raise _Refused(f"its zip archive has no {folder}/data.pkl; it is not a PyTorch checkpoint")
        try:
            data = archive.read(pickle_entry)  # at most max_zip_ratio times the file; torch reads it whole too
        except (zipfile.BadZipFile, NotImplementedError, RuntimeError, EOFError) as e:
            raise _Refused(f"its data.pkl cannot be read ({e}); the archive is damaged") from e
        scan.run(io.BytesIO(data))
        scan.finish()
        for key, nbytes in scan.storages.items():
            entry = entries.get(f"{folder}/data/{key}")
            if entry is None or entry.file_size < nbytes:
                have = "missing" if entry is None else f"{entry.file_size:,} bytes"
                raise _Refused(f"its storage {key} declares {nbytes:,} bytes but its data entry is {have}")


def _scan_legacy(p: Path, scan: _PickleScan) -> None:
    """torch's pre-2020 format: pickles of the magic number, protocol, system info, the object and the storage
    keys, then the storages' bytes."""
    with contextlib.suppress(tarfile.TarError, OSError, ValueError, EOFError):
        with tarfile.open(p, mode="r:"):
            raise _Refused("it is a tar archive (PyTorch's format before version 0.4), which is not read")
    if scan.report.file_bytes == 0:
        raise _Refused("it is empty")
    # memory-mapped: reads stop at the end of the file whatever length the pickle declares, and only the pickles
    # at its start are read (Jukebox's files are gigabytes)
    with open(p, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as stream:
        for _ in range(5):
            scan.run(stream)
        remaining = len(stream) - stream.tell()
    scan.finish()
    declared = scan.report.storage_bytes
    if declared > remaining:
        raise _Refused(f"it declares {declared:,} bytes of tensor storage but only {remaining:,} bytes follow")


# --- loading -----------------------------------------------------------------------------------------------------
def load_checkpoint(
    path: str | Path,
    *,
    what: str = "checkpoint",
    hint: str = "",
    map_location: str | torch.device = "cpu",
    safe_globals: Iterable[Any] = (),
    mmap: bool = False,
    limits: ScanLimits = LIMITS,
) -> Any:
    """The contents of a checkpoint file (tensors and plain values, plus ``safe_globals``), or one CheckpointError.

    ``what`` names the file in messages ("EDGE checkpoint"); ``hint`` says what to do instead (where to get a good
    copy). The file is scanned (:func:`scan_checkpoint`) before ``torch.load(weights_only=True)`` reads it."""
    p = Path(path).expanduser()
    hint = f" {hint.strip()}" if hint.strip() else ""
    if not p.is_file():
        raise CheckpointError(f"{what} {p} does not exist; check the path.{hint}")
    try:
        scan_checkpoint(p, limits, what)
    except CheckpointError as e:
        raise CheckpointError(f"{e}.{hint}") from None
    try:
        with torch.serialization.safe_globals(list(safe_globals)):
            return torch.load(p, map_location=map_location, weights_only=True, mmap=mmap)
    except pickle.UnpicklingError as e:
        found = re.search(r"GLOBAL ([\w.]+)", str(e))
        asks = f"the Python global {found.group(1)}" if found else "a Python object other than tensors"
        raise UnsafeCheckpointError(
            f"cannot read {what} {p}: it was refused, as it asks for {asks}, which could run code on this "
            f"machine; nothing was loaded. Do not open it with a full torch.load either.{hint}"
        ) from e
    except Exception as e:  # noqa: BLE001 - truncated or corrupt archives raise many types
        raise CheckpointError(
            f"cannot read {what} {p} ({type(e).__name__}: {first_line(e)}); it is truncated or not a PyTorch "
            f"checkpoint.{hint}"
        ) from e


def first_line(error: BaseException, limit: int = 300) -> str:
    """The first line of an exception's message (terminal colours removed), shortened at a word (for one-line
    error messages)."""
    text = re.sub(r"\x1b\[[0-9;]*m", "", str(error)).strip()
    first = text.splitlines()[0].strip() if text else ""
    if len(first) > limit:
        first = first[:limit].rsplit(" ", 1)[0].rstrip(".,;:") + " ..."
    return first


@contextlib.contextmanager
def reading(p: Path | str, what: str = "checkpoint") -> Iterator[None]:
    """The error boundary of the checks run on a loaded checkpoint: anything unexpected that a malformed file makes
    them raise (a tensor where a flag belongs, text where a number belongs) becomes one CheckpointError."""
    try:
        yield
    except CheckpointError:
        raise
    except (ValueError, TypeError, RuntimeError, KeyError, IndexError, AttributeError, RecursionError) as e:
        raise CheckpointError(
            f"{what} {p} is malformed ({type(e).__name__}: {first_line(e)}); it was not written by the tool it "
            "claims to come from"
        ) from e


__all__ = [
    "LIMITS",
    "ScanLimits",
    "ScanReport",
    "UnsafeCheckpointError",
    "load_checkpoint",
    "reading",
    "scan_checkpoint",
]
