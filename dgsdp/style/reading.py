"""Reading free text as a genre, a speed and how the body moves: the router of ``style_text_reading=router``.

A model trained on a few descriptions per genre has learnt what those descriptions' embeddings ask for; a text
unlike them lies where it learnt nothing, and a blend of genres is danced as a third genre. :class:`TextRouter`
therefore reads a text in three parts, each fitted on the run's training descriptions alone (never on the held-out
lists the style benchmark measures with):

- **genre**: a linear classifier (logistic regression) on the text embeddings of the descriptions, of each
  sentence of those with several, and of each genre's name in a few neutral phrases ("a krump dance"), gives a
  probability per genre; the text is danced as the likeliest genre, exactly as that genre asked by name.
- **energy**: a second linear classifier, on phrases that compose each genre's name with slow and fast words
  (``resources/style_attributes.yaml``) and on the descriptions themselves as neutral, reads how much faster or
  slower than usual the text asks to be danced: -1 to +1 (the mean reading of the slow and of the fast phrases is
  -1 and +1). A model conditioned on speed dances it at that quantile of its genre's training speeds.
- **movement**: one more such classifier per movement attribute (:data:`ATTRIBUTES`: level, arms, travel, turning),
  on phrases composing each genre's name with words for the attribute's two ends ("tall", "crouched"; "arms
  raised overhead", "arms down"; ...), reads a score from -1 to +1 of each; a model conditioned on the attribute
  (``model.movement_channels``) is asked for that quantile of its genre's training windows, as for the speed.
- **known**: a text less similar to every description than each description is to its nearest other description
  resembles nothing the model knows; it is danced in no particular genre, and the reading says so. The threshold is
  calibrated on the descriptions and applied to them alone: the short phrases composed for the energy resemble any
  short text ("tango" was read as LA hip-hop through "a furious la-style hip-hop dance").
- **negation**: a negation word ("not", "no", "never", "without", "anything but", "rather than", ...) negates the
  words after it up to the next punctuation, "but" or "and". A genre those words name is excluded (its probability
  0; "not krump" alone is danced in no particular genre but krump); the energy and the movement scores are read
  from the rest of the text, and the negated words' scores, read composed with every genre's name, count against
  them ("krump, not fast" and "not fast at all" read slow, "anything but slow" fast, "house without spinning"
  facing ahead).

:class:`TextReading` is what a dance reports about how its style was read.
"""

from __future__ import annotations

import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch

from dgsdp.errors import ConfigError
from dgsdp.resources import RESOURCES_DIR
from dgsdp.style.movement import MOVEMENT_CHANNELS

ATTRIBUTES_FILE = RESOURCES_DIR / "style_attributes.yaml"
GENRE_C = 30.0  # the genre classifier's inverse regularisation: the best of 3, 10, 30 in leave-one-description-out
# (aistpp_augmented: 0.78 of its descriptions read as their genre when left out, with their sentences)
ENERGY_C = 1.0  # the energy classifier's
SPEED_SPAN = 0.4  # energy +-1 asks for the genre's training speed at quantile 0.5 +- this (its 10th / 90th percentile)
ATTRIBUTES = tuple(c for c in MOVEMENT_CHANNELS if c != "speed")
"""The movement attributes a text is read for beside its energy (which asks for the speed)."""
ATTRIBUTE_ENDS = {"level": ("lower", "higher"), "arms": ("lower", "higher"), "travel": ("less", "more"),
                  "turning": ("less", "more")}  # fmt: skip
"""How a reading describes asking for less or more of each attribute ("arms higher", "travel more")."""
MIN_SENTENCE_WORDS = 3
# a negation word, the longer phrases first, and what ends its scope (punctuation, "but", "and")
NEGATION = re.compile(
    r"\b(?:anything but|nothing like|rather than|instead of|not|no|never|without|nor|isn't|aren't|don't|doesn't|"
    r"won't|can't)(?=\W|$)",
    re.IGNORECASE,
)
_SCOPE_END = re.compile(r"[,.;:!?]|\b(?:but|and)\b", re.IGNORECASE)


