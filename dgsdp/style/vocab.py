"""Dance-genre vocabulary: the fixed order of genres that one-hot vectors, labels and prompt banks share.

AIST++ names its genres by two-letter codes (``gKR`` in file names). Users type codes or names in any case
("KR", "gKR", "krump", "Middle Hip-hop"); :meth:`GenreVocab.index` turns all of those into the same index.
Other datasets build their own vocabulary from a list or a yaml file.
"""

from __future__ import annotations

import difflib
import os
import re
from collections.abc import Iterable, Iterator, Mapping
from pathlib import Path

import yaml

from dgsdp.errors import ConfigError, DataError
from dgsdp.resources import FINEDANCE_DIR

FREE_TEXT_PREFIX = "text:"
"""``style="text: locking"`` uses the words as a free-text description even when they look like a genre name."""


def split_free_text(style: str) -> tuple[str, bool]:
    """``(text, True)`` for a style marked as free text with :data:`FREE_TEXT_PREFIX`, else ``(style, False)``."""
    stripped = style.strip()
    if stripped.lower().startswith(FREE_TEXT_PREFIX):
        return stripped[len(FREE_TEXT_PREFIX) :].strip(), True
    return style, False


def _normalise(key: str) -> str:
    """Lower-case and drop spaces, hyphens and underscores, so "LA-style Hip-hop" == "la style hiphop"."""
    return re.sub(r"[\s\-_]+", "", key.strip().lower())


