"""Loading a checkpoint file we were given: a bounded scan of its pickle stream, then torch's weights-only loader.

``torch.load(weights_only=True)`` runs no code from a file, but it still builds whatever the pickle describes: a
dict key nested a million tuples deep crashes the interpreter when it is hashed, a shared ``(x, x)`` fetched 64
levels deep through the pickle's memo hashes 2^64 times, a 2 KB file can declare petabytes of tensor storage or a
stride-0 view of 2^50 elements. :func:`scan_checkpoint` walks the pickle's instructions first
(:mod:`dgsdp.safety.pickle_scan`, the scan motion pickles go through too) and refuses a file whose nesting, unfolded
size, instruction count, declared storage or tensor views exceed :data:`LIMITS`, or whose zip entries unpack to far
more than the file. :func:`load_checkpoint` is the one way this package opens a checkpoint file (project
checkpoints, EDGE's, Jukebox weights): scan, then ``torch.load`` with weights only, every failure as one
:class:`~dgsdp.errors.CheckpointError` naming the file. docs/security.md explains the limits.
"""

from __future__ import annotations

import contextlib
import io
import mmap
import pickle
import re
import tarfile
import zipfile
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import torch

from dgsdp.errors import CheckpointError, UnsafeCheckpointError
from dgsdp.safety.pickle_scan import LIMITS, PickleScan, ScanLimits, ScanRefused, ScanReport

ZIP_MAGIC = b"PK\x03\x04"  # torch.load takes a file for a zip archive when it starts with a local file header


# --- files ---------------------------------------------------------------------------------------------------------
def scan_checkpoint(path: str | Path, limits: ScanLimits = LIMITS, what: str = "checkpoint") -> ScanReport:
    """Check a checkpoint file's pickle stream against ``limits`` without building anything from it.

    Raises a CheckpointError naming the file (``what``: its kind, for the message) and the exceeded limit; returns
    the measurements otherwise."""
    p = Path(path)
    try:
        return _scan(p, limits)
    except ScanRefused as e:
        raise CheckpointError(f"cannot read {what} {p}: {e}. Nothing was loaded") from None
    except OSError as e:
        raise CheckpointError(f"cannot read {what} {p}: {e}") from e


def _scan(p: Path, limits: ScanLimits) -> ScanReport:
    report = ScanReport(file_bytes=p.stat().st_size)
    scan = PickleScan(report, limits, "torch")
    with open(p, "rb") as f:
        is_zip = f.read(len(ZIP_MAGIC)) == ZIP_MAGIC
    if is_zip:
        _scan_zip(p, scan)
    else:
        _scan_legacy(p, scan)
    report.storages = len(scan.storages)
    return report


def _scan_zip(p: Path, scan: PickleScan) -> None:
    """torch's zip format: ``<folder>/data.pkl`` plus one stored entry per storage (``<folder>/data/<key>``)."""
    size = scan.report.file_bytes
    try:
        archive = zipfile.ZipFile(p)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, ValueError, EOFError) as e:
        raise ScanRefused(f"it is truncated or not a PyTorch checkpoint (not a readable zip archive: {e})") from e
    with archive:
        infos = archive.infolist()
        names = [i.filename for i in infos]
        if not names or "/" not in names[0]:
            raise ScanRefused("its zip archive is not a PyTorch checkpoint (no folder holding data.pkl)")
        if len(set(names)) != len(names):
            raise ScanRefused("its zip archive holds two entries with the same name")
        unpacked = sum(i.file_size for i in infos)
        if unpacked > scan.limits.max_zip_ratio * size:
            raise ScanRefused(
                f"its zip entries unpack to {unpacked:,} bytes, more than {scan.limits.max_zip_ratio:g} times the "
                f"file's {size:,} bytes (a zip bomb; PyTorch stores entries uncompressed)"
            )
        folder = names[0].split("/", 1)[0]  # torch reads the folder of the archive's first entry
        entries = {i.filename: i for i in infos}
        pickle_entry = entries.get(f"{folder}/data.pkl")
        if pickle_entry is None:
            raise ScanRefused(f"its zip archive has no {folder}/data.pkl; it is not a PyTorch checkpoint")
        try:
            data = archive.read(pickle_entry)  # at most max_zip_ratio times the file; torch reads it whole too
        except (zipfile.BadZipFile, NotImplementedError, RuntimeError, EOFError) as e:
            raise ScanRefused(f"its data.pkl cannot be read ({e}); the archive is damaged") from e
        scan.run(io.BytesIO(data))
        scan.finish()
        for key, nbytes in scan.storages.items():
            entry = entries.get(f"{folder}/data/{key}")
            if entry is None or entry.file_size < nbytes:
                have = "missing" if entry is None else f"{entry.file_size:,} bytes"
                raise ScanRefused(f"its storage {key} declares {nbytes:,} bytes but its data entry is {have}")


def _scan_legacy(p: Path, scan: PickleScan) -> None:
    """torch's pre-2020 format: pickles of the magic number, protocol, system info, the object and the storage
    keys, then the storages' bytes."""
    with contextlib.suppress(tarfile.TarError, OSError, ValueError, EOFError):
        with tarfile.open(p, mode="r:"):
            raise ScanRefused("it is a tar archive (PyTorch's format before version 0.4), which is not read")
    if scan.report.file_bytes == 0:
        raise ScanRefused("it is empty")
    # memory-mapped: reads stop at the end of the file whatever length the pickle declares, and only the pickles
    # at its start are read (Jukebox's files are gigabytes)
    with open(p, "rb") as f, mmap.mmap(f.fileno(), 0, access=mmap.ACCESS_READ) as stream:
        for _ in range(5):
            scan.run(stream)
        remaining = len(stream) - stream.tell()
    scan.finish()
    declared = scan.report.storage_bytes
    if declared > remaining:
        raise ScanRefused(f"it declares {declared:,} bytes of tensor storage but only {remaining:,} bytes follow")


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