@dataclass(frozen=True)
class TextReading:
    """How a style text was read: ``how`` ("genre": a genre asked by name; "router"; "blend": similarity weights;
    "own": the text's own embedding), the genres it was read as with their weights (largest first), the genre danced
    (None: no one genre), the energy (-1 slow to +1 fast; 0: the genre's usual), whether it resembles the model's
    descriptions (with the closest one and its similarity), the speed asked (m/s; speed-conditioned models), the
    genres the text negates ("not krump"), the movement attributes read (name, score -1 to +1; router readings) and
    the movement values asked of a model conditioned on them (name, value in the measure's unit,
    :mod:`dgsdp.metrics.attributes`; the speed is ``speed_m_s``)."""

    text: str
    how: str
    weights: tuple[tuple[str, float], ...] = ()
    genre: str | None = None
    energy: float = 0.0
    known: bool = True
    closest: str | None = None
    similarity: float | None = None
    speed_m_s: float | None = None
    excluded: tuple[str, ...] = ()
    attributes: tuple[tuple[str, float], ...] = ()
    movement: tuple[tuple[str, float], ...] = ()

    def describe_attributes(self) -> str:
        """The movement read, e.g. ``level lower (-0.80), arms usual, travel more (+0.60), turning usual``."""
        parts = []
        for name, score in self.attributes:
            less, more = ATTRIBUTE_ENDS.get(name, ("less", "more"))
            parts.append(
                f"{name} usual" if abs(score) < 0.05 else f"{name} {less if score < 0 else more} ({score:+.2f})"
            )
        return ", ".join(parts)

    def describe(self) -> str:
        """One line for the user."""
        speed = "" if self.speed_m_s is None else f", at {self.speed_m_s:.2f} m/s"
        if self.attributes and self.how == "router":
            speed += f"; {self.describe_attributes()}"
        negated = " or ".join(self.excluded)
        if negated and not self.known:
            return f"style {self.text!r}: no genre asked, only not {negated}: danced in no particular genre{speed}"
        if negated:
            speed += f"; not {negated} (negated)"
        if self.how == "genre":
            return f"style {self.text!r}: the genre {self.genre}{speed}"
        if self.how == "own":
            return f"style {self.text!r}: read by its own text embedding (style_text_reading=off)"
        if not self.known:
            return (
                f"style {self.text!r} resembles none of the descriptions this model knows (the closest, "
                f"{_short(self.closest)}, at similarity {self.similarity:.2f}): danced in no particular genre{speed}"
            )
        top = ", ".join(f"{name} {w:.2f}" for name, w in self.weights[:3])
        if self.how == "blend":
            return f"style {self.text!r}: read as a blend of genres ({top})"
        pace = "its genre's usual pace" if abs(self.energy) < 0.05 else ("slower" if self.energy < 0 else "faster")
        energy = f"energy {self.energy:+.2f} ({pace})"
        return f"style {self.text!r}: read as {self.genre} ({top}); {energy}{speed}"

    def to_dict(self) -> dict[str, Any]:
        return {
            "text": self.text, "how": self.how, "weights": dict(self.weights), "genre": self.genre,
            "energy": self.energy, "known": self.known, "closest": self.closest, "similarity": self.similarity,
            "speed_m_s": self.speed_m_s, "excluded": list(self.excluded), "attributes": dict(self.attributes),
            "movement": dict(self.movement),
        }  # fmt: skip


def _short(text: str | None, words: int = 8) -> str:
    parts = (text or "").split()
    return repr(" ".join(parts[:words]) + (" ..." if len(parts) > words else ""))


def sentences(text: str) -> list[str]:
    """The sentences of a description of several (each of at least MIN_SENTENCE_WORDS words), else []."""
    parts = [p.strip() for p in re.split(r"(?<=[.;!?])\s+", text) if len(p.split()) >= MIN_SENTENCE_WORDS]
    return parts if len(parts) > 1 else []