class GenreVocab:
    """An ordered list of genres, each with a short code and a display name.

    Index order is the order given; it fixes one-hot columns and label ids, so never reorder a vocabulary
    that a checkpoint was trained with.
    """

    def __init__(self, genres: Mapping[str, str] | Iterable[tuple[str, str]]) -> None:
        pairs = list(genres.items()) if isinstance(genres, Mapping) else [tuple(g) for g in genres]
        if not pairs:
            raise ConfigError("A genre vocabulary needs at least one genre (code and name).")
        self._codes: list[str] = []
        self._names: list[str] = []
        self._lookup: dict[str, int] = {}
        for i, pair in enumerate(pairs):
            if len(pair) != 2 or not all(isinstance(p, str) and p.strip() for p in pair):
                raise ConfigError(f"Genre entry {pair!r} must be a (code, name) pair of non-empty strings.")
            code, name = (p.strip() for p in pair)
            self._codes.append(code)
            self._names.append(name)
            for key in {_normalise(code), _normalise(name)}:
                if key in self._lookup and self._lookup[key] != i:
                    raise ConfigError(f"Genre key {key!r} is used by two genres; codes and names must be unique.")
                self._lookup[key] = i

    @classmethod
    def from_yaml(cls, path: str | os.PathLike) -> GenreVocab:
        """Read a yaml mapping ``code: name`` (order kept) or a list of ``[code, name]`` pairs."""
        path = Path(path)
        if not path.is_file():
            raise DataError(f"Genre vocabulary file {path} does not exist; give a yaml file of `code: name` lines.")
        with open(path, encoding="utf-8") as f:
            data = yaml.safe_load(f)
        if not isinstance(data, Mapping | list):
            raise DataError(f"Genre vocabulary file {path} must hold a `code: name` mapping or a list of pairs.")
        return cls(data)

    @classmethod
    def named(cls, name: str) -> GenreVocab:
        """The genre vocabulary of a dataset the project reads, by name (see :data:`DATASET_VOCABS`)."""
        if name not in DATASET_VOCABS:
            raise ConfigError(f"no genre vocabulary named {name!r}; named ones: {', '.join(DATASET_VOCABS)}")
        found = DATASET_VOCABS[name]
        return found if isinstance(found, GenreVocab) else cls.from_yaml(found)

    @property
    def codes(self) -> list[str]:
        return list(self._codes)

    @property
    def names(self) -> list[str]:
        return list(self._names)

    def __len__(self) -> int:
        return len(self._codes)

    def __iter__(self) -> Iterator[str]:
        """Iterate over codes in index order."""
        return iter(self._codes)

    def __contains__(self, key: object) -> bool:
        return isinstance(key, str) and self._find(key) is not None

    def __eq__(self, other: object) -> bool:
        return isinstance(other, GenreVocab) and self.to_dict() == other.to_dict()

    def __hash__(self) -> int:
        return hash(tuple(self._codes))

    def __repr__(self) -> str:
        return f"GenreVocab({self.describe()})"

    def _find(self, key: str) -> int | None:
        norm = _normalise(key)
        if norm in self._lookup:
            return self._lookup[norm]
        # AIST++ file names prefix the code with "g" (gKR); accept that form too.
        if norm.startswith("g") and norm[1:] in self._lookup:
            return self._lookup[norm[1:]]
        return None

    def suggest(self, key: str) -> str | None:
        """The genre a short style string was probably meant to name ("locking" -> "Lock", "krumpp" -> "Krump"),
        or None when it is a known genre or reads as a description rather than a misspelt genre."""
        if self._find(key) is not None or not re.fullmatch(r"[\w\s-]{2,30}", key.strip()) or len(key.split()) > 3:
            return None
        words = key.split()
        spans = [" ".join(words[i:j]) for i in range(len(words)) for j in range(i + 1, len(words) + 1)]
        if any(self._find(span) is not None for span in spans if span != " ".join(words)):
            return None  # a genre with other words ("slow ballet jazz"): a description, not a misspelt genre
        norm = _normalise(key)
        for i, name in enumerate(self._names):  # "locking", "popping", "krumping": a genre name plus an ending
            name_norm = _normalise(name)
            if len(name_norm) >= 3 and norm.startswith(name_norm) and len(norm) - len(name_norm) <= 4:
                return self._names[i]
        by_key = {_normalise(n): n for n in self._names}
        close = difflib.get_close_matches(norm, list(by_key), n=1, cutoff=0.75)
        return by_key[close[0]] if close else None

    def check_not_near_miss(self, key: str) -> None:
        """ConfigError when ``key`` is not a genre but is close to one: say which, and how to mean free text."""
        suggestion = self.suggest(key)
        if suggestion is not None:
            raise ConfigError(
                f"style {key!r} is not a genre; did you mean {suggestion.lower()!r} ({self.code(suggestion)})? "
                f"To use it as a free-text description on purpose, write style='{FREE_TEXT_PREFIX} {key}'. "
                f"Known genres: {self.describe()}."
            )

    def index(self, key: str | int) -> int:
        """Index of a genre given by code ("KR", "gKR") or name ("krump"), case-insensitive; ints pass through."""
        if isinstance(key, int) and not isinstance(key, bool):
            if 0 <= key < len(self):
                return key
            raise ConfigError(f"Genre index {key} is out of range; known genres: {self.describe()}.")
        found = self._find(str(key))
        if found is None:
            raise ConfigError(f"Unknown genre {key!r}. Known genres (code or name, any case): {self.describe()}.")
        return found

    def code(self, key: str | int) -> str:
        return self._codes[self.index(key)]

    def name(self, key: str | int) -> str:
        return self._names[self.index(key)]

    def describe(self) -> str:
        """One line listing the genres, e.g. ``BR (Break), PO (Pop), ...``."""
        return ", ".join(f"{c} ({n})" for c, n in zip(self._codes, self._names))

    def to_dict(self) -> dict[str, str]:
        """Plain ``{code: name}`` in index order (for checkpoints and cache keys)."""
        return dict(zip(self._codes, self._names))


AISTPP_GENRES = GenreVocab(
    [
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
)
"""The 10 AIST++ genres in the index order used throughout the project."""

DATASET_VOCABS: dict[str, GenreVocab | Path] = {"aistpp": AISTPP_GENRES, "finedance": FINEDANCE_DIR / "genres.yaml"}
"""The genre vocabularies of the datasets the project reads, by the name configs give (``data.vocab``,
``style.vocab``): AIST++'s 10 genres, FineDance's 16 (``dgsdp/resources/finedance/genres.yaml``)."""
