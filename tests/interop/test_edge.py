"""EDGE's released checkpoint format: safe reading, weight mapping, the import CLI, hostile files, and generation,
evaluation and the studio on an imported model. Against EDGE's own code: tests/interop/test_edge_verify_slow.py."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
import torch
from edge_format import EdgeSkeleton, RunsCode, edge_modules, fitted_normalizer, motion_data, write_edge_checkpoint
from generation.gen_helpers import make_tiny_dataset, write_click_song

from dgsdp.errors import CheckpointError
from dgsdp.interop.edge import UnsafeCheckpointError, edge_architecture, import_edge, read_edge_checkpoint, to_dgsdp
from dgsdp.interop.edge.__main__ import main
from dgsdp.trained import load_model

SIZES = {"d": 32, "layers": 2, "ff": 64}


@pytest.fixture(scope="module")
def edge35(tmp_path_factory) -> tuple[Path, dict[str, torch.Tensor]]:
    path = tmp_path_factory.mktemp("edge") / "checkpoint.pt"
    return path, write_edge_checkpoint(path, 35, **SIZES)


@pytest.fixture(scope="module")
def imported35(edge35, tmp_path_factory) -> Path:
    return import_edge(edge35[0], tmp_path_factory.mktemp("imported") / "edge35.ckpt")


def test_reading_gives_plain_weights_and_the_scaler(edge35, tmp_path):
    path, state = edge35
    edge = read_edge_checkpoint(path)
    assert set(edge.ema) == set(state) and all(torch.equal(edge.ema[k], state[k]) for k in state)
    assert torch.equal(edge.model["final_layer.bias"], state["final_layer.bias"] + 1)
    data = motion_data().reshape(-1, 151)
    assert torch.equal(edge.scaler.data_min, data.min(0).values) and edge.scaler.feature_range == (-1.0, 1.0)
    assert edge.scaler.n_samples_seen == data.shape[0] and edge.scaler.clip
    # a checkpoint saved from several processes: the "module." prefix is dropped
    prefixed = tmp_path / "ddp.pt"
    write_edge_checkpoint(prefixed, 4800, prefix=True, **SIZES)
    assert set(read_edge_checkpoint(prefixed).ema) == set(state)


def test_architecture_is_read_from_the_weights(edge35):
    arch = edge_architecture(edge35[1])
    assert (arch.d_model, arch.n_layers, arch.ff_dim, arch.seq_len, arch.feature_dim) == (32, 2, 64, 150, 35)
    assert arch.feature_type == "baseline" and arch.encoder_layers == 2
    big = EdgeSkeleton(4800, d=512, layers=8, ff=1024).state_dict()
    paper = edge_architecture(big)
    assert (paper.d_model, paper.n_layers, paper.ff_dim, paper.feature_type) == (512, 8, 1024, "jukebox")
    # EDGE's paper model, counted from its own module tree: the README's 49.46M with Jukebox features
    assert sum(v.numel() for k, v in big.items() if not k.endswith("freqs")) == 49_464_471


def test_weights_land_in_the_matching_parameters(edge35):
    state = edge35[1]
    ours = to_dgsdp(state)
    d = SIZES["d"]
    w = state["seqTransDecoder.stack.1.multihead_attn.in_proj_weight"]
    assert torch.equal(ours["layers.1.cross_attn.q.weight"], w[:d])
    assert torch.equal(ours["layers.1.cross_attn.kv.weight"], w[d:])
    assert torch.equal(ours["music_encoder.0.attn.out.bias"], state["cond_encoder.0.self_attn.out_proj.bias"])
    assert torch.equal(ours["layers.0.film3.proj.1.weight"], state["seqTransDecoder.stack.0.film3.block.1.weight"])
    assert torch.equal(ours["null_music_hidden"], state["null_cond_hidden"])
    assert torch.equal(ours["time_mlp.0.weight"], state["time_mlp.1.weight"])
    # every EDGE parameter is used once, every denoiser parameter is filled
    n_edge = sum(v.numel() for k, v in state.items() if not k.endswith("freqs"))
    assert sum(v.numel() for v in ours.values()) == n_edge


def test_import_writes_an_ordinary_checkpoint(edge35, imported35):
    raw = torch.load(imported35, weights_only=True)  # plain tensors and data only
    model = load_model(imported35)
    spec = model.spec
    assert spec.groups["experiment"] == "edge" and spec.conditioning.audio_dim == 35
    assert spec.model["rotary_placement"] == "input" and spec.model["null_music"] == "output"
    assert spec.audio["_target_"] == "dgsdp.audio.LibrosaEncoder"
    assert (spec.audio["loudness_lufs"], spec.audio["standardize"], spec.audio["mfcc_fmax_hz"]) == (None, "none", None)
    record = raw["hyper_parameters"]["record"]["edge_import"]
    assert record["weights"] == "ema" and record["guidance_weight"] == 2.0 and record["stride_frames"] == 75
    assert record["feature_type"] == "baseline" and len(record["sha256"]) == 64
    assert math.isfinite(record["floor_height"]["metres"]) and "measured" in record["floor_height"]["how"]
    # EMA weights in both the model and its EMA copy
    ema = edge35[1]["final_layer.weight"]
    assert torch.equal(model.ema.module.output_proj.weight, ema) and torch.equal(model.denoiser.output_proj.weight, ema)
    # the normaliser maps like EDGE's scaler: x * scale_ + min_
    edge = read_edge_checkpoint(edge35[0])
    x = motion_data(2, seed=3)
    expected = x * edge.scaler.scale + edge.scaler.min
    torch.testing.assert_close(model.normalizer.normalize(x), expected, atol=2e-5, rtol=0)
    torch.testing.assert_close(model.normalizer.unnormalize(expected), x, atol=2e-5, rtol=0)


def test_cli_imports_raw_weights_and_a_given_floor(edge35, tmp_path, capsys):
    out = tmp_path / "raw.ckpt"
    assert main(["import", str(edge35[0]), str(out), "--weights", "model", "--floor-height", "0.05"]) == 0
    assert "wrote" in capsys.readouterr().out
    model = load_model(out)
    torch.testing.assert_close(model.ema.module.output_proj.bias, edge35[1]["final_layer.bias"] + 1)
    assert float(model.floor_height) == pytest.approx(0.05)


def test_jukebox_feature_checkpoints_import_with_the_jukebox_encoder(tmp_path):
    src = tmp_path / "juke.pt"
    write_edge_checkpoint(src, 4800, prefix=True, **SIZES)
    model = load_model(import_edge(src, tmp_path / "juke.ckpt", floor_height=0.0))
    assert model.spec.conditioning.audio_dim == 4800 and model.spec.audio["_target_"] == "dgsdp.audio.JukeboxEncoder"
    assert model.spec.audio["layer"] == 66 and model.spec.audio["per_window"] and model.spec.audio["fp16"] is False


def bad_case(tmp_path: Path, name: str) -> Path:
    path = tmp_path / f"{name}.pt"
    if name == "not_a_dict":
        torch.save([torch.zeros(2)], path)
    elif name == "missing_normalizer":
        torch.save({"ema_state_dict": {"a": torch.zeros(1)}, "model_state_dict": {"a": torch.zeros(1)}}, path)
    elif name == "wrong_feature_dim":
        write_edge_checkpoint(path, 100, **SIZES)
    elif name == "missing_key":
        write_edge_checkpoint(path, 35, **SIZES)
        ckpt = _reload(path)
        del ckpt["ema_state_dict"]["final_layer.bias"]
        _resave(ckpt, path)
    elif name == "wrong_shape":
        write_edge_checkpoint(path, 35, **SIZES)
        ckpt = _reload(path)
        ckpt["ema_state_dict"]["seqTransDecoder.stack.1.linear1.weight"] = torch.zeros(3, 32)
        _resave(ckpt, path)
    elif name == "truncated":
        write_edge_checkpoint(path, 35, **SIZES)
        path.write_bytes(path.read_bytes()[:5000])
    elif name == "other_scaler_range":

        def make(Normalizer, MinMaxScaler):
            n = fitted_normalizer(Normalizer, MinMaxScaler, motion_data())
            n.scaler.feature_range = (0, 1)
            return n

        write_edge_checkpoint(path, 35, normalizer=make, **SIZES)
    return path


def _reload(path: Path) -> dict:
    with edge_modules() as (Normalizer, MinMaxScaler):
        with torch.serialization.safe_globals([Normalizer, MinMaxScaler]):
            return torch.load(path, weights_only=True)


def _resave(ckpt: dict, path: Path) -> None:
    with edge_modules() as (Normalizer, MinMaxScaler):
        n = fitted_normalizer(Normalizer, MinMaxScaler, motion_data())
        torch.save({**ckpt, "normalizer": n}, path)


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("not_a_dict", "not an EDGE checkpoint"),
        ("missing_normalizer", "has no normalizer"),
        ("wrong_feature_dim", "100-d music features; EDGE's read 35-d"),
        ("missing_key", "missing: final_layer.bias"),
        ("wrong_shape", r"wrong shapes: seqTransDecoder.stack.1.linear1.weight \(3, 32\)"),
        ("truncated", "truncated or not a PyTorch checkpoint"),
        ("other_scaler_range", r"scales to \(0, 1\)"),
    ],
)
def test_bad_files_get_one_clear_error_and_write_nothing(tmp_path, case, message):
    out = tmp_path / "out.ckpt"
    with pytest.raises(CheckpointError, match=message):
        import_edge(bad_case(tmp_path, case), out, floor_height=0.0)
    assert list(tmp_path.glob("out*")) == []


def hostile_case(tmp_path: Path, name: str, marker: Path) -> Path:
    path = tmp_path / f"{name}.pt"
    if name == "normalizer_runs_code":
        write_edge_checkpoint(path, 35, normalizer=lambda N, S: RunsCode(marker), **SIZES)
    elif name == "os_system_anywhere":
        write_edge_checkpoint(path, 35, **SIZES)
        ckpt = _reload(path)
        with edge_modules() as (Normalizer, MinMaxScaler):
            n = fitted_normalizer(Normalizer, MinMaxScaler, motion_data())
            torch.save({**ckpt, "normalizer": n, "optimizer_state_dict": RunsCode(marker)}, path)
    elif name == "nested_object":  # a scaler attribute holding an object of another class

        def make(Normalizer, MinMaxScaler):
            n = fitted_normalizer(Normalizer, MinMaxScaler, motion_data())
            n.scaler.copy = RunsCode(marker)
            return n

        write_edge_checkpoint(path, 35, normalizer=make, **SIZES)
    elif name == "normalizer_in_normalizer":  # EDGE's own classes, in a shape EDGE never writes

        def make(Normalizer, MinMaxScaler):
            inner = fitted_normalizer(Normalizer, MinMaxScaler, motion_data())
            outer = Normalizer()
            outer.scaler = inner
            return outer

        write_edge_checkpoint(path, 35, normalizer=make, **SIZES)
    return path


@pytest.mark.parametrize(
    ("case", "message"),
    [
        ("normalizer_runs_code", r"asks for the Python global (posix|os)\.system"),
        ("os_system_anywhere", r"asks for the Python global (posix|os)\.system"),
        ("nested_object", r"asks for the Python global (posix|os)\.system"),
        ("normalizer_in_normalizer", "scaler is a Normalizer, not EDGE's dataset.scaler.MinMaxScaler"),
    ],
)
def test_hostile_files_run_no_code(tmp_path, case, message):
    marker = tmp_path / "PWNED"
    path = hostile_case(tmp_path, case, marker)
    out = tmp_path / "out.ckpt"
    error = UnsafeCheckpointError if "global" in message else CheckpointError
    with pytest.raises(error, match=message):
        import_edge(path, out, floor_height=0.0)
    assert main(["import", str(path), str(out), "--floor-height", "0"]) == 2
    assert not marker.exists() and not out.exists()


def test_an_existing_checkpoint_survives_a_failed_import(tmp_path, imported35):
    out = tmp_path / "keep.ckpt"
    out.write_bytes(imported35.read_bytes())
    with pytest.raises(CheckpointError):
        import_edge(bad_case(tmp_path, "truncated"), out, floor_height=0.0)
    assert out.read_bytes() == imported35.read_bytes()


@pytest.fixture(scope="module")
def song(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("song") / "clicks.wav"
    write_click_song(path, 8.0, bpm=120)
    return path


def test_generate_runs_on_the_imported_model_with_default_and_edge_sampling(imported35, song, tmp_path):
    from dgsdp.cli.config import compose_config
    from dgsdp.cli.generate import generate

    for preset in ("dpmpp_2m", "edge"):
        out = tmp_path / preset
        cfg = compose_config(
            "generate",
            [f"checkpoint={imported35}", f"music={song}", f"sampling={preset}", "progress=false", "device=cpu",
             f"output_dir={out}", f"paths.output_dir={out}", f"paths.cache_dir={tmp_path / 'cache'}",
             "formats=[npy,bvh]"],
        )  # fmt: skip
        report = generate(cfg)
        motion = np.load(out / "clicks.npy")
        assert motion.shape == (240, 151) and np.isfinite(motion).all(), preset
        assert {p.suffix for p in report.written[str(song)]} == {".npy", ".bvh"}


def test_evaluate_runs_on_the_imported_model(imported35, tmp_path):
    from dgsdp.cli.config import compose_config
    from dgsdp.cli.evaluate import evaluate

    make_tiny_dataset(tmp_path / "data")
    cfg = compose_config(
        "evaluate",
        [f"checkpoint={imported35}", "protocol=table1", "protocol.trials=1", "protocol.guidance_weights=[2.0]",
         "sampling.steps=2", "progress=false", "device=cpu", f"data.root={tmp_path / 'data'}",
         f"paths.cache_dir={tmp_path / 'cache'}", "logger=none"],
        output_dir=tmp_path / "eval",
    )  # fmt: skip
    results = evaluate(cfg)["results"]
    (row,) = [r for r in results["rows"] if r["kind"] == "generated"]
    assert row["guidance"] == 2.0 and row["n_dances"] == 2
    assert all(math.isfinite(row["metrics"][m]["mean"]) for m in ("BeatAlign", "PFC", "Div_k"))
    json.dumps(results)  # plain data
    # each clip's windows got features from their own audio (EDGE's procedure), cached as such
    assert list((tmp_path / "cache").rglob("*-windows-*"))


def test_studio_generates_with_the_imported_model(imported35, song, tmp_path):
    from dgsdp.studio.app import StudioConfig, build_app

    config = StudioConfig(checkpoint=str(imported35), work_dir=str(tmp_path / "work"), outputs=str(tmp_path / "none"),
                          max_song_seconds=20, max_upload_mb=2, device="cpu")  # fmt: skip
    _, studio = build_app(config)
    update, status = studio.on_checkpoint(str(imported35), None)
    assert "without style" in status
    args = [str(imported35), None, "", [], 2.0, 1.0, "ddim", 2, 0, False]
    value, files, state, status = studio.on_generate(str(song), *args, progress=lambda *a, **k: None)
    assert np.load(state["motion"]).shape == (240, 151) and "240 frames (8.0 s)" in status


def test_per_window_features_are_each_windows_own_audio(tmp_path):
    """EDGE's procedure: window k's features are the encoder's features of its own 5 s of audio (silence past the
    song's end), computed here by slicing the waveform by hand."""
    from dgsdp.audio import LibrosaEncoder

    encoder = LibrosaEncoder(loudness_lufs=None, standardize="none", mfcc_fmax_hz=None, per_window=True)
    rate = 15360
    t = np.arange(int(7.3 * rate)) / rate
    wave = (0.3 * np.sin(2 * np.pi * 220 * t) * (np.sin(2 * np.pi * 2 * t) > 0)).astype(np.float32)
    windows = encoder.encode_windows(wave, rate, [0, 75, 150], 150, music_id=None)
    assert windows.shape == (3, 150, 35)
    for k, start in enumerate((0.0, 2.5, 5.0)):
        piece = wave[int(start * rate) : int(start * rate) + 5 * rate]
        piece = np.pad(piece, (0, 5 * rate - len(piece)))
        np.testing.assert_allclose(windows[k], encoder.encode(piece, rate, n_frames=150), atol=1e-6)
    # not the same as cutting the song's features: the second window's own beat track and envelope
    whole = encoder.encode(wave, rate)
    assert np.abs(windows[1][: len(whole) - 75] - whole[75:]).max() > 1e-3


