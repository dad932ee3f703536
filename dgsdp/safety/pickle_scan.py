"""A bounded scan of a pickle stream: what unpickling it would build, measured without building anything.

Unpickling runs a small stack machine whose instructions can describe far more than the file holds: a dict key
nested a million tuples deep crashes the interpreter when it is hashed, a shared ``(x, x)`` fetched 64 levels deep
through the pickle's memo hashes 2^64 times, a 2 KB file can declare petabytes of tensor storage, a stride-0 view of
2^50 elements, or a numpy object array whose shape claims more items than its list holds (numpy then reads past the
list). :class:`PickleScan` walks the instructions (:func:`pickletools.genops`, which builds no objects), keeping a
light record of what each would make, and raises :class:`ScanRefused` when the nesting, unfolded size, instruction
count, declared sizes or views exceed its :class:`ScanLimits`.

One machine, two kinds of file: ``"torch"`` (checkpoints, read by :mod:`dgsdp.safety.checkpoint_file`: the
instructions torch's weights-only unpickler executes, tensor storages and views) and ``"data"`` (motion pickles,
read by :mod:`dgsdp.safety.safe_pickle`: every instruction of plain data of protocols 0-5, numpy's array rebuilds).
docs/security.md explains the limits.
"""

from __future__ import annotations

import _compat_pickle
import math
import pickletools
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Any, Literal

import torch


@dataclass(frozen=True)
class ScanLimits:
    """Bounds on a pickle stream (docs/security.md gives the measured values they sit above)."""

    max_opcodes: int = 500_000  # pickle instructions; a paper-size training checkpoint has 63,494
    max_depth: int = 100  # containers inside containers (and calls); project checkpoints nest 6 to 9 deep
    max_unfolded: int = 2_000_000  # objects, each shared (memo) reference counted every time it is used: 31,462
    max_view_ratio: float = 4.0  # all tensor views together, in bytes, at most this many times the file
    max_zip_ratio: float = 2.0  # zip entries' unpacked size at most this many times the file (torch stores them)


LIMITS = ScanLimits()
"""The limits of checkpoint files."""
DATA_LIMITS = ScanLimits(max_opcodes=5_000_000, max_unfolded=5_000_000)
"""The limits of motion pickles: room for a 5-minute motion written as lists of numbers (1.4M instructions)."""
Kind = Literal["torch", "data"]

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
# Every instruction of plain data (protocols 0-5) but persistent ids, extension codes, out-of-band buffers and the
# class instantiations of protocol 0 (INST, OBJ): motion files are written without any of them.
DATA_OPCODES = frozenset(
    "INT BININT BININT1 BININT2 LONG LONG1 LONG4 STRING BINSTRING SHORT_BINSTRING BINBYTES SHORT_BINBYTES BINBYTES8 "
    "BYTEARRAY8 UNICODE SHORT_BINUNICODE BINUNICODE BINUNICODE8 FLOAT BINFLOAT NONE NEWTRUE NEWFALSE EMPTY_LIST "
    "APPEND APPENDS LIST EMPTY_TUPLE TUPLE TUPLE1 TUPLE2 TUPLE3 EMPTY_DICT DICT SETITEM SETITEMS EMPTY_SET ADDITEMS "
    "FROZENSET POP DUP MARK POP_MARK GET BINGET LONG_BINGET PUT BINPUT LONG_BINPUT MEMOIZE GLOBAL STACK_GLOBAL "
    "REDUCE BUILD NEWOBJ NEWOBJ_EX PROTO STOP FRAME".split()
)
_INTS = frozenset("BININT BININT1 BININT2 LONG1 INT LONG LONG4".split())
_STRINGS = frozenset("BINUNICODE SHORT_BINSTRING STRING BINSTRING UNICODE SHORT_BINUNICODE BINUNICODE8".split())
_LEAVES = frozenset("NONE NEWFALSE NEWTRUE BINFLOAT FLOAT BINBYTES SHORT_BINBYTES BINBYTES8 BYTEARRAY8".split())
# numpy's array rebuild: ``_reconstruct(ndarray, (0,), b"b")``, then BUILD with ``([version,] shape, dtype,
# is_fortran, data)``; for object arrays data is a list that numpy reads ``prod(shape)`` items from, unchecked
ARRAY_REBUILDS = frozenset(f"{p}.multiarray._reconstruct" for p in ("numpy._core", "numpy.core"))


class ScanRefused(Exception):
    """A reason to refuse the file (its reader turns it into one error naming the file)."""


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


