"""How free text is read: through the training descriptions it resembles (the blend) and the settings that choose
the reading (generate.py's style_text_reading, _temperature and _descriptions, and what a run records)."""

import pytest
import torch

from dgsdp.generation.pipeline import read_through_bank


def test_a_small_temperature_gives_the_nearest_description_and_a_large_one_their_mean():
    bank = torch.nn.functional.normalize(torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]), dim=-1)
    text = torch.tensor([0.9, 0.3, 0.1])
    assert torch.allclose(read_through_bank(text, bank, 1e-3), bank[0], atol=1e-4)
    assert torch.allclose(read_through_bank(text, bank, 1e3), bank.mean(0), atol=1e-3)
    weights = torch.softmax(torch.nn.functional.cosine_similarity(bank, text[None], dim=-1) / 0.1, 0)
    assert torch.allclose(read_through_bank(text, bank, 0.1), weights @ bank)


def test_other_descriptions_stand_for_the_values_given():
    keys = torch.nn.functional.normalize(torch.tensor([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]]), dim=-1)
    values = torch.tensor([[5.0, 5.0], [-1.0, 2.0], [-1.0, 2.0]])  # e.g. the genre means of each description's genre
    text = torch.tensor([0.2, 0.9, 0.3])
    assert torch.allclose(read_through_bank(text, keys, 1e-3, values), values[1], atol=1e-4)
    weights = torch.softmax(torch.nn.functional.cosine_similarity(keys, text[None], dim=-1) / 0.5, 0)
    assert torch.allclose(read_through_bank(text, keys, 0.5, values), weights @ values)


def test_the_reading_a_run_recorded():
    import pytest

    from dgsdp.errors import ConfigError
    from dgsdp.generation.pipeline import TextReadingChoice, recorded_text_reading

    assert recorded_text_reading(None) is None  # older checkpoints and the papers' rows
    assert recorded_text_reading({"generation": {"style_text_temperature": None}}) is None
    chosen = {"style_text_temperature": 0.02, "style_text_descriptions": "aistpp_augmented"}  # rows 10-12
    assert recorded_text_reading({"generation": chosen}) == TextReadingChoice("blend", 0.02, "aistpp_augmented")
    assert recorded_text_reading({"generation": {"style_text_temperature": "0.5"}}) == TextReadingChoice("blend", 0.5)
    routed = {"style_text_reading": "router", "style_text_descriptions": "aistpp_augmented"}  # row 13
    assert recorded_text_reading({"generation": routed}) == TextReadingChoice("router", None, "aistpp_augmented")
    # a checkpoint is data: it may name a shipped file, never a path to read
    for named in ("/etc/passwd", "../aistpp_augmented", "not_shipped"):
        with pytest.raises(ConfigError, match="not a shipped file's name"):
            recorded_text_reading({"generation": {"style_text_temperature": 0.02, "style_text_descriptions": named}})
    for bad in (0, -1, "warm"):
        with pytest.raises(ConfigError, match="not a positive number"):
            recorded_text_reading({"generation": {"style_text_temperature": bad}})
    with pytest.raises(ConfigError, match="style_text_reading must be one of"):
        recorded_text_reading({"generation": {"style_text_reading": "guess"}})


@pytest.mark.parametrize(
    ("settings", "expected"),
    [
        ({}, None),
        ({"style_text_temperature": "off"}, ("off", None, None)),
        ({"style_text_temperature": False}, ("off", None, None)),  # YAML 1.1 reads off as false
        ({"style_text_reading": False}, ("off", None, None)),
        ({"style_text_temperature": "0.02"}, ("blend", 0.02, None)),
        ({"style_text_reading": "router", "style_text_descriptions": "aistpp_augmented"},
         ("router", None, "aistpp_augmented")),
        ({"style_text_reading": "blend", "style_text_temperature": 0.1}, ("blend", 0.1, None)),
    ],
)  # fmt: skip
def test_generate_reads_the_text_reading_settings(settings, expected):
    from omegaconf import OmegaConf

    from dgsdp.cli.generate import text_reading_setting

    got = text_reading_setting(OmegaConf.create(settings))
    assert (got if got is None else (got.how, got.temperature, got.descriptions)) == expected


@pytest.mark.parametrize(
    ("settings", "message"),
    [
        ({"style_text_temperature": "warm"}, "positive number"),
        ({"style_text_reading": "blend"}, "positive number"),
        ({"style_text_reading": "router", "style_text_temperature": 0.1}, "takes none"),
        ({"style_text_reading": "nearest"}, "must be one of router, blend, off"),
        ({"style_text_descriptions": "aistpp_augmented"}, "set style_text_reading=router"),
    ],
)
def test_bad_text_reading_settings_are_one_error(settings, message):
    from omegaconf import OmegaConf

    from dgsdp.cli.generate import text_reading_setting
    from dgsdp.errors import ConfigError

    with pytest.raises(ConfigError, match=message):
        text_reading_setting(OmegaConf.create(settings))