def test_training_refuses_per_window_features():
    from dgsdp.cli.config import compose_config
    from dgsdp.cli.train import check_config

    with pytest.raises(CheckpointError.__mro__[1], match="audio.per_window=true is EDGE's generation procedure"):
        check_config(compose_config("train", ["debug=tiny", "audio.per_window=true"]))


def test_edge_code_names_a_missing_dependency_of_edges_own(tmp_path):
    import sys

    from dgsdp.errors import ConfigError
    from dgsdp.interop.edge.verify import edge_code

    checkout = tmp_path / "EDGE"
    (checkout / "model").mkdir(parents=True)
    (checkout / "model" / "model.py").write_text("import not_installed_edge_dependency\n")
    (checkout / "model" / "diffusion.py").write_text("")
    path_before = list(sys.path)
    with pytest.raises(ConfigError, match=r"needs the module 'not_installed_edge_dependency'.*pip install "
                       r"not_installed_edge_dependency"):  # fmt: skip
        with edge_code(checkout):
            pass
    assert sys.path == path_before and "model" not in sys.modules  # nothing of the checkout is left imported
    # a checkout without one of EDGE's classes, or without one of its files, is named as such
    (checkout / "model" / "model.py").write_text("class DanceDecoder: ...\n")
    with pytest.raises(ConfigError, match="not a checkout of EDGE's code as published.*GaussianDiffusion"):
        with edge_code(checkout):
            pass
    (checkout / "model" / "diffusion.py").write_text("class GaussianDiffusion: ...\n")
    with pytest.raises(ConfigError, match="not a complete checkout of EDGE.*dataset"):
        with edge_code(checkout):
            pass
