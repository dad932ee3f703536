"""Motion pickles: real numpy-written files load; files whose unpickling would call anything but numpy's array
reconstruction are refused before any call, naming the file and the refused global; broken files get one error."""

from __future__ import annotations

import functools
import os
import pickle
import subprocess
import time

import hostile_checkpoints as made
import numpy as np
import pytest
from conftest import accepted, refused, shell_touch

from dgsdp.data.aistpp import load_motion_pkl
from dgsdp.editing import load_motion_file
from dgsdp.errors import DataError
from dgsdp.safety.safe_pickle import UnsafePickleError, load_pickle


def aistpp_dict(n: int = 120, dtype=np.float64) -> dict:
    """The AIST++ release's layout: smpl_loss, smpl_poses (N, 72), smpl_scaling (1,), smpl_trans (N, 3)."""
    rng = np.random.default_rng(0)
    return {
        "smpl_loss": 0.5,
        "smpl_poses": (0.2 * rng.standard_normal((n, 72))).astype(dtype),
        "smpl_scaling": np.array([93.0], dtype=dtype),
        "smpl_trans": (rng.standard_normal((n, 3)) * 10 + [0, 90, 0]).astype(dtype),
    }


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
@pytest.mark.parametrize("dtype", [np.float64, np.float32, np.float16])
def test_numpy_written_aistpp_pickles_load(tmp_path, protocol, dtype):
    data = aistpp_dict(dtype=dtype)
    path = tmp_path / "gBR_sBM_cAll_d04_mBR0_ch01.pkl"
    path.write_bytes(pickle.dumps(data, protocol=protocol))
    poses, trans = load_motion_pkl(path)
    np.testing.assert_allclose(poses, data["smpl_poses"].astype(np.float32), rtol=1e-6)
    np.testing.assert_allclose(trans, data["smpl_trans"].astype(np.float32) / np.float32(93.0), rtol=1e-5)
    accepted()


@pytest.mark.parametrize("protocol", [2, 3, 4, 5])
def test_plain_values_round_trip_exactly(tmp_path, protocol):
    """Every kind of value a motion file may hold comes back equal to what plain pickle gives."""
    value = {
        "ints": np.arange(5, dtype=np.int16), "bools": np.array([True, False]), "big_endian": np.ones(3, ">f8"),
        "fortran": np.asfortranarray(np.arange(6.0).reshape(2, 3)), "scalar": np.float32(2.5), "int": 3,
        "float": 1.5, "none": None, "text": "gBR", "bytes": b"\x00\x01", "nested": [(1, 2), {"a": [np.int64(4)]}],
        "set": {1, 2}, "complex": 1 + 2j, "c64": np.ones(2, np.complex64), "u8": np.arange(3, dtype=np.uint64),
        "empty": np.zeros((0, 72), np.float32), "shared": [np.ones(2)] * 2,
    }  # fmt: skip
    path = tmp_path / "values.pkl"
    path.write_bytes(pickle.dumps(value, protocol=protocol))
    got, expected = load_pickle(path), pickle.loads(path.read_bytes())
    assert repr(got) == repr(expected)
    assert all(type(got[k]) is type(expected[k]) for k in expected)
    assert got["shared"][0] is got["shared"][1]  # one array stored once stays one array
    arrays = [v for v in got.values() if isinstance(v, np.ndarray)]
    for arr in arrays:  # built from the file's bytes as fresh arrays of their own, as numpy's unpickler gives them
        assert arr.flags.writeable and arr.flags.owndata
    assert got["fortran"].flags.f_contiguous and got["big_endian"].dtype == expected["big_endian"].dtype
    accepted()


class _Gadget:
    """Pickles as a call of ``func(*args)``: what an attacker's file asks the unpickler to do."""

    def __init__(self, func, *args):
        self.func, self.args = func, args

    def __reduce__(self):
        return self.func, self.args


