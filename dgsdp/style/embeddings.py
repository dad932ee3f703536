"""Style embeddings (DGSDP): none, one-hot, genre-name embedding, or description-prompt embedding.

:class:`StyleEmbedder` turns genres (and, at inference, free text) into style vectors. Training reads a
precomputed :class:`StyleBank` (one or more rows per genre), cached on disk, so a text encoder is loaded at
most once per set of texts and settings, never in every run.
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Literal

import numpy as np
import torch
import yaml

from dgsdp.errors import ConfigError, DataError
from dgsdp.resources import FINEDANCE_PROMPTS_FILE, STYLE_PROMPTS_FILE
from dgsdp.style.text_encoders import TextEncoder, plain_config
from dgsdp.style.vocab import AISTPP_GENRES, DATASET_VOCABS, GenreVocab, split_free_text
from dgsdp.utils.io import DiskCache, stable_hash

StyleKind = Literal["none", "onehot", "genre", "prompt"]
STYLE_KINDS: tuple[str, ...] = ("none", "onehot", "genre", "prompt")

DEFAULT_PROMPTS_FILE = STYLE_PROMPTS_FILE
"""The shipped AIST++ description prompts (``dgsdp/resources/style_prompts/aistpp.yaml``)."""
DATASET_PROMPTS_FILES = {"aistpp": STYLE_PROMPTS_FILE, "finedance": FINEDANCE_PROMPTS_FILE}
"""The shipped description prompts of each named vocabulary (:data:`dgsdp.style.vocab.DATASET_VOCABS`)."""


SHIPPED_PROMPTS_DIR = STYLE_PROMPTS_FILE.parent
"""The shipped prompt files; ``style.prompts_file`` may name one by its stem (``aistpp_augmented``)."""


def resolve_prompts_file(prompts_file: str | os.PathLike, shipped_dir: Path = SHIPPED_PROMPTS_DIR) -> Path:
    """A prompts file given as a path, or as the name of a shipped one (``<shipped_dir>/<name>.yaml``, by default
    ``dgsdp/resources/style_prompts/``) when no such path exists: ``style.prompts_file=aistpp_augmented`` works from
    any folder and in checkpoints."""
    path = Path(prompts_file)
    if not path.exists() and path.parent == Path("."):
        shipped = shipped_dir / (path.name if path.suffix == ".yaml" else f"{path.name}.yaml")
        if shipped.is_file():
            return shipped
    return path


def default_prompts_file(vocab: GenreVocab) -> Path:
    """The shipped prompts of a dataset's vocabulary (FineDance's for FineDance's genres), else AIST++'s."""
    for name, path in DATASET_PROMPTS_FILES.items():
        if GenreVocab.named(name) == vocab:
            return path
    return DEFAULT_PROMPTS_FILE


class StyleBank:
    """Precomputed style vectors: ``vectors (P, dim)`` with ``genre_index (P,)`` naming each row's genre.

    Prompt banks hold several rows per genre; :meth:`sample` picks one at random per item (training
    augmentation) and :meth:`mean_for` gives the genre's mean row (deterministic, for evaluation).
    """

    def __init__(self, vectors: torch.Tensor, genre_index: torch.Tensor, n_genres: int) -> None:
        vectors = torch.as_tensor(vectors, dtype=torch.float32)
        genre_index = torch.as_tensor(genre_index, dtype=torch.long, device=vectors.device)
        if vectors.ndim != 2 or genre_index.shape != (vectors.shape[0],):
            raise DataError(
                f"A style bank needs vectors (P, dim) and genre_index (P,); got {tuple(vectors.shape)} and "
                f"{tuple(genre_index.shape)}. Delete the style cache folder to rebuild it."
            )
        if genre_index.numel() and (genre_index.min() < 0 or genre_index.max() >= n_genres):
            raise DataError(f"Style bank genre_index must lie in [0, {n_genres}); delete the style cache to rebuild.")
        self.vectors = vectors
        self.genre_index = genre_index
        self.n_genres = int(n_genres)
        self._index_tables()

    def _index_tables(self) -> None:
        """Rows sorted by genre, with per-genre start offsets and counts, and per-genre means."""
        self._order = torch.argsort(self.genre_index, stable=True)
        self.counts = torch.bincount(self.genre_index, minlength=self.n_genres)  # (G,)
        self._offsets = torch.cumsum(self.counts, 0) - self.counts  # (G,)
        sums = torch.zeros(self.n_genres, self.dim, device=self.vectors.device)
        sums.index_add_(0, self.genre_index, self.vectors)
        self.means = sums / self.counts.clamp_min(1).unsqueeze(1).to(sums.dtype)  # (G, dim)

    @property
    def dim(self) -> int:
        return int(self.vectors.shape[1])

    def __len__(self) -> int:
        return int(self.vectors.shape[0])

    def to(self, device: torch.device | str) -> StyleBank:
        return StyleBank(self.vectors.to(device), self.genre_index.to(device), self.n_genres)

    def _check(self, genre_idx: torch.Tensor) -> torch.Tensor:
        genre_idx = torch.as_tensor(genre_idx, dtype=torch.long).to(self.vectors.device)
        if genre_idx.numel():
            if genre_idx.min() < 0 or genre_idx.max() >= self.n_genres:
                raise ConfigError(f"Genre index out of range [0, {self.n_genres}): {genre_idx.tolist()}.")
            missing = genre_idx[self.counts[genre_idx] == 0]
            if missing.numel():
                raise DataError(f"The style bank has no rows for genre index(es) {sorted(set(missing.tolist()))}.")
        return genre_idx

    def sample(
        self, genre_idx: torch.Tensor, generator: torch.Generator | None = None, *, check: bool = True
    ) -> torch.Tensor:
        """One random row of each item's genre: ``genre_idx (B,)`` -> ``(B, dim)`` on the bank's device.

        ``generator`` (optional, for reproducibility) must live on the bank's device; see :meth:`to`.
        ``check=False`` skips the range checks, which read values back from the device (training steps).
        """
        genre_idx = self._check(genre_idx) if check else genre_idx.to(self.vectors.device, torch.long)
        u = torch.rand(genre_idx.shape, generator=generator, device=self.vectors.device)
        counts = self.counts[genre_idx]
        pick = torch.minimum((u * counts).long(), counts - 1)  # uniform in [0, count)
        rows = self._order[self._offsets[genre_idx] + pick]
        return self.vectors[rows]

    def mean_for(self, genre_idx: torch.Tensor, *, check: bool = True) -> torch.Tensor:
        """Mean row of each item's genre: ``genre_idx (B,)`` -> ``(B, dim)``; ``check`` as in :meth:`sample`."""
        return self.means[self._check(genre_idx) if check else genre_idx.to(self.vectors.device, torch.long)]

    def state_dict(self) -> dict[str, torch.Tensor]:
        """Plain tensors, safe for ``torch.load(weights_only=True)``."""
        return {
            "vectors": self.vectors.detach().cpu(),
            "genre_index": self.genre_index.detach().cpu(),
            "n_genres": torch.tensor(self.n_genres),
        }

    @classmethod
    def from_state_dict(cls, state: Mapping[str, torch.Tensor]) -> StyleBank:
        return cls(state["vectors"], state["genre_index"], int(state["n_genres"]))


