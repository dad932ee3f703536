"""The shipped description prompts and the prompts-file reader."""

from __future__ import annotations

import re

import pytest
import yaml

from dgsdp.errors import DataError
from dgsdp.style.embeddings import DEFAULT_PROMPTS_FILE, load_prompts
from dgsdp.style.vocab import AISTPP_GENRES, GenreVocab


def test_shipped_prompts_cover_every_genre_with_distinct_descriptions() -> None:
    raw = yaml.safe_load(DEFAULT_PROMPTS_FILE.read_text())
    assert sorted(raw) == sorted(AISTPP_GENRES.codes)
    per_genre = load_prompts(DEFAULT_PROMPTS_FILE)
    all_texts = [t for texts in per_genre for t in texts]
    assert len(set(all_texts)) == len(all_texts), "descriptions must be distinct"
    for code, texts in zip(AISTPP_GENRES.codes, per_genre):
        assert len(texts) >= 4, code
        for text in texts:
            sentences = [s for s in re.split(r"[.!?]\s", text) if s.strip()]
            assert len(sentences) >= 2, text
            assert 25 <= len(text.split()) <= 90, text
            assert "\n" not in text and "  " not in text


def test_prompts_file_errors(tmp_path) -> None:
    vocab = GenreVocab([("SA", "Salsa"), ("TA", "Tango")])
    good = tmp_path / "good.yaml"
    good.write_text("SA: [Quick hips., Turns.]\ntango: Slow walks.\n")
    assert load_prompts(good, vocab) == [["Quick hips.", "Turns."], ["Slow walks."]]

    missing = tmp_path / "missing.yaml"
    missing.write_text("SA: [Quick hips.]\n")
    with pytest.raises(DataError, match="TA"):
        load_prompts(missing, vocab)

    unknown = tmp_path / "unknown.yaml"
    unknown.write_text("SA: [a]\nTA: [b]\nXX: [c]\n")
    with pytest.raises(DataError, match="Unknown genre 'XX'"):
        load_prompts(unknown, vocab)

    with pytest.raises(DataError, match="does not exist"):
        load_prompts(tmp_path / "nope.yaml", vocab)
