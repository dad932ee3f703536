"""Motion pickles: real numpy-written files load; files whose unpickling would call anything but numpy's array
reconstruction are refused before any call, naming the file and the refused global; broken files get one error."""

from __future__ import annotations

import functools
import os
import pickle
import subprocess

import numpy as np
import pytest
from conftest import accepted, refused, shell_touch

from dgsdp.data.aistpp import load_motion_pkl
from dgsdp.editing import load_motion_file
from dgsdp.errors import DataError
from dgsdp.utils.safe_pickle import UnsafePickleError, load_pickle


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
        "set": {1, 2}, "complex": 1 + 2j, "structured": np.zeros(2, dtype=[("a", "f4"), ("b", "i2")]),
    }  # fmt: skip
    path = tmp_path / "values.pkl"
    path.write_bytes(pickle.dumps(value, protocol=protocol))
    got, expected = load_pickle(path), pickle.loads(path.read_bytes())
    assert repr(got) == repr(expected)
    assert all(type(got[k]) is type(expected[k]) for k in expected)
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
    """A 40-byte file asking for bytes(10**13) gets an error, not an out-of-memory crash."""
    path = tmp_path / "bomb.pkl"
    path.write_bytes(pickle.dumps(_Gadget(bytes, 10**13), protocol=2))
    with pytest.raises(DataError) as exc:
        load_pickle(path)
    refused(exc, str(path), "too much memory")


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
    "string poses": (dict(smpl_poses=np.array([["a"] * 72] * 10)), "numeric"),
    "object poses": (dict(smpl_poses=np.array([None] * 10, dtype=object)), "(N, 72)"),
    "nan poses": (dict(smpl_poses=np.full((10, 72), np.nan)), "non-finite"),
    "zero scaling": (dict(smpl_scaling=np.zeros(1)), "smpl_scaling"),
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
