"""Genre vocabulary: AIST++ order, lenient lookup, clear errors, custom vocabularies."""

from __future__ import annotations

import pytest

from dgsdp.errors import ConfigError, DataError
from dgsdp.style.vocab import AISTPP_GENRES, GenreVocab

EXPECTED = [
    ("BR", "Break"),
    ("PO", "Pop"),
    ("LO", "Lock"),
    ("MH", "Middle Hip-hop"),
    ("LH", "LA-style Hip-hop"),
    ("HO", "House"),
    ("WA", "Waack"),
    ("KR", "Krump"),
    ("JS", "Street Jazz"),
    ("JB", "Ballet Jazz"),
]


def test_aistpp_order_codes_and_names() -> None:
    assert len(AISTPP_GENRES) == 10
    assert AISTPP_GENRES.codes == [c for c, _ in EXPECTED]
    assert AISTPP_GENRES.names == [n for _, n in EXPECTED]
    assert list(AISTPP_GENRES) == [c for c, _ in EXPECTED]


@pytest.mark.parametrize("key", ["KR", "gKR", "krump", "Krump", "kr", " KRUMP ", "gkr"])
def test_index_accepts_codes_names_any_case(key: str) -> None:
    assert AISTPP_GENRES.index(key) == 7


@pytest.mark.parametrize(
    "key, expected",
    [
        ("BR", 0),
        ("break", 0),
        ("middle hip-hop", 3),
        ("Middle Hip Hop", 3),
        ("la-style hip-hop", 4),
        ("LA_style_hip_hop", 4),
        ("gJB", 9),
        ("ballet jazz", 9),
        ("Street Jazz", 8),
        (5, 5),
    ],
)
def test_index_table(key: str | int, expected: int) -> None:
    assert AISTPP_GENRES.index(key) == expected
    assert AISTPP_GENRES.code(key) == EXPECTED[expected][0]
    assert AISTPP_GENRES.name(key) == EXPECTED[expected][1]


@pytest.mark.parametrize("key", ["tango", "hip-hop", "g", "", 10, -1])
def test_unknown_genre_lists_known_ones(key: str | int) -> None:
    with pytest.raises(ConfigError) as info:
        AISTPP_GENRES.index(key)
    message = str(info.value)
    for code, name in EXPECTED:
        assert code in message and name in message


def test_contains() -> None:
    assert "gWA" in AISTPP_GENRES and "waack" in AISTPP_GENRES
    assert "salsa" not in AISTPP_GENRES and 3 not in AISTPP_GENRES


def test_custom_vocab_from_list_and_yaml(tmp_path) -> None:
    vocab = GenreVocab([("SA", "Salsa"), ("TA", "Tango")])
    assert len(vocab) == 2 and vocab.index("tango") == 1
    path = tmp_path / "genres.yaml"
    path.write_text("SA: Salsa\nTA: Tango\nWZ: Waltz\n")
    from_file = GenreVocab.from_yaml(path)
    assert from_file.codes == ["SA", "TA", "WZ"] and from_file.index("waltz") == 2
    assert from_file.to_dict() == {"SA": "Salsa", "TA": "Tango", "WZ": "Waltz"}
    assert GenreVocab(from_file.to_dict()) == from_file


def test_bad_vocabularies() -> None:
    with pytest.raises(ConfigError):
        GenreVocab([])
    with pytest.raises(ConfigError, match="unique"):
        GenreVocab([("SA", "Salsa"), ("sa", "Samba")])
    with pytest.raises(DataError, match="does not exist"):
        GenreVocab.from_yaml("no/such/genres.yaml")
