"""The sampling defaults are written once (SamplingSettings); the config group and its presets build on them."""

import dataclasses

from dgsdp.cli.config import compose_config
from dgsdp.sampling import SamplingSettings


def test_the_default_preset_is_the_dataclass_defaults():
    for name, overrides in (("generate", []), ("evaluate", ["sampling=dpmpp_2m"])):
        composed = SamplingSettings.from_config(compose_config(name, overrides).sampling)
        assert dataclasses.asdict(composed) == dataclasses.asdict(SamplingSettings()), name


def test_presets_change_only_what_they_name():
    base = dataclasses.asdict(SamplingSettings())
    ddim = dataclasses.asdict(SamplingSettings.from_config(compose_config("generate", ["sampling=ddim"]).sampling))
    assert {k for k in base if base[k] != ddim[k]} == {"method", "steps"}
