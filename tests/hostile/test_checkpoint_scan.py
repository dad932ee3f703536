"""Checkpoint files that crash, hang or exhaust memory in a plain weights-only ``torch.load``: every loader and every
entry point that reads a checkpoint refuses each with one clear error, within 10 s of CPU time, before building
anything.

The files are made by tests/hostile/hostile_checkpoints.py. In-process cases run every loader (EDGE import,
project checkpoints as generate/evaluate/studio/resume read them, Jukebox weights); one fresh interpreter runs
the entry points themselves (tests/cli/cli_driver.py), so that a segfault or a hang fails the test instead of
killing pytest."""

from __future__ import annotations

import copy
import json
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import hostile_checkpoints as made
import pytest
import torch
from conftest import TALLY, refused
from hostile_checkpoints import EDGE_ONLY, HEAVY, HOSTILE

from dgsdp.errors import CheckpointError, DgsdpError
from dgsdp.safety.checkpoint_file import LIMITS, ScanLimits, load_checkpoint, scan_checkpoint

REPO = Path(__file__).resolve().parents[2]
SECONDS = 10.0  # the most CPU time a refusal may take (the wall time of a busy shared machine is several times that)
WALL_SECONDS = 60.0


def slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "_", name.lower()).strip("_")


@pytest.fixture(scope="module")
def files(tmp_path_factory) -> dict[str, Path]:
    folder = tmp_path_factory.mktemp("hostile")
    return {name: make(folder / f"{slug(name)}.pt") for name, (make, _) in HOSTILE.items()}


def _edge(path: Path, tmp: Path) -> None:
    from dgsdp.interop.edge import import_edge

    import_edge(path, tmp / "out.ckpt", floor_height=0.0)


def _project(path: Path, tmp: Path) -> None:
    from dgsdp.trained import load_model

    load_model(path)


def _studio(path: Path, tmp: Path) -> None:
    from dgsdp.studio.engine import Engine

    Engine(cache_dir=tmp / "cache").generator(str(path))


def _jukebox(path: Path, tmp: Path) -> None:
    from dgsdp.audio.jukebox_encoder import _load_checkpoint_state

    _load_checkpoint_state(path)


LOADERS = {"EDGE import": _edge, "project checkpoint": _project, "studio": _studio, "Jukebox weights": _jukebox}
CASES = [
    pytest.param(loader, case, id=f"{loader}: {case}")
    for loader in LOADERS
    for case in HOSTILE
    if (loader == "EDGE import" or case not in EDGE_ONLY) and (loader == "project checkpoint" or case not in HEAVY)
]


@pytest.mark.timeout(60)
@pytest.mark.parametrize(("loader", "case"), CASES)
def test_every_loader_refuses_hostile_files_quickly(files, tmp_path, loader, case):
    start, cpu_start = time.perf_counter(), time.process_time()
    with pytest.raises(DgsdpError) as exc:
        LOADERS[loader](files[case], tmp_path)
    seconds, cpu_seconds = time.perf_counter() - start, time.process_time() - cpu_start
    refused(exc, str(files[case]), HOSTILE[case][1])
    assert cpu_seconds < SECONDS and seconds < WALL_SECONDS, f"{case}: {cpu_seconds:.1f} s CPU, {seconds:.1f} s"
    assert not (tmp_path / "out.ckpt").exists()


def test_scan_reads_real_checkpoints_within_the_limits(tmp_path):
    """A tiny model's checkpoint, in the zip and the legacy format, passes with room to spare; tied weights (one
    storage, two names) too. The figures of the quick start and paper-size checkpoints are in docs/security.md."""
    sys.path.insert(0, str(REPO / "tests" / "generation"))
    from gen_helpers import tiny_model

    model = tiny_model()
    ckpt = {"hyper_parameters": model.spec.to_dict(), "state_dict": model.state_dict()}
    shared = torch.arange(6.0).reshape(2, 3)
    ckpt["tied"] = {"a": shared, "b": shared, "row": shared[1], "t": shared.t()}
    for zip_format in (True, False):
        path = tmp_path / f"tiny{zip_format}.ckpt"
        torch.save(ckpt, path, _use_new_zipfile_serialization=zip_format)
        report = scan_checkpoint(path)
        assert report.storages == len(model.state_dict()) + 1
        assert 0 < report.opcodes < LIMITS.max_opcodes / 20 and report.depth < LIMITS.max_depth / 5
        assert report.storage_bytes <= report.file_bytes
        loaded = load_checkpoint(path)
        assert torch.equal(loaded["tied"]["t"], shared.t())
        assert loaded["tied"]["a"].data_ptr() == loaded["tied"]["b"].data_ptr()
    # tensors with their own dtype over untyped storage (_rebuild_tensor_v3) and with attributes (_rebuild_from_type_v2)
    tagged = torch.ones(3)
    tagged.note = "kept"
    f8 = torch.arange(4.0).to(torch.float8_e4m3fn)
    torch.save({"f8": f8, "f8_part": f8[1:3], "tagged": tagged}, tmp_path / "kinds.pt")
    loaded = load_checkpoint(tmp_path / "kinds.pt")
    assert loaded["f8_part"].float().tolist() == [1.0, 2.0] and loaded["tagged"].note == "kept"