class PickleScan:
    """Runs the pickle machine on light nodes for one or more consecutive pickles of a file of ``kind`` ("torch":
    a checkpoint; "data": a motion pickle), whose size ``report.file_bytes`` bounds what its calls may ask for."""

    def __init__(self, report: ScanReport, limits: ScanLimits, kind: Kind = "torch") -> None:
        if kind not in ("torch", "data"):
            raise ValueError(f"kind must be 'torch' or 'data', got {kind!r}")
        self.report, self.limits, self.kind = report, limits, kind
        self.opcodes = TORCH_OPCODES if kind == "torch" else DATA_OPCODES
        self.files = "PyTorch checkpoints" if kind == "torch" else "motion files"
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
        report, max_opcodes, fetches, allowed = self.report, self.limits.max_opcodes, self.memo_fetches, self.opcodes
        try:
            for opcode, arg, _ in pickletools.genops(stream):
                report.opcodes += 1
                if report.opcodes > max_opcodes:
                    raise ScanRefused(f"its pickle has more than {max_opcodes:,} instructions (the limit)")
                name = opcode.name
                if name in ("BINPUT", "LONG_BINPUT", "PUT"):  # the most frequent instructions first
                    memo[arg] = stack[-1]
                elif name in ("BINGET", "LONG_BINGET", "GET"):
                    if arg not in memo:
                        raise ScanRefused(f"its pickle fetches memo entry {arg}, which it never stored")
                    fetches[arg] = fetches.get(arg, 0) + 1
                    stack.append(memo[arg])
                elif name in _INTS:
                    stack.append(_Node("int", int(arg)))
                elif name not in allowed:
                    raise ScanRefused(f"its pickle uses the instruction {name}, which {self.files} never contain")
                elif name == "MARK":
                    marks.append(stack)
                    stack = []
                elif name in ("TUPLE", "LIST", "DICT", "FROZENSET", "APPENDS", "SETITEMS", "ADDITEMS"):
                    items, stack = stack, marks.pop()
                    if name in ("APPENDS", "SETITEMS", "ADDITEMS"):
                        self.grow(stack[-1], items)
                    else:
                        stack.append(self.made(_Node("tuple" if name == "TUPLE" else "container", None, items)))
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
                elif name in ("REDUCE", "NEWOBJ", "NEWOBJ_EX"):
                    if name == "NEWOBJ_EX":
                        keywords = stack.pop()
                        args = stack.pop()
                        args = self.made(_Node("tuple", None, [args, keywords]))
                    else:
                        args = stack.pop()
                    func = stack.pop()
                    self.check_call(func, args)
                    stack.append(self.made(_Node("call", func.value if func.kind == "global" else None, [func, args])))
                elif name in ("EMPTY_LIST", "EMPTY_DICT", "EMPTY_SET"):
                    stack.append(self.made(_Node("container", None, [])))
                elif name == "EMPTY_TUPLE":
                    stack.append(self.made(_Node("tuple", None, [])))
                elif name in _STRINGS:
                    text = arg if isinstance(arg, str) else arg.decode("latin-1")
                    stack.append(_Node("str", text if len(text) <= 256 else None))
                elif name == "GLOBAL":
                    module, _, attr = arg.partition(" ")
                    stack.append(_global(module, attr))
                elif name == "STACK_GLOBAL":
                    attr, module = stack.pop(), stack.pop()
                    if module.kind != "str" or attr.kind != "str" or module.value is None or attr.value is None:
                        raise ScanRefused("its pickle names a global without a module and name")
                    stack.append(_global(module.value, attr.value))
                elif name == "BINPERSID":
                    stack.append(self.storage(stack.pop()))
                elif name in _LEAVES:
                    stack.append(_LEAF)
                elif name == "MEMOIZE":
                    memo[len(memo)] = stack[-1]
                elif name == "POP":
                    stack.pop()
                elif name == "DUP":
                    stack.append(stack[-1])
                elif name == "POP_MARK":
                    stack = marks.pop()
                elif name == "STOP":
                    root = stack.pop()
                    if stack or marks:
                        raise ScanRefused("its pickle stops with objects left over; it is malformed")
                    return root
                # PROTO, FRAME: nothing to do
        except ScanRefused:
            raise
        except IndexError as e:  # stack or mark underflow
            raise ScanRefused("its pickle takes more objects than it made; it is malformed") from e
        except (ValueError, EOFError, OverflowError, UnicodeDecodeError) as e:
            what = "a PyTorch checkpoint" if self.kind == "torch" else "a pickle"
            raise ScanRefused(f"it is truncated or not {what} (its pickle: {e})") from e
        raise ScanRefused("its pickle ends without a STOP instruction; it is truncated")

    def made(self, node: _Node) -> _Node:
        """Check a new node's depth and unfolded size as far as known now (exact unless it holds a list or dict
        that grows later)."""
        self.composites.append(node)
        self.check_size(node.depth, node.unfolded)
        return node

    def grow(self, target: _Node, items: list[_Node]) -> None:
        """Items added to a list, dict or object; its parents' figures are settled by :meth:`finish`."""
        if target.children is None:  # torch refuses this too; nothing more to learn from the file
            raise ScanRefused("its pickle adds items to a number or string; it is malformed")
        if not items:
            return
        target.kind = "container"
        target.children.extend(items)
        target.depth = max(target.depth, 1 + max(i.depth for i in items))
        target.unfolded += sum(i.unfolded for i in items)
        self.check_size(target.depth, target.unfolded)

    def check_size(self, depth: int, unfolded: int) -> None:
        if depth > self.limits.max_depth:
            raise ScanRefused(
                f"its objects are nested more than {self.limits.max_depth} levels deep (the limit; {self.files} "
                f"nest {'about 10' if self.kind == 'torch' else '3 to 6'}); reading it would crash the interpreter"
            )
        if unfolded > self.limits.max_unfolded:
            raise ScanRefused(
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
                    raise ScanRefused("an object in its pickle contains itself, which checkpoints never do")
                elif child.children and id(child) not in done:
                    path.append((child, iter(child.children or ())))
                    on_path.add(id(child))
        self.report.max_memo_fetches = max(self.memo_fetches.values(), default=0)

    # --- storages, views and calls ------------------------------------------------------------------------------
    def storage(self, pid: _Node) -> _Node:
        """A persistent id: torch's ``('storage', storage type, key, location, numel[, view])``."""
        items = pid.children if pid.kind == "tuple" else None
        if not items or len(items) not in (5, 6) or items[0].kind != "str" or items[0].value != "storage":
            raise ScanRefused("it refers to outside objects other than tensor storage")
        kind, key, numel = items[1], items[2], items[4]
        if kind.kind != "global" or key.kind not in ("str", "int") or numel.kind != "int" or numel.value < 0:
            raise ScanRefused("it declares a tensor storage without a type, key or element count")
        itemsize = _itemsize(kind.value)
        nbytes = numel.value * itemsize
        key_text = str(key.value)
        before = self.storages.get(key_text, 0)
        self.storages[key_text] = max(before, nbytes)
        self.report.storage_bytes += max(nbytes - before, 0)
        if self.report.storage_bytes > self.report.file_bytes:
            raise ScanRefused(
                f"it declares {self.report.storage_bytes:,} bytes of tensor storage in a "
                f"{self.report.file_bytes:,}-byte file (storage can never exceed the file's own size)"
            )
        if len(items) == 6 and items[5].kind == "tuple":  # legacy files: a view into a larger storage
            view = [c.value if c.kind == "int" else None for c in items[5].children or ()]
            if len(view) != 3 or view[1] is None or view[2] is None or view[1] < 0 or view[1] + view[2] > numel.value:
                raise ScanRefused("it declares a storage view outside its storage")
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
                raise ScanRefused(f"it calls {FROM_TYPE_REBUILD} without a tensor rebuild and its arguments")
            self.check_call(items[0], items[2])
        elif name in WRAPPING_REBUILDS:
            pass  # wraps a tensor built (and checked) by one of the above
        elif name is not None and name.startswith(("torch._utils._rebuild", "torch._tensor._rebuild")):
            raise ScanRefused(f"it builds tensors with {name} (sparse, quantised, meta or other tensors), which "
                           "model checkpoints never hold")  # fmt: skip
        else:
            if self.int_product(args) > self.report.file_bytes:
                raise ScanRefused(
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
        """``BUILD`` on a tensor with ``(storage, offset, size, stride)`` (the legacy way of making a view), or on a
        numpy array rebuild (:meth:`check_array`)."""
        if state.kind == "tuple" and state.children and state.children[0].kind == "storage":
            self.check_view(state.children)
        elif target.kind == "call" and target.value in ARRAY_REBUILDS:
            self.check_array(state)

    def check_array(self, state: _Node) -> None:
        """numpy's array state ``([version,] shape, dtype, is_fortran, data)``: at most as many elements as the file
        has bytes, and for an object array (data: a list) exactly as many items as its shape holds (numpy reads
        ``prod(shape)`` items from the list without checking its length: past its end, a crash)."""
        items = state.children if state.kind == "tuple" else None
        if not items or len(items) not in (4, 5):
            return  # numpy refuses any other state itself
        shape, data = _int_tuple(items[-4]), items[-1]
        if shape is None or any(n < 0 for n in shape):
            raise ScanRefused("it rebuilds a numpy array whose shape is not a tuple of integers >= 0")
        elements = math.prod(shape)
        if elements > self.report.file_bytes:
            raise ScanRefused(
                f"it rebuilds a numpy array of {elements:,} elements, more than the file's {self.report.file_bytes:,} "
                "bytes could hold"
            )
        if data.kind == "container" and len(data.children or ()) != elements:
            raise ScanRefused(
                f"it rebuilds a numpy object array of shape {shape} from {len(data.children or ())} items (numpy "
                "would read past them and crash)"
            )

    def check_view(self, items: list[_Node] | None, dtype_itemsize: int = 0) -> None:
        """A view (storage, offset, size, stride, ...) within its storage and the file; ``dtype_itemsize``: the
        element size of a view with its own dtype (``_rebuild_tensor_v3``) over the storage's bytes."""
        if not items or len(items) < 4 or items[0].kind != "storage":
            raise ScanRefused("it rebuilds a tensor without a storage, offset, size and stride")
        numel, itemsize = items[0].value
        if dtype_itemsize:
            numel, itemsize = numel * itemsize // dtype_itemsize, dtype_itemsize
        offset = items[1].value if items[1].kind == "int" else None
        size, stride = (_int_tuple(n) for n in items[2:4])
        if offset is None or size is None or stride is None or len(size) != len(stride):
            raise ScanRefused("it rebuilds a tensor whose offset, size or stride are not plain integers")
        if offset < 0 or any(s < 0 for s in size) or any(s < 0 for s in stride):
            raise ScanRefused("it rebuilds a tensor with a negative offset, size or stride")
        elements = math.prod(size)
        if elements:
            last = offset + sum((s - 1) * st for s, st in zip(size, stride, strict=True))
            if last >= numel:
                raise ScanRefused(f"a tensor view reaches element {last:,} of a storage of {numel:,} elements")
        nbytes = elements * itemsize
        if nbytes > self.report.file_bytes:
            raise ScanRefused(
                f"a tensor view of {elements:,} elements ({nbytes:,} bytes, stride 0 repeating its storage) is "
                f"larger than the whole {self.report.file_bytes:,}-byte file"
            )
        self.report.view_bytes += nbytes
        self.report.largest_view_bytes = max(self.report.largest_view_bytes, nbytes)
        if self.report.view_bytes > self.limits.max_view_ratio * self.report.file_bytes:
            raise ScanRefused(
                f"its tensor views add up to {self.report.view_bytes:,} bytes, more than "
                f"{self.limits.max_view_ratio:g} times the file's {self.report.file_bytes:,} bytes (the limit)"
            )


def _global(module: str, attr: str) -> _Node:
    """A global's node, named as Python 3 names it (pickles of Python 2 say ``__builtin__``, ``copy_reg``...)."""
    module, attr = _compat_pickle.NAME_MAPPING.get((module, attr), (module, attr))
    return _Node("global", f"{_compat_pickle.IMPORT_MAPPING.get(module, module)}.{attr}")


def _itemsize(storage_type: str) -> int:
    """Bytes per element of a storage type global (``torch.FloatStorage``, ``torch.UntypedStorage``...)."""
    itemsize = _STORAGE_ITEMSIZES.get(storage_type)
    if itemsize is None:
        raise ScanRefused(f"it declares tensor storage of an unknown type {storage_type}")
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
        raise ScanRefused(f"it rebuilds a tensor with an unknown dtype {node.value}")
    return dtype.itemsize


def _int_tuple(node: _Node) -> tuple[int, ...] | None:
    """A tensor's size or stride: a tuple of at most MAX_DIMS integers, or None."""
    if node.kind != "tuple" or len(node.children or ()) > MAX_DIMS or any(c.kind != "int" for c in node.children or ()):
        return None
    return tuple(c.value for c in node.children or ())


def scan_stream(stream: Any, report: ScanReport, limits: ScanLimits, kind: Kind, pickles: int = 1) -> PickleScan:
    """Scan ``pickles`` consecutive pickles of ``stream`` (a file of ``report.file_bytes`` bytes) and settle the
    figures of everything they make; raises :class:`ScanRefused`. Returns the scan (its storages, for checkpoints)."""
    scan = PickleScan(report, limits, kind)
    for _ in range(pickles):
        scan.run(stream)
    scan.finish()
    return scan


__all__ = ["DATA_LIMITS", "LIMITS", "PickleScan", "ScanLimits", "ScanRefused", "ScanReport", "scan_stream"]
