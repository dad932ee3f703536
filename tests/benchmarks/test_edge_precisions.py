"""The EDGE benchmark times bf16 only where the CPU has bf16 instructions, and its last line compares each precision
with the same one, float32 first."""

import dgsdp.benchmarks.edge as edge


def test_bf16_rows_only_with_bf16_instructions(monkeypatch):
    monkeypatch.setattr(edge, "cpu_has_native_bf16", lambda: True)
    assert edge.precisions() == ("fp32", "bf16")
    monkeypatch.setattr(edge, "cpu_has_native_bf16", lambda: False)
    assert edge.precisions() == ("fp32",)


def test_headline_compares_each_precision_with_the_same_one():
    # EDGE is fastest in bf16 (2.0 s), dgsdp in fp32 (1.0 s): fastest against fastest would say 2.0x
    best = {"edge long_ddim_sample": 30.0, "dgsdp default": 4.0, "student 5 steps": 1.5,
            "edge fp32": 3.0, "dgsdp fp32": 1.0, "edge bf16": 2.0, "dgsdp bf16": 1.6}  # fmt: skip
    line = edge.headline(best)
    assert line == (
        "sampling_speedup_vs_edge=7.50 training_speedup_vs_edge_fp32=3.00 training_speedup_vs_edge_bf16=1.25 "
        "student_sampling_speedup_vs_edge=20.00 (speed only; quality: docs/distillation.md)"
    )
    # float32 only (a CPU without bf16 instructions), and a run without the training part
    del best["edge bf16"], best["dgsdp bf16"]
    assert "training_speedup_vs_edge_fp32=3.00 student_" in edge.headline(best)
    sampling_only = {k: v for k, v in best.items() if k not in ("edge fp32", "dgsdp fp32")}
    assert edge.headline(sampling_only).startswith("sampling_speedup_vs_edge=7.50 training_speedup_vs_edge_fp32=n/a ")