def _payloads(marker, tmp_path):
    evil_npy = tmp_path / "inner.npy"
    np.save(evil_npy, np.array([_Gadget(os.system, shell_touch(marker))], dtype=object), allow_pickle=True)
    touch = f"open({str(marker)!r}, 'w').close()"
    return {
        "os.system": (_Gadget(os.system, shell_touch(marker)), "system"),
        "builtins.exec": (_Gadget(exec, touch), "builtins.exec"),
        "builtins.eval": (_Gadget(eval, touch), "builtins.eval"),
        "subprocess.Popen": (_Gadget(subprocess.Popen, ["touch", str(marker)]), "subprocess.Popen"),
        "subprocess.check_call": (_Gadget(subprocess.check_call, ["touch", str(marker)]), "subprocess.check_call"),
        "functools.partial": (_Gadget(functools.partial(os.system, shell_touch(marker))), "functools.partial"),
        "numpy.load(allow_pickle=True)": (_Gadget(np.load, str(evil_npy), None, True), "numpy"),
        "builtins.open": (_Gadget(open, str(marker), "w"), ".open"),
        "numpy.savetxt": (_Gadget(np.savetxt, str(marker), np.zeros(1)), "savetxt"),
        "getattr chain": (_Gadget(getattr, _Gadget(__import__, "os"), "system"), "builtins.getattr"),
    }


PAYLOAD_NAMES = [
    "os.system", "builtins.exec", "builtins.eval", "subprocess.Popen", "subprocess.check_call", "functools.partial",
    "numpy.load(allow_pickle=True)", "builtins.open", "numpy.savetxt", "getattr chain",
]  # fmt: skip


@pytest.mark.parametrize("name", PAYLOAD_NAMES)
def test_malicious_aistpp_motion_is_refused(tmp_path, marker, name):
    gadget, global_name = _payloads(marker, tmp_path)[name]
    data = aistpp_dict(n=10)
    data["smpl_loss"] = gadget  # hidden inside an otherwise valid motion
    path = tmp_path / "gBR_sBM_cAll_d04_mBR0_ch01.pkl"
    path.write_bytes(pickle.dumps(data, protocol=4))
    with pytest.raises(UnsafePickleError) as exc:
        load_motion_pkl(path)
    refused(exc, str(path), global_name, "refused")


@pytest.mark.parametrize("protocol", [0, 2, 5])
@pytest.mark.parametrize("reader", ["edit", "aistpp"])
def test_malicious_seed_motion_is_refused_by_every_reader(tmp_path, marker, protocol, reader):
    """seed_motion_file / keyframes_file / motion_file (editing) and dataset motions read through the same guard."""
    path = tmp_path / "seed.pkl"
    path.write_bytes(pickle.dumps([_Gadget(os.system, shell_touch(marker))], protocol=protocol))
    with pytest.raises(UnsafePickleError) as exc:
        load_motion_file(path) if reader == "edit" else load_motion_pkl(path)
    refused(exc, str(path), "system")


def test_object_array_with_payload_is_refused(tmp_path, marker):
    """An object-dtype array pickles its elements; a gadget among them is still refused."""
    arr = np.empty(2, dtype=object)
    arr[0], arr[1] = 1.0, _Gadget(os.system, shell_touch(marker))
    path = tmp_path / "obj.pkl"
    path.write_bytes(pickle.dumps({"smpl_poses": arr, "smpl_trans": np.zeros((2, 3))}, protocol=5))
    with pytest.raises(UnsafePickleError) as exc:
        load_motion_pkl(path)
    refused(exc, "system")


def test_huge_bytes_request_is_refused(tmp_path):
    """A 40-byte file asking for bytes(10**13) gets an error from the scan, not an out-of-memory crash."""
    path = tmp_path / "bomb.pkl"
    path.write_bytes(pickle.dumps(_Gadget(bytes, 10**13), protocol=2))
    with pytest.raises(DataError) as exc:
        load_pickle(path)
    refused(exc, str(path), "asking for more than the file's", "nothing was loaded")


# --- broken, not malicious ------------------------------------------------------------------------------------
def _bad(data: dict, **changes) -> dict:
    out = dict(data)
    for key, value in changes.items():
        if value is None:
            out.pop(key)
        else:
            out[key] = value
    return out


