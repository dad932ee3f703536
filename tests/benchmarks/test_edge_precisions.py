"""The EDGE benchmark times bf16 only where the CPU has bf16 instructions."""

import dgsdp.benchmarks.edge as edge


def test_bf16_rows_only_with_bf16_instructions(monkeypatch):
    monkeypatch.setattr(edge, "cpu_has_native_bf16", lambda: True)
    assert edge.precisions() == ("fp32", "bf16")
    monkeypatch.setattr(edge, "cpu_has_native_bf16", lambda: False)
    assert edge.precisions() == ("fp32",)
