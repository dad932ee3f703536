"""style_text_temperature: free text read through the training descriptions it resembles."""

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
    from dgsdp.generation.pipeline import recorded_text_reading

    assert recorded_text_reading(None) == (None, None)  # older checkpoints and the papers' rows
    assert recorded_text_reading({"generation": {"style_text_temperature": None}}) == (None, None)
    chosen = {"style_text_temperature": 0.02, "style_text_descriptions": "aistpp_augmented"}
    assert recorded_text_reading({"generation": chosen}) == (0.02, "aistpp_augmented")
    assert recorded_text_reading({"generation": {"style_text_temperature": "0.5"}}) == (0.5, None)
    # a checkpoint is data: it may name a shipped file, never a path to read
    for named in ("/etc/passwd", "../aistpp_augmented", "not_shipped"):
        with pytest.raises(ConfigError, match="not a shipped file's name"):
            recorded_text_reading({"generation": {"style_text_temperature": 0.02, "style_text_descriptions": named}})
    for bad in (0, -1, "warm"):
        with pytest.raises(ConfigError, match="not a positive number"):
            recorded_text_reading({"generation": {"style_text_temperature": bad}})


def test_generate_reads_the_temperature_setting():
    import pytest

    from dgsdp.cli.generate import text_temperature_setting
    from dgsdp.errors import ConfigError

    assert text_temperature_setting(None) is None
    assert text_temperature_setting("off") == text_temperature_setting(False) == "off"  # YAML 1.1 reads off as false
    assert text_temperature_setting("0.02") == 0.02
    with pytest.raises(ConfigError, match="positive number, off"):
        text_temperature_setting("warm")