BROKEN = {
    "missing smpl_poses": (dict(smpl_poses=None), "smpl_poses"),
    "missing smpl_trans": (dict(smpl_trans=None), "smpl_trans"),
    "poses (N, 69)": (dict(smpl_poses=np.zeros((10, 69))), "(N, 72)"),
    "trans (N, 2)": (dict(smpl_trans=np.zeros((10, 2))), "(N, 3)"),
    "poses 1-d": (dict(smpl_poses=np.zeros(72)), "(N, 72)"),
    "zero frames": (dict(smpl_poses=np.zeros((0, 72)), smpl_trans=np.zeros((0, 3))), "(N, 72)"),
    "string poses": (dict(smpl_poses=np.array([["a"] * 72] * 10)), "only plain numeric arrays"),
    "object poses": (dict(smpl_poses=np.array([None] * 10, dtype=object)), "dtype 'O8'"),
    "nan poses": (dict(smpl_poses=np.full((10, 72), np.nan)), "non-finite"),
    "zero scaling": (dict(smpl_scaling=np.zeros(1)), "smpl_scaling"),
    "nan scaling": (dict(smpl_scaling=np.full(1, np.nan)), "smpl_scaling"),
    "infinite scaling": (dict(smpl_scaling=np.full(1, np.inf)), "smpl_scaling"),
    "scaling that overflows": (dict(smpl_scaling=np.full(1, 1e-300)), "overflows"),
    "text scaling": (dict(smpl_scaling="big"), "numeric"),
}


@pytest.mark.parametrize("case", list(BROKEN))
def test_broken_motion_dicts(tmp_path, case):
    changes, fragment = BROKEN[case]
    path = tmp_path / "m.pkl"
    path.write_bytes(pickle.dumps(_bad(aistpp_dict(n=10), **changes), protocol=4))
    with pytest.raises(DataError) as exc:
        load_motion_pkl(path)
    refused(exc, str(path), fragment)


@pytest.mark.parametrize("keep", [0, 1, 2, 17, 0.5, 0.99])
def test_truncated_pickles(tmp_path, keep):
    blob = pickle.dumps(aistpp_dict(n=50), protocol=4)
    n = keep if isinstance(keep, int) else int(len(blob) * keep)
    path = tmp_path / "cut.pkl"
    path.write_bytes(blob[:n])
    with pytest.raises(DataError) as exc:
        load_motion_pkl(path)
    refused(exc, str(path), "cannot read")


@pytest.mark.parametrize("content", [b"not a pickle at all", b"\x80\x05garbage", "é".encode() * 50])
def test_not_a_pickle(tmp_path, content):
    path = tmp_path / "x.pkl"
    path.write_bytes(content)
    with pytest.raises(DataError) as exc:
        load_motion_file(path)
    refused(exc, str(path))


@pytest.mark.parametrize(
    "value, fragment",
    [(np.zeros((5, 150)), "(N, 151)"), (np.zeros((5, 151), complex), "(N, 151)"), ([[1.0] * 151, [2.0]], "(N, 151)"),
     ({"fps": "fast", "smpl_poses": np.zeros((4, 72)), "smpl_trans": np.zeros((4, 3))}, "fps"),
     ({"fps": 0, "smpl_poses": np.zeros((4, 72)), "smpl_trans": np.zeros((4, 3))}, "fps")],
    ids=["150-d", "complex", "ragged", "fps text", "fps 0"],
)  # fmt: skip
def test_edit_motion_wrong_shapes_and_types(tmp_path, value, fragment):
    path = tmp_path / "seed.pkl"
    path.write_bytes(pickle.dumps(value, protocol=4))
    with pytest.raises(DataError) as exc:
        load_motion_file(path)
    refused(exc, str(path), fragment)


# --- files that crash or hang a plain restricted unpickler: the bounded scan (docs/security.md) ------------------
def _object_array(shape_items: int, list_items: int) -> bytes:
    """numpy's own pickle of an object array, its shape changed to ``shape_items`` while its list keeps
    ``list_items`` (numpy reads ``shape_items`` items from the list, unchecked)."""
    arr = np.empty(list_items, dtype=object)
    arr[:] = list(range(list_items))
    blob = pickle.dumps(arr, protocol=2)
    shape = made.b_int(list_items) + pickle.TUPLE1
    assert blob.count(shape) == 1
    return blob.replace(shape, made.b_int(shape_items) + pickle.TUPLE1)