INCLUDE_KEY = "include"
"""A prompts file's key naming other prompts files (shipped names or paths beside it) whose texts come first."""
MAX_INCLUDE_DEPTH = 4


def load_prompts(path: str | os.PathLike, vocab: GenreVocab = AISTPP_GENRES) -> list[list[str]]:
    """Read a prompts yaml (``genre: [text, ...]``) -> one list of texts per genre, in vocabulary order. The file may
    start from others (``include: [aistpp_augmented]``: shipped names, or paths relative to the file); their texts
    come first, then the file's own."""
    per_genre = _read_prompts(Path(path), vocab, ())
    missing = [vocab.codes[g] for g, texts in enumerate(per_genre) if not texts]
    if missing:
        raise DataError(f"Style prompts file {path} has no descriptions for genre(s) {', '.join(missing)}.")
    return per_genre


def _included(name: str, includer: Path) -> Path:
    """An included prompts file: beside the including one (with or without ``.yaml``), else a shipped name."""
    beside = includer.parent / name
    for candidate in (beside, beside.with_name(f"{beside.name}.yaml")):
        if candidate.is_file():
            return candidate
    return resolve_prompts_file(name)


def _read_prompts(path: Path, vocab: GenreVocab, chain: tuple[Path, ...]) -> list[list[str]]:
    if not path.is_file():
        shipped = ", ".join(sorted(p.stem for p in SHIPPED_PROMPTS_DIR.glob("*.yaml")))
        where = f" (included by {chain[-1]})" if chain else ""
        raise DataError(
            f"Style prompts file {path}{where} does not exist; point style.prompts_file at a yaml file, or name a "
            f"shipped one ({shipped})."
        )
    if path.resolve() in chain or len(chain) >= MAX_INCLUDE_DEPTH:
        raise DataError(
            f"Style prompts file {path} includes itself or nests includes deeper than {MAX_INCLUDE_DEPTH} "
            f"({' -> '.join(str(p) for p in chain)}); include each file once"
        )
    with open(path, encoding="utf-8") as f:
        data = yaml.safe_load(f)
    if not isinstance(data, Mapping):
        raise DataError(f"Style prompts file {path} must map each genre to a list of description texts.")
    per_genre: list[list[str]] = [[] for _ in range(len(vocab))]
    includes = data.get(INCLUDE_KEY, [])
    includes = [includes] if isinstance(includes, str) else includes
    if not isinstance(includes, list) or not all(isinstance(i, str) and i.strip() for i in includes):
        raise DataError(f"In style prompts file {path}: {INCLUDE_KEY} must name prompts files (a name or a list).")
    for name in includes:
        for g, texts in enumerate(_read_prompts(_included(name, path), vocab, (*chain, path.resolve()))):
            per_genre[g].extend(texts)
    for key, texts in data.items():
        if key == INCLUDE_KEY:
            continue
        try:
            g = vocab.index(str(key))
        except ConfigError as e:
            raise DataError(f"In style prompts file {path}: {e}") from e
        if isinstance(texts, str):
            texts = [texts]
        if not isinstance(texts, list) or not all(isinstance(t, str) and t.strip() for t in texts):
            raise DataError(f"In style prompts file {path}: genre {key!r} must have a list of non-empty texts.")
        per_genre[g].extend(" ".join(t.split()) for t in texts)
    return per_genre


