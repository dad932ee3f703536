"""The settings of the sampling-quality benchmark: parsed into evaluate.py overrides, bad ones refused."""

import pytest

from dgsdp.benchmarks.sampling_quality import Setting, parse_setting


@pytest.mark.parametrize(
    "text,expected,overrides",
    [
        ("dpmpp_2m-10", Setting("dpmpp_2m", 10), ["sampling.method=dpmpp_2m", "sampling.steps=10"]),
        ("ddim-50-eta0", Setting("ddim", 50, 0.0), ["sampling.method=ddim", "sampling.steps=50", "sampling.eta=0.0"]),
        (
            "dpmpp_2m-5-bf16",
            Setting("dpmpp_2m", 5, bf16=True),
            ["sampling.method=dpmpp_2m", "sampling.steps=5", "sampling.bf16=true"],
        ),
    ],
)
def test_settings_parse_to_overrides(text, expected, overrides):
    setting = parse_setting(text)
    assert setting == expected
    assert setting.overrides() == overrides


@pytest.mark.parametrize("text", ["dpmpp_2m", "dpmpp_2m-ten", "dpmpp_2m-10-fp8", "dpmpp_2m-10-bf16-x", "heun-10"])
def test_bad_settings_are_refused(text):
    with pytest.raises(Exception, match="setting|sampler|method"):
        parse_setting(text)