def _field_outside(offset: int) -> bytes:
    """numpy's own pickle of a one-field structured array whose field offset is changed to ``offset``."""
    blob = pickle.dumps(np.zeros(2, dtype=[("a", "<f8")]), protocol=2)
    field = made.b_int(0) + pickle.TUPLE2  # (dtype, offset) in the dtype's fields
    assert blob.count(field) == 1
    return blob.replace(field, made.b_int(offset) + pickle.TUPLE2)


def _motion_with(key_value: bytes) -> bytes:
    """An AIST++ motion dict (protocol 2) with one more entry, pickled instruction by instruction."""
    blob = pickle.dumps(aistpp_dict(n=4), protocol=2)
    assert blob.endswith(pickle.SETITEMS + pickle.STOP)
    return blob[:-2] + key_value + pickle.SETITEMS + pickle.STOP


HOSTILE_MOTIONS = {
    # the audit's files: a plain restricted unpickler crashes (exit 139) or never finishes
    "deep key": (lambda: made.deep_key_pickle(), "nested more than 100 levels"),
    "shared (x, x) key": (lambda: made.shared_pair_pickle(64), "unfolds to more than"),
    "deep key inside a motion": (
        lambda: _motion_with(made.b_int(7) + pickle.TUPLE1 * 200_000 + made.b_int(1)),
        "nested more than 100 levels",
    ),  # fmt: skip
    # numpy reads memory past its data
    "object array, shape 3 over 2 items": (lambda: _object_array(3, 2), "from 2 items"),
    "object array, shape 2^30 over 2 items": (lambda: _object_array(2**30, 2), "more than the file's"),
    "structured field past its items": (lambda: _field_outside(100_000), "dtype 'V8'"),
    "structured array": (lambda: pickle.dumps(np.zeros(2, dtype=[("a", "f4"), ("b", "i2")]), protocol=2), "'V6'"),
    "text array": (lambda: pickle.dumps(np.array(["gBR"]), protocol=4), "dtype 'U3'"),
    "datetime array": (lambda: pickle.dumps(np.zeros(2, "M8[s]"), protocol=4), "dtype 'M8'"),
    "bytes shorter than the shape": (
        lambda: pickle.dumps(np.zeros(4)).replace(made.b_int(4), made.b_int(5)),
        "from 32 bytes",
    ),
    # sizes and instructions
    "bytearray(2^40)": (
        lambda: made.pickled(made.b_global("builtins", "bytearray") + made.b_tuple(made.b_int(2**40)) + pickle.REDUCE),
        "builtins.bytearray with sizes",
    ),  # fmt: skip
    "persistent id": (lambda: made.pickled(made.b_str("x") + pickle.BINPERSID), "BINPERSID, which motion files never"),
    "protocol-0 instance": (lambda: b"(iposix\nsystem\n.", "INST, which motion files never"),
    "list containing itself": (
        lambda: made.pickled(pickle.EMPTY_LIST + made.put(0) + made.get(0) + pickle.APPEND),
        "contains itself",
    ),  # fmt: skip
}
"""name -> (maker of the file's bytes, a fragment of its refusal)."""
MOTION_READERS = {
    "load_pickle": load_pickle,
    "AIST++ reader": load_motion_pkl,
    "seed_motion_file / motion_file": load_motion_file,
}


# --- arrays numpy's own unpickling would build unchecked (crashes, writes outside the array, 5-40 GB) -----------
def _np_dtype(code: str, *state: bytes) -> bytes:
    """``numpy.dtype(code, False, True)`` with the ``BUILD`` state ``state`` (numpy's own pickle of a dtype)."""
    return (made.b_global("numpy", "dtype") + made.b_tuple(made.b_str(code), pickle.NEWFALSE, pickle.NEWTRUE)
            + pickle.REDUCE + made.b_tuple(*state) + pickle.BUILD)  # fmt: skip


_NONE_3 = (pickle.NONE,) * 3
OBJECT_DTYPE = _np_dtype("O8", made.b_int(3), made.b_str("|"), *_NONE_3, made.b_int(-1), made.b_int(-1), made.b_int(63))
F8_DTYPE = _np_dtype("f8", made.b_int(3), made.b_str("<"), *_NONE_3, made.b_int(-1), made.b_int(-1), made.b_int(0))


