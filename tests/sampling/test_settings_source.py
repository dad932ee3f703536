"""The sampling defaults are written once (SamplingSettings); the config group and its presets build on them."""

import dataclasses

import pytest

from dgsdp.cli.config import compose_config
from dgsdp.errors import ConfigError
from dgsdp.sampling import SamplingSettings


def test_the_default_preset_is_the_dataclass_defaults():
    for name, overrides in (("generate", []), ("evaluate", ["sampling=dpmpp_2m"])):
        composed = SamplingSettings.from_config(compose_config(name, overrides).sampling)
        assert dataclasses.asdict(composed) == dataclasses.asdict(SamplingSettings()), name


def test_presets_change_only_what_they_name():
    base = dataclasses.asdict(SamplingSettings())
    ddim = dataclasses.asdict(SamplingSettings.from_config(compose_config("generate", ["sampling=ddim"]).sampling))
    assert {k for k in base if base[k] != ddim[k]} == {"method", "steps"}


def test_long_form_windows_overlap_by_half_whatever_the_window():
    default = SamplingSettings()
    # a 150-frame window: EDGE's 75; shorter windows still overlap by half (a 60-frame window once got none)
    assert [default.stride(w) for w in (150, 90, 60, 1)] == [75, 45, 30, 1]
    assert default.stride(300) == 75  # longer windows keep the 75 frames they had
    assert SamplingSettings(stride_frames=40).stride(150) == 40
    assert SamplingSettings(stride_frames=100).stride(60) == 60  # never past the window
    edge = SamplingSettings.from_config(compose_config("generate", ["sampling=edge"]).sampling)
    assert edge.stride(150) == 75
    with pytest.raises(ConfigError, match="stride_frames"):
        SamplingSettings(stride_frames=0)