def split_negation(text: str) -> tuple[str, list[str]]:
    """``text`` without its negated phrases, and those phrases: a negation word negates the words after it up to
    the next punctuation, "but" or "and" (``"house, not too fast"`` -> ``("house,", ["too fast"])``)."""
    kept, negated, pos = [], [], 0
    for match in NEGATION.finditer(text):
        if match.start() < pos:
            continue
        kept.append(text[pos : match.start()])
        end = _SCOPE_END.search(text, match.end())
        stop = end.start() if end else len(text)
        if text[match.end() : stop].strip():
            negated.append(text[match.end() : stop].strip())
        pos = stop
    kept.append(text[pos:])
    return " ".join(" ".join(kept).split()), negated


def load_attributes(path: str | Path = ATTRIBUTES_FILE) -> dict[str, Any]:
    """The slow and fast words and the templates that compose them with genre names, and, where the file has them,
    each movement attribute's words for its lower and higher end with their templates (see the file)."""
    import yaml

    data = yaml.safe_load(Path(path).read_text(encoding="utf-8"))
    keys = ("slow", "fast", "templates", "neutral_templates")
    if not isinstance(data, dict) or any(not isinstance(data.get(k), list) or not data[k] for k in keys):
        raise ConfigError(f"{path} must list {', '.join(keys)}")
    for template in data["templates"] + list(data.get("movement_templates") or []):
        if "{word}" not in template or "{genre}" not in template:
            raise ConfigError(f"{path}: template {template!r} needs {{word}} and {{genre}}")
    out: dict[str, Any] = {k: [str(v) for v in data[k]] for k in keys}
    movement = data.get("movement") or {}
    if movement:
        if not isinstance(movement, dict) or not data.get("movement_templates"):
            raise ConfigError(f"{path}: movement must map attributes to their words, with movement_templates")
        unknown = [name for name in movement if name not in ATTRIBUTES]
        if unknown:
            raise ConfigError(f"{path}: unknown movement attribute(s) {unknown}; known: {', '.join(ATTRIBUTES)}")
        out["movement_templates"] = [str(t) for t in data["movement_templates"]]
        out["movement"] = {}
        for name, ends in movement.items():
            if not isinstance(ends, dict) or any(
                not isinstance(ends.get(k), list) or not ends[k] for k in ("lower", "higher")
            ):
                raise ConfigError(f"{path}: movement.{name} must list words for its lower and higher end")
            out["movement"][name] = {k: [str(w) for w in ends[k]] for k in ("lower", "higher")}
    return out


def _unit(x: torch.Tensor) -> np.ndarray:
    return torch.nn.functional.normalize(x.float(), dim=-1).cpu().numpy().astype(np.float64)