def _object_field_dtype(offset: int) -> bytes:
    """An 8-byte structured dtype whose one object field lies at ``offset`` (numpy writes a pointer there)."""
    fields = pickle.EMPTY_DICT + made.b_str("a") + made.b_tuple(OBJECT_DTYPE, made.b_int(offset)) + pickle.SETITEM
    state = (made.b_int(3), made.b_str("|"), pickle.NONE, made.b_tuple(made.b_str("a")), fields, made.b_int(8),
             made.b_int(1), made.b_int(27))  # fmt: skip
    return _np_dtype("V8", *state)


def _reconstruct(typecode: bytes = pickle.SHORT_BINBYTES + b"\x01b", shape: int = 0) -> bytes:
    ndarray = made.b_global("numpy", "ndarray")
    args = made.b_tuple(ndarray, made.b_tuple(made.b_int(shape)), typecode)
    return made.b_global("numpy._core.multiarray", "_reconstruct") + args + pickle.REDUCE


def _ndarray_call(shape: int, dtype: bytes) -> bytes:
    return made.b_global("numpy", "ndarray") + made.b_tuple(made.b_tuple(made.b_int(shape)), dtype) + pickle.REDUCE


def _array_state(items: int, dtype: bytes, data: bytes) -> bytes:
    """numpy's array state ``(1, (items,), dtype, False, data)`` and its BUILD."""
    return made.b_tuple(made.b_int(1), made.b_tuple(made.b_int(items)), dtype, pickle.NEWFALSE, data) + pickle.BUILD


_ONE_NONE = pickle.EMPTY_LIST + pickle.NONE + pickle.APPEND
_FROMBUFFER = (made.b_global("numpy._core.numeric", "_frombuffer")
               + made.b_tuple(pickle.SHORT_BINBYTES + b"\x08" + bytes(8), F8_DTYPE, made.b_tuple(made.b_int(1)),
                              made.b_str("C")) + pickle.REDUCE)  # fmt: skip
NUMPY_CRASHERS = {
    # the review's files, each under 300 bytes: numpy reads past a one-item list (exit 139)
    "object array on numpy.ndarray": (
        _ndarray_call(0, F8_DTYPE) + _array_state(200_000, OBJECT_DTYPE, _ONE_NONE), "calling numpy.ndarray"),
    "object array on _frombuffer": (
        _FROMBUFFER + _array_state(200_000, OBJECT_DTYPE, _ONE_NONE), "built from a buffer"),
    # numpy writes a pointer outside the array's 8-byte items while the pickle loads (exit 139)
    **{f"object field at offset {n} on _reconstruct": (
        _reconstruct() + _array_state(1, _object_field_dtype(n), pickle.EMPTY_LIST + made.b_tuple(pickle.NONE)
                                      + pickle.APPEND), "dtype 'V8'") for n in (16, 64, 4096, 2**30)},
    **{f"object field at offset {n} on numpy.ndarray": (_ndarray_call(1, _object_field_dtype(n)), "numpy.ndarray")
       for n in (16, 4096)},
    # a plain code whose state gives it a size of its own
    "f8 dtype stating 4096-byte items": (
        _reconstruct() + _array_state(1, _np_dtype("f8", made.b_int(3), made.b_str("<"), *_NONE_3,
                                                   made.b_int(4096), made.b_int(-1), made.b_int(0)),
                                      pickle.SHORT_BINBYTES + b"\x08" + bytes(8)), "a size or flags of its own"),
    # a dtype string that hides its size: 3e8 objects (5.4 GB), or 40 GB of void
    "dtype string hiding 3e8 objects": (_reconstruct(made.b_str("(150000000,)O"), 2), "numpy never writes"),
    "void dtype of 40 GB": (_ndarray_call(1, made.b_str("V40000000000")), "numpy.ndarray"),
}  # fmt: skip
"""name -> (the pickle's body, a fragment of its refusal)."""
_CHILD = """
import json, resource, sys
from dgsdp.editing import load_motion_file
from dgsdp.safety.safe_pickle import load_pickle
from dgsdp.errors import DataError
with open("/proc/self/statm") as f:
    mapped = int(f.read().split()[0]) * resource.getpagesize()
resource.setrlimit(resource.RLIMIT_AS, (mapped + 2**30, resource.RLIM_INFINITY))  # 1 GiB more than now
for path in sys.argv[1:]:
    for reader in (load_pickle, load_motion_file):
        try:
            reader(path)
            result = "loaded"
        except DataError as e:
            result = "DataError: " + str(e)
        except BaseException as e:
            result = type(e).__name__ + ": " + str(e)
        print(json.dumps([path, result]), flush=True)
"""


