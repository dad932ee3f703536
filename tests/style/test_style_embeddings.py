"""Style embeddings and banks: sizes per kind, disk cache, free text, errors, configs."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import yaml
from hydra.utils import instantiate
from omegaconf import OmegaConf

from dgsdp.errors import ConfigError, DataError
from dgsdp.resources import CONFIG_DIR
from dgsdp.style.embeddings import DEFAULT_PROMPTS_FILE, StyleBank, StyleEmbedder
from dgsdp.style.vocab import AISTPP_GENRES


def shipped_prompts() -> dict[str, list[str]]:
    """The prompt texts read straight from the yaml (whitespace collapsed as the embedder does)."""
    raw = yaml.safe_load(DEFAULT_PROMPTS_FILE.read_text())
    return {code: [" ".join(t.split()) for t in texts] for code, texts in raw.items()}


@pytest.mark.parametrize("kind, dim", [("none", 0), ("onehot", 10), ("genre", 6), ("prompt", 6)])
def test_each_kind_gives_a_fixed_size_vector_per_genre(kind: str, dim: int, counting_encoder) -> None:
    embedder = StyleEmbedder(kind, text_encoder=counting_encoder if kind in ("genre", "prompt") else None)
    assert embedder.dim == dim
    for code in AISTPP_GENRES.codes:
        vector = embedder.embed_genre(code)
        assert vector.shape == (dim,) and vector.dtype == torch.float32
    bank = embedder.bank()
    assert bank.dim == dim and bank.n_genres == 10
    assert torch.equal(torch.bincount(bank.genre_index, minlength=10) > 0, torch.ones(10, dtype=torch.bool))


def test_onehot_rows() -> None:
    embedder = StyleEmbedder("onehot")
    expected = torch.zeros(10)
    expected[7] = 1.0
    assert torch.equal(embedder.embed_genre("gKR"), expected)
    assert torch.equal(embedder.embed_text("krump"), expected)
    assert torch.equal(embedder.bank().vectors, torch.eye(10))


def test_genre_kind_embeds_the_genre_names(counting_encoder) -> None:
    embedder = StyleEmbedder("genre", text_encoder=counting_encoder)
    assert torch.equal(embedder.embed_genre("MH"), counting_encoder.vector("Middle Hip-hop"))
    assert torch.equal(embedder.embed_genre("krump"), counting_encoder.vector("Krump"))


def test_prompt_bank_rows_and_genre_means(counting_encoder) -> None:
    embedder = StyleEmbedder("prompt", text_encoder=counting_encoder)
    bank = embedder.bank()
    prompts = shipped_prompts()
    assert len(bank) == sum(len(t) for t in prompts.values())
    for g, code in enumerate(AISTPP_GENRES.codes):
        rows = torch.stack([counting_encoder.vector(t) for t in prompts[code]])
        assert torch.equal(bank.vectors[bank.genre_index == g], rows)
        torch.testing.assert_close(embedder.embed_genre(code), rows.mean(0))


def test_second_bank_reads_the_disk_cache(tmp_path, counting_encoder_cls) -> None:
    first = counting_encoder_cls()
    bank1 = StyleEmbedder("prompt", text_encoder=first, cache_dir=tmp_path).bank()
    assert first.calls > 0
    second = counting_encoder_cls()
    bank2 = StyleEmbedder("prompt", text_encoder=second, cache_dir=tmp_path).bank()
    assert second.calls == 0, "a cached bank must not call the text encoder"
    assert torch.equal(bank1.vectors, bank2.vectors) and torch.equal(bank1.genre_index, bank2.genre_index)
    # Other encoder settings or other texts are a cache miss.
    salted = counting_encoder_cls(salt=1)
    StyleEmbedder("prompt", text_encoder=salted, cache_dir=tmp_path).bank()
    assert salted.calls > 0
    genre = counting_encoder_cls()
    StyleEmbedder("genre", text_encoder=genre, cache_dir=tmp_path).bank()
    assert genre.texts_seen == AISTPP_GENRES.names


def test_minilm_prompt_bank(tmp_path, minilm) -> None:
    """Real embeddings: genres differ, the same prompt is identical, and a cache hit never loads the model."""
    bank = StyleEmbedder("prompt", text_encoder=minilm, cache_dir=tmp_path).bank()
    assert bank.dim == 384
    means = torch.nn.functional.normalize(bank.means, dim=-1)
    similarity = means @ means.T
    off_diagonal = similarity[~torch.eye(10, dtype=torch.bool)]
    assert off_diagonal.max() < 0.95
    prompts = shipped_prompts()
    again = minilm.encode([prompts["KR"][0], prompts["KR"][0]])
    assert torch.equal(again[0], again[1])
    kr_rows = bank.vectors[bank.genre_index == 7]
    torch.testing.assert_close(kr_rows[0], again[0], atol=1e-5, rtol=1e-4)

    config = {"_target_": "dgsdp.style.MiniLMTextEncoder"}
    cached = StyleEmbedder("prompt", text_encoder=config, cache_dir=tmp_path)
    assert torch.equal(cached.bank().vectors, bank.vectors)
    assert not cached.text_encoder.loaded

    # A free-text description of krump lands closest to the krump genre mean.
    text = "Aggressive stomping with violent chest pops and hard arm swings, full of raw anger."
    vector = cached.embed_text(text)
    assert vector.shape == (384,)
    torch.testing.assert_close(vector, minilm.encode([text])[0], atol=1e-5, rtol=1e-4)
    assert int((means @ vector).argmax()) == AISTPP_GENRES.index("KR")


def test_free_text_rules(counting_encoder) -> None:
    prompt = StyleEmbedder("prompt", text_encoder=counting_encoder)
    text = "slow   graceful\nturns"
    assert torch.equal(prompt.embed_text(text), counting_encoder.vector("slow graceful turns"))
    assert torch.equal(prompt.embed("a new style"), counting_encoder.vector("a new style"))
    assert torch.equal(prompt.embed("KR"), prompt.embed_genre("KR"))
    with pytest.raises(ConfigError, match="empty"):
        prompt.embed_text("   ")
    with pytest.raises(ConfigError, match="one-hot.*genre names"):
        StyleEmbedder("onehot").embed_text("slow graceful turns")
    with pytest.raises(ConfigError, match="without style"):
        StyleEmbedder("none").embed_text("krump")


def test_unknown_genre_and_bad_settings(counting_encoder) -> None:
    embedder = StyleEmbedder("genre", text_encoder=counting_encoder)
    with pytest.raises(ConfigError) as info:
        embedder.embed_genre("tango")
    assert all(code in str(info.value) for code in AISTPP_GENRES.codes)
    with pytest.raises(ConfigError, match="Unknown style kind"):
        StyleEmbedder("emoji")
    with pytest.raises(ConfigError, match="text encoder"):
        StyleEmbedder("prompt")
    with pytest.raises(DataError, match="does not exist"):
        StyleEmbedder("prompt", text_encoder=counting_encoder, prompts_file="no/such.yaml").bank()


def test_custom_vocab_and_prompts(tmp_path, counting_encoder) -> None:
    prompts = tmp_path / "prompts.yaml"
    prompts.write_text("SA: [Quick hips and turns., Close partner spins.]\nTA: [Slow walks and sharp kicks.]\n")
    embedder = StyleEmbedder(
        "prompt",
        text_encoder=counting_encoder,
        vocab=[("SA", "Salsa"), ("TA", "Tango")],
        prompts_file=prompts,
    )
    bank = embedder.bank()
    assert bank.genre_index.tolist() == [0, 0, 1] and bank.n_genres == 2
    assert torch.equal(embedder.embed_genre("tango"), counting_encoder.vector("Slow walks and sharp kicks."))
    assert StyleEmbedder("onehot", vocab={"SA": "Salsa", "TA": "Tango"}).dim == 2


# StyleBank -------------------------------------------------------------------------------------------------


def small_bank() -> StyleBank:
    """Genre 0 has one row, genre 1 three rows, genre 2 none."""
    vectors = torch.tensor([[1.0, 0.0], [0.0, 2.0], [10.0, 0.0], [0.0, 4.0]])
    return StyleBank(vectors, torch.tensor([1, 0, 1, 1]), n_genres=3)


def test_bank_mean_for_hand_case() -> None:
    bank = small_bank()
    expected = torch.tensor([[0.0, 2.0], [11.0 / 3.0, 4.0 / 3.0], [0.0, 2.0]])
    torch.testing.assert_close(bank.mean_for(torch.tensor([0, 1, 0])), expected)


def test_bank_sample_stays_in_genre_and_covers_all_rows() -> None:
    bank = small_bank()
    genre_idx = torch.tensor([1] * 300 + [0] * 10)
    g = torch.Generator().manual_seed(0)
    out = bank.sample(genre_idx, generator=g)
    assert out.shape == (310, 2)
    genre1_rows = {(1.0, 0.0), (10.0, 0.0), (0.0, 4.0)}
    picked = {tuple(r.tolist()) for r in out[:300]}
    assert picked == genre1_rows  # only genre-1 rows, and each one at least once
    assert all(tuple(r.tolist()) == (0.0, 2.0) for r in out[300:])
    again = bank.sample(genre_idx, generator=torch.Generator().manual_seed(0))
    assert torch.equal(out, again)


def test_bank_errors_and_state_dict(tmp_path) -> None:
    bank = small_bank()
    with pytest.raises(DataError, match="no rows"):
        bank.sample(torch.tensor([2]))
    with pytest.raises(ConfigError, match="out of range"):
        bank.mean_for(torch.tensor([3]))
    path = tmp_path / "bank.pt"
    torch.save(bank.state_dict(), path)
    loaded = StyleBank.from_state_dict(torch.load(path, weights_only=True))
    assert torch.equal(loaded.vectors, bank.vectors) and torch.equal(loaded.genre_index, bank.genre_index)
    assert loaded.n_genres == 3


# Configs ---------------------------------------------------------------------------------------------------


def compose(style: str, text_encoder: str, cache_dir: Path):
    cfg = OmegaConf.create({"paths": {"cache_dir": str(cache_dir)}})
    cfg.text_encoder = OmegaConf.load(CONFIG_DIR / "text_encoder" / f"{text_encoder}.yaml")
    cfg.style = OmegaConf.load(CONFIG_DIR / "style" / f"{style}.yaml")
    return cfg


@pytest.mark.parametrize(
    "style, text_encoder, dim",
    [
        ("none", "minilm", 0),
        ("onehot", "minilm", 10),
        ("genre", "minilm", 384),
        ("prompt", "minilm", 384),
        ("genre", "clip", 512),
        ("prompt", "clip", 512),
    ],
)
def test_style_configs_instantiate_lazily(style: str, text_encoder: str, dim: int, tmp_path) -> None:
    cfg = compose(style, text_encoder, tmp_path)
    embedder = instantiate(cfg.style)
    assert isinstance(embedder, StyleEmbedder) and embedder.kind == style and embedder.dim == dim
    assert embedder.cache_dir == tmp_path
    if style in ("genre", "prompt"):
        assert not embedder.text_encoder.loaded  # building the config never loads weights
        assert embedder.settings()["text_encoder"]["name"] == text_encoder
    if style == "prompt":
        assert embedder.prompts_file.resolve() == DEFAULT_PROMPTS_FILE
        assert len(embedder.settings()["prompts_hash"]) == 16


def test_style_injection_configs() -> None:
    modulation = OmegaConf.load(CONFIG_DIR / "style_injection" / "modulation.yaml")
    concat = OmegaConf.load(CONFIG_DIR / "style_injection" / "concat.yaml")
    assert (modulation.mode, modulation.variant, modulation.also_concat) == ("modulation", "official", True)
    assert concat.mode == "concat" and "variant" in concat and "also_concat" in concat