def test_memo_reuse_is_measured_unfolded(tmp_path):
    """``x = (x, x)``: with u(0) = 1 for the innermost number and u(n + 1) = 1 + 2 u(n), 20 levels unfold to
    2^21 - 1 objects, and the dict holding that key and a number to 2^21 + 1; the limit decides, not the file's
    size (a few hundred bytes) or its depth (22)."""
    path = made.shared_pair_key(tmp_path / "pairs.pt", levels=20)
    report = scan_checkpoint(path, ScanLimits(max_unfolded=2**22))
    assert (report.unfolded, report.depth) == (2**21 + 1, 22)
    assert report.max_memo_fetches == 1  # each level fetches its memo entry once: fetch counts would not see it
    with pytest.raises(CheckpointError) as exc:
        scan_checkpoint(path, ScanLimits(max_unfolded=2**20))
    refused(exc, "unfolds to more than 1,048,576 objects")


def test_view_offset_and_stride_reach_past_the_storage(tmp_path):
    """The last element a view reaches is offset + sum((size - 1) * stride): 3 + (2 - 1) * 2 = 5 of 6 is fine,
    offset 4 reaches 6 of 6 elements (indices 0..5) and is refused."""
    for offset, ok in ((3, True), (4, False)):
        path = tmp_path / f"view{offset}.pt"
        made.torch_zip(
            path,
            made.pickled(made.b_dict((made.b_str("w"), made.b_tensor(made.b_storage(6), (2, 1), (2, 1), offset)))),
            {"0": bytes(24)},
        )
        if ok:
            assert load_checkpoint(path)["w"].tolist() == [[0.0], [0.0]]
        else:
            with pytest.raises(CheckpointError) as exc:
                load_checkpoint(path)
            refused(exc, "reaches element 6 of a storage of 6 elements")


def test_large_integers_outside_calls_are_data(tmp_path):
    """Plain numbers (a step count of 10^12) are not sizes: only calls' arguments are bounded."""
    path = made.torch_zip(
        tmp_path / "steps.pt", made.pickled(made.b_dict((made.b_str("global_step"), made.b_int(10**12))))
    )
    assert load_checkpoint(path) == {"global_step": 10**12}


# --- the model's sizes, before the model is built ------------------------------------------------------------------
def _tiny_checkpoint(tmp_path: Path, **model_changes) -> Path:
    sys.path.insert(0, str(REPO / "tests" / "generation"))
    from gen_helpers import tiny_model

    model = tiny_model()
    hparams = copy.deepcopy(model.spec.to_dict())
    hparams["model"].update(model_changes)
    path = tmp_path / "sizes.ckpt"
    torch.save({"hyper_parameters": hparams, "state_dict": model.state_dict()}, path)
    return path


@pytest.mark.timeout(60)
@pytest.mark.parametrize(
    ("changes", "fragment"),
    [
        ({"d_model": 4096, "n_layers": 64, "ff_dim": 16384}, "nothing was built"),  # 193 GB of weights if it were built
        ({"n_layers": 8}, "weights the file does not hold: denoiser.layers.1"),
        ({"d_model": 10**6}, "model.d_model=1,000,000 is larger than any model this project builds"),
        ({"n_layers": 10**9}, "model.n_layers=1,000,000,000 is larger"),
        ({"music_encoder_layers": 10**7}, "model.music_encoder_layers=10,000,000 is larger"),
    ],
    ids=["huge model", "more layers", "d_model 10^6", "10^9 layers", "music encoder layers"],
)
def test_stored_model_sizes_are_checked_before_building(tmp_path, changes, fragment):
    """A small file whose config asks for a huge model is refused by comparing the config's layout (meta device,
    no memory) with its weights, or by the size bounds, before any model is built."""
    from dgsdp.studio.engine import Engine
    from dgsdp.trained import load_model

    path = _tiny_checkpoint(tmp_path, **changes)
    for load in (load_model, lambda p: Engine(cache_dir=tmp_path / "cache").generator(str(p))):
        cpu_start = time.process_time()
        with pytest.raises(CheckpointError) as exc:
            load(path)
        refused(exc, str(path), fragment)
        assert time.process_time() - cpu_start < SECONDS