def test_numpy_crashers_are_refused_before_numpy_builds_anything(tmp_path):
    """The review's files: object arrays built on numpy.ndarray or _frombuffer, object fields outside their items,
    dtype strings hiding their size. Read by two readers in a fresh interpreter limited to 1 GiB more memory than it
    has after its imports (a crash kills only it; a 5 GB or 40 GB allocation fails there as MemoryError): each file
    is one DataError from each reader, naming the file, the interpreter exits 0."""
    import json
    import sys
    from pathlib import Path

    files = {}
    for i, (case, (body, _)) in enumerate(NUMPY_CRASHERS.items()):
        files[case] = tmp_path / f"m{i}.pkl"
        files[case].write_bytes(made.pickled(body))
        assert files[case].stat().st_size < 300, case
    repo = Path(__file__).resolve().parents[2]
    env = {**os.environ, "PYTHONPATH": str(repo), "HF_HUB_OFFLINE": "1"}
    proc = subprocess.run([sys.executable, "-c", _CHILD, *map(str, files.values())], env=env, capture_output=True,
                          text=True, timeout=300)  # fmt: skip
    results: dict[str, list[str]] = {}
    for line in proc.stdout.splitlines():
        path, result = json.loads(line)
        results.setdefault(path, []).append(result)
    for case, path in files.items():
        got = results.get(str(path))
        assert got is not None, f"{case}: the interpreter died before reading it (rc {proc.returncode})"
        for result in got:
            assert result.startswith("DataError: ") and str(path) in result, f"{case}: {result[:500]}"
            assert NUMPY_CRASHERS[case][1].lower() in result.lower(), f"{case}: {result[:500]}"
    assert proc.returncode == 0, proc.stderr[-2000:]


@pytest.mark.timeout(60)
@pytest.mark.parametrize("reader", list(MOTION_READERS))
@pytest.mark.parametrize("case", list(HOSTILE_MOTIONS))
def test_hostile_motion_pickles_are_refused_quickly(tmp_path, case, reader):
    """Each file is refused by every reader with one DataError naming the file and the limit, within 10 s of CPU
    time, before anything is built (a crash here would kill pytest: the entry-point test below runs them apart)."""
    make, fragment = HOSTILE_MOTIONS[case]
    path = tmp_path / "gBR_sBM_cAll_d04_mBR0_ch01.pkl"
    path.write_bytes(make())
    cpu_start = time.process_time()
    with pytest.raises(DataError) as exc:
        MOTION_READERS[reader](path)
    refused(exc, str(path), fragment)
    assert time.process_time() - cpu_start < 10.0


def test_scan_limits_of_motion_pickles(tmp_path):
    """Real motion files pass far below the limits: an AIST++ motion of 20 s with numpy arrays, and a 60 s motion
    written as lists of numbers; the limits decide (a tighter limit refuses the same file, naming it)."""
    from dgsdp.safety.pickle_scan import DATA_LIMITS, ScanLimits, ScanReport, scan_stream

    arrays = tmp_path / "arrays.pkl"
    arrays.write_bytes(pickle.dumps(aistpp_dict(n=1200), protocol=4))
    lists = tmp_path / "lists.pkl"
    lists.write_bytes(pickle.dumps(np.zeros((1800, 151)).tolist(), protocol=2))
    for path, opcodes in ((arrays, 60), (lists, 1800 * 151)):
        report = ScanReport(file_bytes=path.stat().st_size)
        with open(path, "rb") as f:
            scan_stream(f, report, DATA_LIMITS, "data")
        assert opcodes <= report.opcodes < DATA_LIMITS.max_opcodes / 10 and report.depth <= 8
        assert load_pickle(path) is not None
    with pytest.raises(DataError) as exc:
        load_pickle(lists, limits=ScanLimits(max_opcodes=100_000))
    refused(exc, str(lists), "more than 100,000 instructions")