class TextRouter:
    """Reads free text as a genre, an energy, movement attributes and whether it is known (see the module
    docstring), fitted on a run's training descriptions ``per_genre`` (one list per genre, in the vocabulary's order)
    with its text encoder's ``embed`` (texts -> (N, dim)). ``genre_names``: the genres' names, composed with the
    attribute words (``attributes``: :func:`load_attributes`' form; default the shipped file). ``movement``: the
    movement attributes to read (default: every one the words name); a model is read for those it takes."""

    def __init__(
        self,
        per_genre: Sequence[Sequence[str]],
        embed: Callable[[list[str]], torch.Tensor],
        genre_names: Sequence[str],
        attributes: dict[str, Any] | None = None,
        movement: Sequence[str] | None = None,
    ) -> None:
        from sklearn.linear_model import LogisticRegression

        if len(per_genre) != len(genre_names) or sum(1 for texts in per_genre if texts) < 2:
            raise ConfigError("the free-text reader needs descriptions of at least two genres")
        attributes = attributes or load_attributes()
        if movement is not None:  # only the attributes a model takes: each costs its phrases' embeddings to fit
            unknown = sorted(set(movement) - set(ATTRIBUTES))
            if unknown:
                raise ConfigError(f"unknown movement attribute(s) {unknown}; known: {', '.join(ATTRIBUTES)}")
            kept = {k: v for k, v in (attributes.get("movement") or {}).items() if k in movement}
            attributes = {**attributes, "movement": kept}
        self.embed = embed
        self.n_genres = len(per_genre)
        self.genre_names = [str(n).lower() for n in genre_names]
        # the examples: each description, then its sentences (a description and its sentences share a group)
        texts, labels, groups = [], [], []
        for genre, descriptions in enumerate(per_genre):
            for d in descriptions:
                for t in [d, *sentences(d)]:
                    texts.append(t)
                    labels.append(genre)
                    groups.append(len(set(groups)) if t == d else groups[-1])
        self.texts, self.labels, self.groups = texts, np.asarray(labels), np.asarray(groups)
        self.examples = _unit(embed(texts))
        # the genre: the examples, and each genre's name in the neutral templates ("a krump dance")
        named = [(t.format(genre=name), g) for g, name in enumerate(genre_names) if per_genre[g]
                 for t in attributes["neutral_templates"]]  # fmt: skip
        x_named = _unit(embed([t for t, _ in named]))
        self.genre_model = LogisticRegression(C=GENRE_C, max_iter=5000).fit(
            np.concatenate([self.examples, x_named]), np.concatenate([self.labels, [g for _, g in named]])
        )
        # known: as similar to some description as each description is to its nearest other one
        heads = np.flatnonzero(np.r_[True, self.groups[1:] != self.groups[:-1]])
        sims = self.examples[heads] @ self.examples.T
        sims[self.groups[heads][:, None] == self.groups[None, :]] = -np.inf
        self.known_similarity = float(sims.max(axis=1).min())
        # energy: slow / neutral / fast phrases composed with the genres' names, the descriptions neutral
        self.energy = _Scale(self, genre_names, attributes["slow"], attributes["fast"], attributes["templates"],
                             attributes["neutral_templates"], "slow from fast")  # fmt: skip
        # each movement attribute: its lower / neutral / higher phrases, the same way
        self.attributes = {
            name: _Scale(self, genre_names, ends["lower"], ends["higher"], attributes["movement_templates"],
                         attributes["neutral_templates"], f"a lower from a higher {name}")
            for name, ends in (attributes.get("movement") or {}).items()
        }  # fmt: skip

    def negated_genres(self, text: str) -> list[int]:
        """The genres a negated phrase of ``text`` names ("not krump", "anything but house")."""
        spans = split_negation(text)[1]
        return [
            g for g, name in enumerate(self.genre_names)
            if any(re.search(rf"(?<!\w){re.escape(name)}(?!\w)", span, re.IGNORECASE) for span in spans)
        ]  # fmt: skip

    def read(self, text: str) -> tuple[np.ndarray, float, bool, str, float]:
        """(genre probabilities (G,) over all the vocabulary's genres, energy in [-1, 1], known, the closest
        description, its similarity) of one text; a negated genre has probability 0 (module docstring)."""
        x = _unit(self.embed([text]))
        sims = (self.examples @ x[0]).astype(np.float64)
        best = int(sims.argmax())
        known = bool(sims[best] >= self.known_similarity)
        probs = np.zeros(self.n_genres)
        probs[self.genre_model.classes_] = self.genre_model.predict_proba(x)[0]
        energy = self.energy.read(text, x)
        kept, negated = split_negation(text)
        if negated:  # the genre from the whole text but the genres negated
            if not re.search(r"\w", kept):  # nothing but negations: no genre asked
                known = False
            excluded = self.negated_genres(text)
            probs[excluded] = 0.0
            if probs.sum() > 0:
                probs /= probs.sum()
            else:
                known = False
        return probs, energy, known, self.texts[best], float(sims[best])

    def read_attributes(self, text: str) -> dict[str, float]:
        """Each movement attribute's score in [-1, 1] of one text (0: its genre's usual), negations read as the
        energy's are; empty when the reader was given no movement words."""
        if not self.attributes:
            return {}
        x = _unit(self.embed([text]))
        return {name: scale.read(text, x) for name, scale in self.attributes.items()}