class StyleEmbedder:
    """Builds style vectors of one kind for a genre vocabulary.

    kind: ``none`` (dim 0), ``onehot`` (dim = number of genres), ``genre`` (text embedding of each genre
    name) or ``prompt`` (text embeddings of the description prompts in ``prompts_file``, several per genre).
    text_encoder: a :class:`TextEncoder`, or its config (a mapping with ``_target_``) that is only
    instantiated when first needed; required for ``genre`` and ``prompt``.
    cache_dir: where computed banks are kept (``None``: no disk cache).
    """

    def __init__(
        self,
        kind: StyleKind = "prompt",
        text_encoder: TextEncoder | Mapping[str, Any] | None = None,
        vocab: GenreVocab | Sequence[tuple[str, str]] | Mapping[str, str] | str | os.PathLike | None = None,
        prompts_file: str | os.PathLike | None = None,
        cache_dir: str | os.PathLike | None = None,
    ) -> None:
        if kind not in STYLE_KINDS:
            raise ConfigError(f"Unknown style kind {kind!r}; use one of {', '.join(STYLE_KINDS)}.")
        self.kind = kind
        self.vocab = _as_vocab(vocab)
        self.prompts_file = (
            resolve_prompts_file(prompts_file) if prompts_file is not None else default_prompts_file(self.vocab)
        )
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        if kind in ("genre", "prompt") and text_encoder is None:
            raise ConfigError(f"style kind {kind!r} needs a text encoder; set text_encoder (e.g. text_encoder=minilm).")
        self._encoder_cfg: dict[str, Any] | None = None
        self._encoder: TextEncoder | None = None
        if isinstance(text_encoder, TextEncoder):
            self._encoder = text_encoder
        elif text_encoder is not None:
            self._encoder_cfg = plain_config(text_encoder)
            if not isinstance(self._encoder_cfg, dict) or "_target_" not in self._encoder_cfg:
                raise ConfigError("text_encoder must be a TextEncoder or a config mapping with a _target_.")
        self._bank: StyleBank | None = None
        self._text_memo: dict[str, torch.Tensor] = {}

    @property
    def text_encoder(self) -> TextEncoder:
        """The text encoder, instantiated from its config on first use (its weights load on first encode)."""
        if self._encoder is None:
            if self._encoder_cfg is None:
                raise ConfigError(f"style kind {self.kind!r} uses no text encoder.")
            from dgsdp.registry import build

            # registered classes only, nothing imported: this config may come from a checkpoint
            encoder = build(self._encoder_cfg, "text_encoder", where="style.text_encoder", source="checkpoint")
            if not isinstance(encoder, TextEncoder):
                raise ConfigError(f"text_encoder config built a {type(encoder).__name__}, not a TextEncoder.")
            self._encoder = encoder
        return self._encoder

    @property
    def dim(self) -> int:
        if self.kind == "none":
            return 0
        if self.kind == "onehot":
            return len(self.vocab)
        return self.text_encoder.dim

    def settings(self) -> dict[str, Any]:
        """Plain dict describing the style space (stored with checkpoints to catch mismatches)."""
        out: dict[str, Any] = {"kind": self.kind, "vocab": self.vocab.to_dict(), "dim": self.dim}
        if self.kind in ("genre", "prompt"):
            out["text_encoder"] = self.text_encoder.settings()
        if self.kind == "prompt":
            out["prompts_hash"] = stable_hash(self.bank_texts())
        return out

    def bank_texts(self) -> tuple[list[str], list[int]]:
        """Texts embedded into the bank and each text's genre index (empty for none/onehot)."""
        if self.kind == "genre":
            return self.vocab.names, list(range(len(self.vocab)))
        if self.kind == "prompt":
            per_genre = load_prompts(self.prompts_file, self.vocab)
            texts = [t for texts in per_genre for t in texts]
            index = [g for g, texts in enumerate(per_genre) for _ in texts]
            return texts, index
        return [], []

    def bank(self) -> StyleBank:
        """All precomputed style vectors; text embeddings come from the disk cache when possible."""
        if self._bank is None:
            n = len(self.vocab)
            if self.kind == "none":
                self._bank = StyleBank(torch.zeros(n, 0), torch.arange(n), n)
            elif self.kind == "onehot":
                self._bank = StyleBank(torch.eye(n), torch.arange(n), n)
            else:
                texts, index = self.bank_texts()
                self._bank = StyleBank(self._encode_cached(texts), torch.tensor(index), n)
        return self._bank

    def _encode_cached(self, texts: list[str]) -> torch.Tensor:
        """``(N, dim)`` embeddings of ``texts``, keyed on disk by encoder settings and the exact texts."""
        encoder = self.text_encoder

        def compute() -> dict[str, np.ndarray]:
            return {"vectors": encoder.encode(texts).numpy()}

        if self.cache_dir is None:
            return torch.from_numpy(compute()["vectors"])
        settings = encoder.settings()
        cache = DiskCache(self.cache_dir, f"style-text-{encoder.name}-{stable_hash(settings, 8)}")
        key = stable_hash({"settings": settings, "texts": texts})
        vectors = cache.get_or_compute(key, compute, required=("vectors",))["vectors"]
        if vectors.shape != (len(texts), encoder.dim):
            raise DataError(f"Cached style embeddings in {cache.dir} have the wrong shape; delete that folder.")
        return torch.from_numpy(vectors).float()

    def embed_genre(self, key: str | int) -> torch.Tensor:
        """Style vector ``(dim,)`` of a genre (code or name); for prompts the genre's mean embedding."""
        g = self.vocab.index(key)
        return self.bank().mean_for(torch.tensor([g]))[0]

    def embed_text(self, text: str) -> torch.Tensor:
        """Style vector ``(dim,)`` of a free-text description (inference); loads the text encoder if needed."""
        if self.kind == "none":
            raise ConfigError("This model was trained without style conditioning (style=none); drop the style text.")
        text, on_purpose = split_free_text(text)
        if not on_purpose:
            self.vocab.check_not_near_miss(text)  # "locking" is a typo of "lock", not a description
        if self.kind == "onehot":
            if text in self.vocab and not on_purpose:
                return self.embed_genre(text)
            raise ConfigError(
                f"This model was trained with one-hot styles and only accepts genre names, not free text {text!r}. "
                f"Known genres: {self.vocab.describe()}."
            )
        text = " ".join(text.split())
        if not text:
            raise ConfigError("The style text is empty; give a description or a genre name.")
        if text not in self._text_memo:
            self._text_memo[text] = self._encode_cached([text])[0]
        return self._text_memo[text]

    def embed_texts(self, texts: list[str]) -> torch.Tensor:
        """``(N, dim)`` embeddings of several descriptions at once (one disk-cache entry); loads the encoder if needed."""
        if self.kind not in ("genre", "prompt"):
            raise ConfigError(f"style kind {self.kind!r} embeds no text.")
        return self._encode_cached([" ".join(t.split()) for t in texts])

    def embed(self, style: str) -> torch.Tensor:
        """``(dim,)`` for a user's style string: a known genre code/name, otherwise a free-text description."""
        return self.embed_genre(style) if style in self.vocab else self.embed_text(style)


def _as_vocab(vocab: Any) -> GenreVocab:
    if vocab is None:
        return AISTPP_GENRES
    if isinstance(vocab, GenreVocab):
        return vocab
    if isinstance(vocab, str) and vocab in DATASET_VOCABS:
        return GenreVocab.named(vocab)
    if isinstance(vocab, str | os.PathLike):
        return GenreVocab.from_yaml(vocab)
    return GenreVocab(plain_config(vocab))
