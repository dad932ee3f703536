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