@pytest.mark.parametrize("protocol", [0, 1, 2, 3, 4, 5])
def test_every_protocol_passes_the_scan(tmp_path, protocol):
    """The scan knows every instruction plain data is written with (protocol 0's text opcodes, 4's frames and
    MEMOIZE, 5's bytearrays): sets, frozensets, shared references and numpy arrays load as pickle gives them."""
    shared = [1.5, "x"]
    value = {"a": np.arange(6.0).reshape(2, 3), "s": {1, 2}, "f": frozenset({3}), "twice": (shared, shared),
             "big": 10**30, "neg": -5, "text": "é" * 300, "b": b"\x00" * 300, "t": ()}  # fmt: skip
    path = tmp_path / "v.pkl"
    path.write_bytes(pickle.dumps(value, protocol=protocol))
    got, expected = load_pickle(path), pickle.loads(path.read_bytes())
    assert repr(got) == repr(expected)
    assert got["twice"][0] is got["twice"][1]


@pytest.mark.timeout(600)
def test_generate_refuses_hostile_seed_motions_in_a_fresh_interpreter(tmp_path):
    """The audit's command, ``generate.py task=seed_motion seed_motion_file=<file>``, on the files that crashed or
    hung it: a non-zero exit with one ``error:`` line naming the file and the limit, no traceback, within 10 s of CPU
    time each, nothing written. Run in a fresh interpreter, so that a segfault or a hang fails the test."""
    import json
    import sys
    from pathlib import Path

    import torch

    repo = Path(__file__).resolve().parents[2]
    sys.path.insert(0, str(repo / "tests" / "generation"))
    from gen_helpers import tiny_model, write_click_song

    model = tiny_model()
    checkpoint = tmp_path / "tiny.ckpt"
    torch.save({"hyper_parameters": model.spec.to_dict(), "state_dict": model.state_dict()}, checkpoint)
    write_click_song(tmp_path / "song.wav", 3.0)
    cases = ("deep key", "shared (x, x) key", "object array, shape 3 over 2 items", "structured field past its items")
    files = {}
    for i, case in enumerate(cases):
        files[case] = tmp_path / f"seed{i}.pkl"
        files[case].write_bytes(HOSTILE_MOTIONS[case][0]())
    common = [f"checkpoint={checkpoint}", f"music={tmp_path / 'song.wav'}", "task=seed_motion", "sampling.steps=2",
              f"output_dir={tmp_path / 'out'}", f"paths.cache_dir={tmp_path / 'cache'}", "device=cpu"]  # fmt: skip
    jobs = [{"name": "warm-up", "script": str(repo / "generate.py"), "argv": ["--help"]}]
    jobs += [
        {"name": case, "script": str(repo / "generate.py"), "argv": [*common, f"seed_motion_file={path}",
                                                                     f"hydra.run.dir={tmp_path / 'run'}"]}
        for case, path in files.items()
    ]  # fmt: skip
    (tmp_path / "jobs.json").write_text(json.dumps(jobs))
    env = {**os.environ, "PYTHONPATH": str(repo), "HF_HUB_OFFLINE": "1", "WANDB_MODE": "offline"}
    proc = subprocess.run(
        [sys.executable, str(repo / "tests" / "cli" / "cli_driver.py"), str(tmp_path / "results.json"),
         str(tmp_path / "jobs.json")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=540,
    )  # fmt: skip
    assert proc.returncode == 0, f"the interpreter died (rc {proc.returncode}): {proc.stderr[-2000:]}"
    results = json.loads((tmp_path / "results.json").read_text())
    for case, path in files.items():
        result = results[case]
        code, output = result["code"], result["stdout"] + result["stderr"]
        if isinstance(code, str) and code.startswith("error: "):  # SystemExit(message): exit status 1
            output, code = output + code, 1
        assert code in (1, 2), f"{case}: exit {code!r}: {output[-2000:]}"
        assert "Traceback" not in output, f"{case}: {output[-2000:]}"
        errors = [line for line in output.splitlines() if line.startswith("error: ")]
        assert len(errors) == 1 and str(path) in errors[0], f"{case}: {output[-2000:]}"
        assert HOSTILE_MOTIONS[case][1].lower() in errors[0].lower(), f"{case}: {errors[0]}"
        assert result["cpu_seconds"] < 10.0, f"{case}: {result['cpu_seconds']:.1f} s CPU"
    assert not (tmp_path / "out").exists() or not any((tmp_path / "out").iterdir())
