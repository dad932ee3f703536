"""bf16 autocast on a CPU without bf16 instructions is refused with the setting's name (it would be hundreds of
times slower than float32, not faster)."""

import pytest
import torch

import dgsdp.utils.device
from dgsdp.errors import ConfigError
from dgsdp.generation import DanceGenerator
from dgsdp.sampling import SamplingSettings
from dgsdp.utils.device import check_cpu_bf16, cpu_has_native_bf16


def test_the_capability_is_what_onednn_reports():
    assert cpu_has_native_bf16() == bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())


def test_check_names_the_setting_only_where_bf16_is_emulated(monkeypatch):
    monkeypatch.setattr(dgsdp.utils.device, "cpu_has_native_bf16", lambda: True)
    check_cpu_bf16("sampling.bf16=true")  # no error
    monkeypatch.setattr(dgsdp.utils.device, "cpu_has_native_bf16", lambda: False)
    with pytest.raises(ConfigError, match=r"sampling.bf16=true asks for bf16 autocast .* Use float32"):
        check_cpu_bf16("sampling.bf16=true")


def test_generation_refuses_bf16_sampling_without_bf16_instructions(tiny_model, tmp_path, monkeypatch):
    generator = DanceGenerator(tiny_model, cache_dir=tmp_path)
    music = torch.randn(12, 35)
    monkeypatch.setattr(dgsdp.utils.device, "cpu_has_native_bf16", lambda: False)
    with pytest.raises(ConfigError, match="sampling.bf16=true asks for bf16 autocast"):
        generator.generate(12, music=music, sampling=SamplingSettings(steps=2, bf16=True), seed=0)
    float32 = generator.generate(12, music=music, sampling=SamplingSettings(steps=2), seed=0)  # float32 is fine
    monkeypatch.setattr(dgsdp.utils.device, "cpu_has_native_bf16", lambda: True)
    bf16 = generator.generate(12, music=music, sampling=SamplingSettings(steps=2, bf16=True), seed=0)
    assert bf16.shape == float32.shape and torch.isfinite(bf16).all()
    assert not torch.equal(bf16, float32)  # it did run under autocast
