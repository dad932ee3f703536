"""The EDGE benchmark's ``--device``: cuda where torch sees a GPU, else cpu; the device chosen reaches every part
(with a GPU's defaults: a 3-minute song, batch 128, bf16 on both sides, the MFU line); cuda without a GPU is one
clear error, not a traceback. The parts themselves are stood in for (EDGE's code is not needed)."""

import pytest
import torch

import dgsdp.benchmarks.edge as edge


@pytest.fixture
def parts(monkeypatch):
    """The parts replaced by stand-ins that record how they were called and return fixed times."""
    calls = {}

    def sampling(edge_src, **kwargs):
        calls["sampling"] = kwargs
        rows = {"edge long_ddim_sample": 30.0, "dgsdp default": 4.0, "student 5 steps": 1.5}
        if kwargs["device"].type == "cuda":
            rows.update({"edge long_ddim_sample, bf16": 20.0, "dgsdp default, bf16": 2.0, "student 5 steps, bf16": 1.0})
        return {name: [seconds] for name, seconds in rows.items()}

    def training(edge_src, **kwargs):
        calls["training"] = kwargs
        return {f"{side} {p}": [3.0 if side == "edge" else 1.0] for p in edge.precisions(kwargs["device"])
                for side in ("edge", "dgsdp")}  # fmt: skip

    def mfu(device, batch):
        calls["mfu"] = (device, batch)
        return {"samples_per_s": 640.0, "step_s": 0.2, "achieved_tflops": 98.0, "peak_tflops": 989.4,
                "mfu_percent": 9.9, "update_ms": 1.5, "reference_update_ms": 9.0}  # fmt: skip

    monkeypatch.setattr(edge, "run_sampling", sampling)
    monkeypatch.setattr(edge, "run_training", training)
    monkeypatch.setattr(edge, "run_mfu", mfu)
    monkeypatch.setattr(edge, "pytorch3d_importable", lambda: True)
    return calls


def fake_gpu(monkeypatch, visible: bool) -> None:
    monkeypatch.setattr(torch.cuda, "is_available", lambda: visible)
    monkeypatch.setattr(torch.cuda, "get_device_name", lambda device=None: "NVIDIA H100 80GB HBM3")


def test_the_default_device_is_cuda_where_a_gpu_is_visible(monkeypatch):
    fake_gpu(monkeypatch, True)
    assert edge.default_device() == "cuda"
    fake_gpu(monkeypatch, False)
    assert edge.default_device() == "cpu"


def test_cuda_without_a_gpu_is_one_clear_error(monkeypatch, capsys, parts):
    fake_gpu(monkeypatch, False)
    with pytest.raises(SystemExit) as exit_:
        edge.main(["--edge-src", "EDGE", "--device", "cuda"])
    assert exit_.value.code == 2
    err = capsys.readouterr().err
    assert "--device cuda: torch sees no CUDA device" in err and "--device cpu" in err
    assert "Traceback" not in err and not parts  # nothing ran
    with pytest.raises(SystemExit):
        edge.main(["--edge-src", "EDGE", "--device", "tpu"])
    assert "invalid choice: 'tpu'" in capsys.readouterr().err


def test_cpu_runs_every_part_on_the_cpu_with_the_cpu_defaults(monkeypatch, capsys, parts):
    fake_gpu(monkeypatch, True)  # a GPU visible: --device cpu still means the CPU
    monkeypatch.setattr(edge, "cpu_has_native_bf16", lambda: False)
    best = edge.main(["--edge-src", "EDGE", "--device", "cpu"])
    assert parts["sampling"]["device"] == torch.device("cpu") and parts["sampling"]["seconds"] == 30.0
    assert parts["training"]["device"] == torch.device("cpu") and parts["training"]["batch"] == 32
    assert "mfu" not in parts  # no MFU on a CPU unless asked
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("device: CPU (")
    assert out[-1] == (
        "sampling_speedup_vs_edge=7.50 training_speedup_vs_edge_fp32=3.00 student_sampling_speedup_vs_edge=20.00 "
        "(speed only; quality: docs/distillation.md)"
    )
    assert "dgsdp bf16" not in best  # this CPU has no bf16 instructions
    edge.main(["--edge-src", "EDGE", "--device", "cpu", "--parts", "mfu"])
    assert "mfu" not in parts and capsys.readouterr().out.startswith("device: CPU")


def test_cuda_runs_every_part_on_the_gpu_with_a_gpus_defaults(monkeypatch, capsys, parts):
    fake_gpu(monkeypatch, True)
    monkeypatch.setattr(edge, "cpu_has_native_bf16", lambda: False)  # bf16 on a GPU whatever the CPU has
    precision = torch.get_float32_matmul_precision()
    try:
        edge.main(["--edge-src", "EDGE"])  # the default device: the GPU
        assert torch.get_float32_matmul_precision() == "high"  # TF32 for both codes, as dgsdp's training
    finally:
        torch.set_float32_matmul_precision(precision)
    cuda = torch.device("cuda")
    assert parts["sampling"]["device"] == cuda and parts["sampling"]["seconds"] == 180.0  # a 3-minute song
    assert parts["training"]["device"] == cuda and parts["training"]["batch"] == 128
    assert parts["mfu"] == (cuda, 128)
    out = capsys.readouterr().out.splitlines()
    assert out[0].startswith("device: NVIDIA H100 80GB HBM3 (cuda)")
    assert "  dgsdp default, bf16 vs EDGE's code in bf16: 10.00x" in out
    mfu = next(line for line in out if line.startswith("mfu:"))
    assert "--device cuda --models paper --batch 128" in mfu and "MFU 9.9% of 989 TFLOP/s" in mfu
    assert out[-1] == (
        "sampling_speedup_vs_edge=7.50 sampling_speedup_vs_edge_bf16=10.00 training_speedup_vs_edge_fp32=3.00 "
        "training_speedup_vs_edge_bf16=3.00 student_sampling_speedup_vs_edge=20.00 "
        "student_sampling_speedup_vs_edge_bf16=20.00 (speed only; quality: docs/distillation.md)"
    )


def test_bf16_rows_always_on_a_gpu(monkeypatch):
    monkeypatch.setattr(edge, "cpu_has_native_bf16", lambda: False)
    assert edge.precisions("cuda") == ("fp32", "bf16")
    assert edge.precisions(torch.device("cpu")) == ("fp32",)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--seconds", "0"], "--seconds must be positive"),
        (["--batch", "0"], "--batch and --repeats must be at least 1"),
    ],
)
def test_bad_sizes_are_one_clear_error(monkeypatch, capsys, parts, flags, message):
    fake_gpu(monkeypatch, False)
    with pytest.raises(SystemExit):
        edge.main(["--edge-src", "EDGE", *flags])
    assert message in capsys.readouterr().err and not parts