class _Scale:
    """A score from -1 (``lower`` words) to +1 (``higher`` words) of a text: a linear classifier on phrases that
    compose each genre's name with the words of either end, and on the genre names and the router's examples as
    neutral (0); scaled so that the mean reading of each end's phrases is -1 and +1. ``what`` names what it tells
    apart, for the error when the words cannot."""

    def __init__(
        self,
        router: TextRouter,
        genre_names: Sequence[str],
        lower: Sequence[str],
        higher: Sequence[str],
        templates: Sequence[str],
        neutral_templates: Sequence[str],
        what: str,
    ) -> None:
        from sklearn.linear_model import LogisticRegression

        self.router = router
        phrases, classes = [], []
        for name in genre_names:
            for cls, words in ((0, lower), (2, higher)):
                for word in words:
                    for template in templates:
                        phrases.append(template.format(word=word, genre=name))
                        classes.append(cls)
            for template in neutral_templates:
                phrases.append(template.format(genre=name))
                classes.append(1)
        composed = _unit(router.embed(phrases))
        x = np.concatenate([composed, router.examples])
        y = np.concatenate([np.asarray(classes), np.ones(len(router.examples), dtype=np.int64)])
        self.model = LogisticRegression(C=ENERGY_C, max_iter=5000, class_weight="balanced").fit(x, y)
        raw = self.raw(composed)
        classes_arr = np.asarray(classes)
        self.scale = (float(-raw[classes_arr == 0].mean()), float(raw[classes_arr == 2].mean()))
        if not min(self.scale) > 0:
            raise ConfigError(f"the attribute words do not separate {what} for this text encoder")

    def raw(self, x: np.ndarray) -> np.ndarray:
        p = self.model.predict_proba(x)
        order = list(self.model.classes_)
        return p[:, order.index(2)] - p[:, order.index(0)]

    def value(self, raw: float) -> float:
        return float(np.clip(raw / self.scale[0 if raw < 0 else 1], -1.0, 1.0))

    def read(self, text: str, x: np.ndarray) -> float:
        """The score of ``text`` (its unit embedding ``x``, (1, dim)): of the words not negated, less the score of
        each negated phrase composed with every genre's name (as the classifier was fitted)."""
        score = self.value(float(self.raw(x)[0]))
        kept, negated = split_negation(text)
        if not negated:
            return score
        router = self.router
        score = self.value(float(self.raw(_unit(router.embed([kept])))[0])) if re.search(r"\w", kept) else 0.0
        for span in negated:
            composed = _unit(router.embed([f"{span} {name}" for name in router.genre_names]))
            score -= self.value(float(self.raw(composed).mean()))
        return float(np.clip(score, -1.0, 1.0))


def speed_quantile(energy: float | torch.Tensor) -> float | torch.Tensor:
    """The quantile of a genre's training speeds an energy (-1 to +1, clamped; not finite: 0) asks for; of a
    movement attribute's training values, its score. A float for a float, a tensor for a tensor of scores."""
    scores = torch.as_tensor(energy, dtype=energy.dtype if isinstance(energy, torch.Tensor) else torch.float64)
    quantile = 0.5 + SPEED_SPAN * scores.nan_to_num(0.0, posinf=0.0, neginf=0.0).clamp(-1.0, 1.0)
    return quantile if isinstance(energy, torch.Tensor) else float(quantile)


__all__ = [
    "ATTRIBUTES", "ATTRIBUTES_FILE", "TextReading", "TextRouter", "load_attributes", "sentences", "speed_quantile", "split_negation"
]  # fmt: skip