# --- the entry points, in a fresh interpreter ----------------------------------------------------------------------
@pytest.mark.timeout(600)
def test_entry_points_print_one_error_and_exit_nonzero(files, tmp_path):
    """``python -m dgsdp.interop.edge import`` on every hostile file, and generate.py, evaluate.py and train.py's
    resume on one each: a non-zero exit, an ``error:`` line naming the file and the limit, no traceback, within
    10 s of CPU time each, and nothing written. A segfault or hang fails here (the interpreter dies or times out)."""
    jobs = [
        {"name": f"import: {case}", "module": "dgsdp.interop.edge", "argv": ["import", str(path), str(tmp_path / "o.ckpt")]}
        for case, path in files.items()
    ]  # fmt: skip
    project = {"generate.py": "deep key", "evaluate.py": "shared (x, x) key", "train.py": "stride-0 weight"}
    run_dir = f"hydra.run.dir={tmp_path / 'run'}"
    jobs += [
        {"name": "generate.py", "script": str(REPO / "generate.py"), "argv": [
            f"checkpoint={files[project['generate.py']]}", f"music={tmp_path / 'song.wav'}",
            f"output_dir={tmp_path / 'out'}", run_dir]},
        {"name": "evaluate.py", "script": str(REPO / "evaluate.py"), "argv": [
            f"checkpoint={files[project['evaluate.py']]}", run_dir]},
        {"name": "train.py", "script": str(REPO / "train.py"), "argv": [
            "debug=tiny", "audio=none", "style=onehot", "logger=none", f"data.root={tmp_path / 'data'}",
            "data.synthetic=null", f"paths.cache_dir={tmp_path / 'cache'}", f"ckpt_path={files[project['train.py']]}",
            run_dir]},
    ]  # fmt: skip
    # first each entry point once with nothing to load, so that the timed runs do not include Python's imports
    warm_up = [
        {"name": "warm-up: import", "module": "dgsdp.interop.edge", "argv": ["import", str(tmp_path / "none.pt"),
         str(tmp_path / "o.ckpt")]},
        *({"name": f"warm-up: {script}", "script": str(REPO / script), "argv": ["--help"]} for script in project),
    ]  # fmt: skip
    (tmp_path / "jobs.json").write_text(json.dumps(warm_up + jobs))
    env = {**os.environ, "PYTHONPATH": str(REPO), "HF_HUB_OFFLINE": "1", "WANDB_MODE": "offline"}
    proc = subprocess.run(
        [sys.executable, str(REPO / "tests" / "cli" / "cli_driver.py"), str(tmp_path / "results.json"),
         str(tmp_path / "jobs.json")],
        cwd=tmp_path, env=env, capture_output=True, text=True, timeout=540,
    )  # fmt: skip
    assert proc.returncode == 0, f"the entry points' interpreter died (rc {proc.returncode}): {proc.stderr[-2000:]}"
    results = json.loads((tmp_path / "results.json").read_text())
    assert [results[job["name"]]["code"] for job in warm_up] == [2, 0, 0, 0], results
    for job in jobs:
        name = job["name"]
        case = name.removeprefix("import: ") if name.startswith("import: ") else project[name]
        result = results[name]
        TALLY["tried"] += 1
        code, output = result["code"], result["stdout"] + result["stderr"]
        if isinstance(code, str) and code.startswith("error: "):  # SystemExit(message): exit status 1
            output, code = output + code, 1
        assert code in (1, 2), f"{name}: exit {code!r}"
        assert "Traceback" not in output, f"{name}: {output[-2000:]}"
        errors = [line for line in output.splitlines() if line.startswith("error: ")]
        assert len(errors) == 1 and str(files[case]) in errors[0], f"{name}: {output[-2000:]}"
        assert HOSTILE[case][1].lower() in errors[0].lower(), f"{name}: {errors[0]}"
        seconds, cpu_seconds = result["seconds"], result["cpu_seconds"]
        assert cpu_seconds < SECONDS and seconds < WALL_SECONDS, f"{name}: {cpu_seconds:.1f} s CPU, {seconds:.1f} s"
        TALLY["refused cleanly"] += 1
    assert not (tmp_path / "o.ckpt").exists() and not (tmp_path / "out").exists()


def test_resume_checks_the_configured_model_against_the_weights(tmp_path):
    """train.py's resume compares the configured run's layout with the checkpoint's weights before building it."""
    sys.path.insert(0, str(REPO / "tests" / "generation"))
    from gen_helpers import tiny_model

    from dgsdp.trained import check_weights

    model = tiny_model()
    state = dict(model.state_dict())
    check_weights(model.spec, state, "ok.ckpt")  # the run's own weights pass
    name = next(k for k, v in state.items() if k.startswith("denoiser.") and v.ndim == 2)
    state[name] = torch.zeros(state[name].shape[0] + 1, state[name].shape[1])
    del state["ema.n_averaged"]
    with pytest.raises(CheckpointError) as exc:
        check_weights(model.spec, state, "other.ckpt")
    refused(exc, "other.ckpt", f"{name} ", "(the file holds", "weights the file does not hold: ema.n_averaged")


def test_one_torch_load_in_the_package():
    """Every checkpoint file goes through load_checkpoint: the package has no other torch.load call."""
    calls = [
        f"{py.relative_to(REPO)}:{i}"
        for py in (REPO / "dgsdp").rglob("*.py")
        for i, line in enumerate(py.read_text().splitlines(), 1)
        if re.search(r"torch\.load\(\s*[^w)]", line) or re.search(r"\bfrom torch import .*\bload\b", line)
    ]
    assert calls == ["dgsdp/safety/checkpoint_file.py:" + str(_load_line())], calls


def _load_line() -> int:
    source = (REPO / "dgsdp" / "safety" / "checkpoint_file.py").read_text().splitlines()
    return next(i for i, line in enumerate(source, 1) if "return torch.load(p, " in line)
