"""Counting reads of tensor values back to the host (each one waits for a GPU to catch up), for the tests that
check that sampling and training read nothing back per step.

On a CPU there is no device to wait for, so what is counted is the Python-level calls that would read a CUDA
tensor back: ``item``, ``tolist``, ``bool``/``int``/``float``/``index`` of a tensor, ``numpy``, ``cpu``,
``nonzero`` and ``torch.equal``. A GPU check (``torch.cuda.set_sync_debug_mode``) also sees the reads made in
C++, such as a blocking copy from the host."""

from __future__ import annotations

import traceback
from collections import Counter
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path

import pytest
import torch

TENSOR_METHODS = ("item", "tolist", "__bool__", "__int__", "__float__", "__index__", "numpy", "cpu", "nonzero")
TORCH_FUNCTIONS = ("nonzero", "equal")
PROJECT = str(Path(__file__).resolve().parents[1] / "dgsdp")


@dataclass
class HostReads:
    """The reads seen: calls per (what, where), where being the innermost project line that led to it (else the
    caller's), and the tensors read (held, so that each keeps its identity)."""

    calls: Counter = field(default_factory=Counter)
    tensors: list[torch.Tensor] = field(default_factory=list)

    @property
    def total(self) -> int:
        return sum(self.calls.values())

    @property
    def distinct_tensors(self) -> int:
        """How many different values were read (tensors over different memory: views of one count once, and as the
        tensors read are held, no memory is reused): a value read again and again (a host copy that a progress bar
        shows after every batch) counts once."""
        return len({t.untyped_storage().data_ptr() for t in self.tensors})

    def record(self, what: str, tensor: torch.Tensor) -> None:
        stack = traceback.extract_stack()[:-2]
        frame = next((f for f in reversed(stack) if f.filename.startswith(PROJECT)), stack[-1])
        self.calls[(what, f"{Path(frame.filename).name}:{frame.lineno}")] += 1
        self.tensors.append(tensor)


@contextmanager
def count_host_reads() -> Iterator[HostReads]:
    """Count the host reads made inside the block (see the module docstring)."""
    reads = HostReads()

    def counted(name: str, original, what: str):
        def wrapper(tensor, *args, **kwargs):
            if isinstance(tensor, torch.Tensor):
                reads.record(what, tensor)
            return original(tensor, *args, **kwargs)

        wrapper.__name__ = name
        return wrapper

    with pytest.MonkeyPatch.context() as patch:
        for name in TENSOR_METHODS:
            patch.setattr(torch.Tensor, name, counted(name, getattr(torch.Tensor, name), name))
        for name in TORCH_FUNCTIONS:
            patch.setattr(torch, name, counted(name, getattr(torch, name), f"torch.{name}"))
        yield reads


def differences(few: HostReads, more: HostReads) -> dict:
    """The call sites whose counts differ between a run with few steps and one with more steps."""
    return {site: (few.calls.get(site, 0), n) for site, n in more.calls.items() if few.calls.get(site, 0) != n}
