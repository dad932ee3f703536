"""Against EDGE's own code: checkpoints written by EDGE's own classes (its DanceDecoder with random weights, its
Normalizer fitted by its own code) import, and ``verify`` finds our sampling equal to EDGE's ``long_ddim_sample``.

Needs a checkout of EDGE (Stanford-TML/EDGE) named by ``DGSDP_EDGE_SRC`` and EDGE's ``einops``; skipped otherwise."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import torch
import torch.nn.functional as F

from dgsdp.interop.edge.__main__ import main
from dgsdp.interop.edge.verify import edge_code

EDGE_SRC = os.environ.get("DGSDP_EDGE_SRC")
pytestmark = [
    pytest.mark.slow,
    pytest.mark.skipif(not EDGE_SRC, reason="set DGSDP_EDGE_SRC to a checkout of EDGE's repository"),
]


def write_with_edges_code(path: Path, feature_dim: int) -> None:
    pytest.importorskip("einops")
    with edge_code(EDGE_SRC) as (edge, _):
        torch.manual_seed(feature_dim)
        model = edge["DanceDecoder"](
            nfeats=151, seq_len=150, latent_dim=64, ff_size=128, num_layers=2, num_heads=8, dropout=0.1,
            cond_feature_dim=feature_dim, activation=F.gelu,
        )  # fmt: skip
        data = torch.randn(10, 150, 151)
        data[..., :4] = (data[..., :4] > 0).float()
        data[..., 4:7] = 0.3 * data[..., 4:7] + torch.tensor([0.0, 0.0, 0.9])
        normalizer = edge["Normalizer"](data)  # EDGE's own fit
        state = model.state_dict()
        torch.save({"ema_state_dict": state, "model_state_dict": state, "optimizer_state_dict": {},
                    "normalizer": normalizer}, path)  # fmt: skip


@pytest.mark.parametrize("feature_dim", [35, 4800])
def test_verify_against_edges_code(tmp_path, capsys, feature_dim):
    ckpt = tmp_path / "checkpoint.pt"
    write_with_edges_code(ckpt, feature_dim)
    assert main(["import", str(ckpt), str(tmp_path / "edge.ckpt"), "--floor-height", "0"]) == 0
    code = main(["verify", "--edge-src", EDGE_SRC, str(ckpt), "--windows", "3"])
    last = capsys.readouterr().out.strip().splitlines()[-1]
    fields = dict(part.split("=") for part in last.split())
    assert set(fields) == {"max_abs_diff", "denoiser_max_abs_diff"}
    assert float(fields["max_abs_diff"]) < 1e-4 and float(fields["denoiser_max_abs_diff"]) < 1e-4
    assert code == 0
    # a tolerance no float32 computation meets makes it fail: the check can fail
    assert main(["verify", "--edge-src", EDGE_SRC, str(ckpt), "--windows", "2", "--tolerance", "1e-12"]) == 1


def test_speed_benchmark_against_edges_code(capsys):
    pytest.importorskip("einops")
    from dgsdp.benchmarks.edge import default_device, precisions
    from dgsdp.benchmarks.edge import main as bench

    best = bench(["--edge-src", EDGE_SRC, "--size", "small", "--seconds", "8", "--repeats", "1", "--features", "35",
                  "--batch", "32", "--parts", "sampling", "training"])  # fmt: skip
    last = capsys.readouterr().out.strip().splitlines()[-1]
    fields = dict(part.split("=", 1) for part in last.split() if "=" in part)
    assert last.endswith(" (speed only; quality: docs/distillation.md)")  # the student is timed untrained
    names = {"sampling_speedup_vs_edge", "student_sampling_speedup_vs_edge", "training_speedup_vs_edge_fp32"}
    if "dgsdp bf16" in best:
        names.add("training_speedup_vs_edge_bf16")
    if "edge long_ddim_sample, bf16" in best:  # a GPU: EDGE's sampling in bf16 too
        names |= {"sampling_speedup_vs_edge_bf16", "student_sampling_speedup_vs_edge_bf16"}
    assert set(fields) == names
    assert float(fields["sampling_speedup_vs_edge"]) == pytest.approx(
        best["edge long_ddim_sample"] / best["dgsdp default"], rel=0.01
    )
    assert float(fields["student_sampling_speedup_vs_edge"]) == pytest.approx(
        best["edge long_ddim_sample"] / best["student 5 steps"], rel=0.01
    )
    if fields["training_speedup_vs_edge_fp32"] != "n/a":  # EDGE's training step needs pytorch3d importable
        for p in precisions(default_device()):  # bf16 on a GPU or a CPU with bf16 instructions; like against like
            ratio = best[f"edge {p}"] / best[f"dgsdp {p}"]
            assert float(fields[f"training_speedup_vs_edge_{p}"]) == pytest.approx(ratio, rel=0.01)
