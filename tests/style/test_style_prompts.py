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


def test_augmented_prompts_keep_the_shipped_ones_first_and_add_short_distinct_ones() -> None:
    from dgsdp.style.embeddings import resolve_prompts_file

    path = resolve_prompts_file("aistpp_augmented")
    assert path == DEFAULT_PROMPTS_FILE.parent / "aistpp_augmented.yaml"
    shipped, augmented = load_prompts(DEFAULT_PROMPTS_FILE), load_prompts(path)
    all_texts = [t for texts in augmented for t in texts]
    assert len(set(all_texts)) == len(all_texts)
    for code, ours, theirs in zip(AISTPP_GENRES.codes, shipped, augmented):
        assert theirs[: len(ours)] == ours, code
        short = theirs[len(ours) :]
        assert len(short) == 16 and all(6 <= len(t.split()) <= 20 for t in short), code


def test_prompts_file_by_shipped_name_path_or_clear_error(tmp_path, monkeypatch) -> None:
    from dgsdp.style.embeddings import StyleEmbedder, resolve_prompts_file

    monkeypatch.chdir(tmp_path)  # a name resolves from any folder
    assert resolve_prompts_file("aistpp_augmented.yaml") == resolve_prompts_file("aistpp_augmented")
    own = tmp_path / "aistpp_augmented.yaml"  # a file of the user's own with that name wins
    own.write_text(yaml.safe_dump({code: ["one text"] for code in AISTPP_GENRES.codes}))
    assert resolve_prompts_file("aistpp_augmented.yaml") == own.relative_to(tmp_path)
    with pytest.raises(DataError, match="aistpp_augmented"):  # the error lists the shipped names
        load_prompts(resolve_prompts_file("no_such_prompts"))
    embedder = StyleEmbedder(kind="onehot", prompts_file="finedance")
    assert embedder.prompts_file == DEFAULT_PROMPTS_FILE.parent / "finedance.yaml"


def test_prompts_file_includes_others_first(tmp_path) -> None:
    vocab = GenreVocab([("SA", "Salsa"), ("TA", "Tango")])
    (tmp_path / "base.yaml").write_text("SA: [Quick hips.]\nTA: [Slow walks.]\n")
    (tmp_path / "more.yaml").write_text("include: base\nSA: [Turns.]\n")
    assert load_prompts(tmp_path / "more.yaml", vocab) == [["Quick hips.", "Turns."], ["Slow walks."]]
    sub = tmp_path / "sub"
    sub.mkdir()
    (sub / "most.yaml").write_text("include: [../more.yaml]\nTA: [Sharp heads.]\n")  # a path beside the includer
    assert load_prompts(sub / "most.yaml", vocab) == [["Quick hips.", "Turns."], ["Slow walks.", "Sharp heads."]]

    (tmp_path / "loop_a.yaml").write_text("include: loop_b\nSA: [a]\nTA: [b]\n")
    (tmp_path / "loop_b.yaml").write_text("include: loop_a\n")
    with pytest.raises(DataError, match="includes itself"):
        load_prompts(tmp_path / "loop_a.yaml", vocab)
    (tmp_path / "lost.yaml").write_text("include: no_such_file\nSA: [a]\nTA: [b]\n")
    with pytest.raises(DataError, match=r"no_such_file.*included by .*lost\.yaml"):
        load_prompts(tmp_path / "lost.yaml", vocab)
    (tmp_path / "bad.yaml").write_text("include: {a: 1}\nSA: [a]\nTA: [b]\n")
    with pytest.raises(DataError, match="include must name prompts files"):
        load_prompts(tmp_path / "bad.yaml", vocab)


def test_reader_descriptions_add_movement_ones_to_the_augmented() -> None:
    """The free-text reader's descriptions: the augmented ones first, then 24 more per genre that are new, distinct
    and do not name their genre (tests/benchmarks keeps them apart from the held-out descriptions)."""
    from dgsdp.style.embeddings import resolve_prompts_file

    augmented = load_prompts(resolve_prompts_file("aistpp_augmented"))
    reader = load_prompts(resolve_prompts_file("aistpp_reader"))
    everything = [t for texts in reader for t in texts]
    assert len(set(everything)) == len(everything)
    for code, name, ours, theirs in zip(AISTPP_GENRES.codes, AISTPP_GENRES.names, augmented, reader):
        assert theirs[: len(ours)] == ours, code
        added = theirs[len(ours) :]
        assert len(added) == 24, code
        own_words = {w for w in re.split(r"[\s-]+", name.lower()) if w not in ("style", "la-style", "la")}
        for text in added:
            assert not own_words & set(re.findall(r"[a-z]+", text.lower())), (code, text)
