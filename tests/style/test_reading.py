"""The free-text router (style_text_reading=router): a genre, an energy and whether the text is known, each fitted on
training descriptions; checked with a bag-of-words embedding whose answers can be worked out by hand, then with the
shipped MiniLM on the shipped descriptions."""

from __future__ import annotations

import re

import numpy as np
import pytest
import torch

from dgsdp.errors import ConfigError
from dgsdp.style.reading import (
    SPEED_SPAN,
    TextReading,
    TextRouter,
    load_attributes,
    sentences,
    speed_quantile,
    split_negation,
)

GENRES = ["break", "house", "ballet"]
DESCRIPTIONS = [
    ["spins on the floor with the legs whirling", "hands on the floor, legs whirling round. Then a frozen spin."],
    ["feet shuffling and sliding on the floor", "quick shuffling feet that slide and jack"],
    ["pointed toes and long graceful extensions", "graceful turns on pointed toes"],
]
ATTRIBUTES = {"slow": ["calm", "lazy"], "fast": ["frantic", "rapid"], "templates": ["{word} {genre}"],
              "neutral_templates": ["{genre}"]}  # fmt: skip
MOVEMENT = {"movement_templates": ["{word} {genre}"],
            "movement": {"level": {"lower": ["crouched", "squat"], "higher": ["tall", "upright"]},
                         "turning": {"lower": ["ahead", "front"], "higher": ["spinning", "twirling"]}}}  # fmt: skip


def words(text: str) -> list[str]:
    return re.findall(r"[a-z]+", text.lower())


VOCAB = sorted({w for ds in DESCRIPTIONS for d in ds for w in words(d)} | set(GENRES) | {"calm", "lazy", "frantic",
               "rapid", "sitting", "chair", "crouched", "squat", "tall", "upright", "ahead", "front", "spinning",
               "twirling"})  # fmt: skip


def bag_of_words(texts: list[str]) -> torch.Tensor:
    """(N, V) word counts: texts that share no word have similarity 0."""
    out = torch.zeros(len(texts), len(VOCAB))
    for i, text in enumerate(texts):
        for w in words(text):
            if w in VOCAB:
                out[i, VOCAB.index(w)] += 1
    return out + 1e-6  # no all-zero row


@pytest.fixture(scope="module")
def router() -> TextRouter:
    return TextRouter(DESCRIPTIONS, bag_of_words, GENRES, ATTRIBUTES)


@pytest.fixture(scope="module")
def mover() -> TextRouter:
    return TextRouter(DESCRIPTIONS, bag_of_words, GENRES, {**ATTRIBUTES, **MOVEMENT})


def test_sentences_of_a_description_of_several():
    assert sentences("One two three. Four five six; seven eight nine!") == ["One two three.", "Four five six;",
                                                                            "seven eight nine!"]  # fmt: skip
    assert sentences("Only one sentence here.") == [] and sentences("Too. Short. Here are enough words.") == []


def test_the_router_reads_a_genre_an_energy_and_whether_it_knows_the_text(router):
    assert router.texts[:3] == [DESCRIPTIONS[0][0], DESCRIPTIONS[0][1], "hands on the floor, legs whirling round."]
    assert router.groups[:4].tolist() == [0, 1, 1, 1]  # a description and its sentences share a group
    probs, energy, known, closest, similarity = router.read("whirling spins")
    assert probs.argmax() == 0 and probs.sum() == pytest.approx(1.0) and known
    assert closest == DESCRIPTIONS[0][0] and similarity == pytest.approx(
        float(torch.nn.functional.cosine_similarity(bag_of_words(["whirling spins"]), bag_of_words([closest]))[0])
    )
    assert router.read("graceful pointed toes")[0].argmax() == 2
    # the known threshold: the least similar description to its nearest other one (here: shared words)
    x = torch.nn.functional.normalize(bag_of_words(router.texts), dim=-1)
    sims = (x @ x.T).numpy()
    heads = [0, 1, 4, 5, 6, 7]  # the descriptions (1 is followed by its two sentences)
    nearest = [max(sims[h, j] for j in range(len(x)) if router.groups[j] != router.groups[h]) for h in heads]
    assert router.known_similarity == pytest.approx(min(nearest), abs=1e-6)
    assert not router.read("sitting chair")[2]  # no word in common with anything it knows
    # energy: the calibration words read slow and fast around a genre; the genre's name alone near its usual pace
    assert router.read("frantic house")[1] > 0.5 and router.read("lazy house")[1] < -0.5
    assert abs(router.read("house")[1]) < 0.5


def test_known_is_judged_against_the_descriptions_it_was_calibrated_on(router):
    """A text that shares words only with the phrases composed for the energy ("calm" of "calm break") resembles no
    description: unknown (before, the threshold set on the descriptions was applied to those phrases too)."""
    composed = torch.nn.functional.normalize(bag_of_words(["calm break"]), dim=-1)
    text = torch.nn.functional.normalize(bag_of_words(["calm"]), dim=-1)
    assert float(composed @ text.T) > router.known_similarity  # close to a composed phrase...
    probs, energy, known, closest, similarity = router.read("calm")
    assert not known and closest in router.texts and similarity < router.known_similarity  # ...but no description
    assert router.read("calm house")[2] is False and router.read("shuffling feet that slide")[2]


@pytest.mark.parametrize(
    "text, kept, negated",
    [("house, not too fast", "house,", ["too fast"]), ("not krump", "", ["krump"]),
     ("anything but krump", "", ["krump"]), ("krump, not fast but smooth", "krump, but smooth", ["fast"]),
     ("no krump, no house", ",", ["krump", "house"]), ("don't stop", "", ["stop"]),
     ("a knot of notes", "a knot of notes", []), ("Nothing like krump and slow", "and slow", ["krump"])],
)  # fmt: skip
def test_split_negation(text, kept, negated):
    assert split_negation(text) == (kept, negated)


def test_negation_excludes_a_genre_and_turns_the_energy(router):
    """ "not break" names break only to exclude it; a negated speed word counts against the text's energy."""
    probs, energy, known, _, _ = router.read("not break")
    assert probs[0] == 0.0 and probs.sum() == pytest.approx(1.0) and not known and energy == pytest.approx(0.0, abs=0.6)
    assert router.negated_genres("anything but break, no house") == [0, 1] and router.negated_genres("break") == []
    probs = router.read("graceful pointed toes, not house")[0]
    assert probs[1] == 0.0 and probs.argmax() == 2
    plain, negated = router.read("frantic house")[1], router.read("house, not frantic")[1]
    assert plain > 0.5 and negated < -0.5
    assert router.read("not lazy")[1] > 0.5 and not router.read("not lazy")[2]
    described = TextReading("not krump", "router", (("House", 0.5),), None, -0.2, False, "x", 0.3, excluded=("krump",))
    assert described.describe() == "style 'not krump': no genre asked, only not krump: danced in no particular genre"
    known = TextReading("house, not krump", "router", (("House", 0.9),), "House", 0.0, True, "x", 0.6, 0.5, ("krump",))
    assert known.describe().endswith("energy +0.00 (its genre's usual pace), at 0.50 m/s; not krump (negated)")
    assert described.to_dict()["excluded"] == ["krump"]


def test_the_router_reads_movement_attributes_beside_the_energy(router, mover):
    """Each attribute's words read at their end around a genre (the calibration: the mean of each end's phrases is
    -1 and +1), the genre's name alone near its usual; a router given no movement words reads none."""
    assert router.read_attributes("tall house") == {}
    assert set(mover.read_attributes("house")) == {"level", "turning"}
    assert (
        mover.read_attributes("crouched house")["level"] < -0.5 and mover.read_attributes("tall house")["level"] > 0.5
    )
    assert (
        mover.read_attributes("twirling ballet")["turning"] > 0.5 and abs(mover.read_attributes("house")["level"]) < 0.5
    )
    assert abs(mover.read_attributes("tall house")["turning"]) < 0.5  # one attribute's words leave the others alone
    # the energy is read as it was without movement words
    for text in ("frantic house", "lazy break", "house, not frantic"):
        assert mover.read(text)[1] == pytest.approx(router.read(text)[1])


def test_a_router_reads_only_the_attributes_it_is_given():
    """A model is read for the movement channels it takes (the pipeline passes them): the others are neither fitted
    nor reported; an attribute the reader does not know is one clear error."""
    level_only = TextRouter(DESCRIPTIONS, bag_of_words, GENRES, {**ATTRIBUTES, **MOVEMENT}, movement=["level"])
    assert set(level_only.read_attributes("crouched house")) == {"level"}
    assert level_only.read_attributes("crouched house")["level"] < -0.5
    assert (
        TextRouter(DESCRIPTIONS, bag_of_words, GENRES, {**ATTRIBUTES, **MOVEMENT}, movement=[]).read_attributes(
            "crouched house"
        )
        == {}
    )
    with pytest.raises(ConfigError, match="unknown movement attribute"):
        TextRouter(DESCRIPTIONS, bag_of_words, GENRES, ATTRIBUTES, movement=["height"])


def test_negated_movement_words_count_against_their_attribute(mover):
    """ "not tall" and "without spinning" read the other way: the negated words, composed with every genre's name,
    count against the rest of the text's score (as the energy's do)."""
    assert mover.read_attributes("house, not tall")["level"] < -0.5
    assert mover.read_attributes("ballet without spinning")["turning"] < -0.5
    assert mover.read_attributes("anything but crouched")["level"] > 0.5
    assert mover.read_attributes("not krump")["level"] == pytest.approx(0.0, abs=0.3)  # no level word in it


def test_a_reading_describes_the_movement_it_read():
    reading = TextReading("tall house", "router", (("House", 0.9),), "House", 0.0, True, "x", 0.7, 0.5,
                          attributes=(("level", 0.8), ("arms", 0.01), ("travel", -0.6), ("turning", 0.0)),
                          movement=(("level", 1.02),))  # fmt: skip
    assert reading.describe() == (
        "style 'tall house': read as House (House 0.90); energy +0.00 (its genre's usual pace), at 0.50 m/s; "
        "level higher (+0.80), arms usual, travel less (-0.60), turning usual"
    )
    assert reading.to_dict()["attributes"]["travel"] == -0.6 and reading.to_dict()["movement"] == {"level": 1.02}


def test_energy_asks_for_a_quantile_of_the_genre_speeds():
    assert speed_quantile(0.0) == 0.5 and speed_quantile(1.0) == pytest.approx(0.5 + SPEED_SPAN)
    assert speed_quantile(-3.0) == pytest.approx(0.5 - SPEED_SPAN) and speed_quantile(float("nan")) == 0.5


def test_a_reading_describes_itself_in_one_line():
    known = TextReading("fast krump", "router", (("Krump", 0.9), ("House", 0.1)), "Krump", 1.0, True, "x", 0.7, 0.55)
    assert known.describe() == (
        "style 'fast krump': read as Krump (Krump 0.90, House 0.10); energy +1.00 (faster), at 0.55 m/s"
    )
    unknown = TextReading("a chair", "router", (("Waack", 0.4),), None, 0.0, False, "a long text of many words here "
                          "to be cut short now", 0.31)  # fmt: skip
    assert unknown.describe() == (
        "style 'a chair' resembles none of the descriptions this model knows (the closest, 'a long text of many "
        "words here to ...', at similarity 0.31): danced in no particular genre"
    )
    assert TextReading("krump", "genre", genre="Krump").describe() == "style 'krump': the genre Krump"
    assert "own text embedding" in TextReading("x", "own").describe()


def test_the_shipped_attribute_words_leave_out_the_benchmarks_words():
    from dgsdp.benchmarks.style import MODIFIER_PAIRS

    attributes = load_attributes()
    checked = {w for pair in MODIFIER_PAIRS for phrase in pair for w in phrase.replace("{genre}", "").split()}
    assert checked == {"slow", "fast", "gentle", "explosive"}
    assert not checked & set(attributes["slow"] + attributes["fast"])
    assert not {t.format(word="{w}", genre="{genre}") for t in attributes["templates"]} & {
        p for pair in MODIFIER_PAIRS for p in pair
    }


def test_the_shipped_movement_words_leave_out_the_benchmarks_wordings():
    """No movement word of the reader occurs in the style benchmark's held-out attribute wordings (which measure how
    the reading carries over to words it never saw), and none carries a negation (it would be read negated)."""
    import yaml

    from dgsdp.resources import RESOURCES_DIR

    attributes = load_attributes()
    assert set(attributes["movement"]) == {"level", "arms", "travel", "turning"}
    heldout_file = RESOURCES_DIR / "style_heldout" / "attributes" / "aistpp.yaml"
    heldout = yaml.safe_load(heldout_file.read_text(encoding="utf-8"))
    wordings = [t.lower() for pairs in heldout.values() for pair in pairs for t in pair]
    for name, ends in attributes["movement"].items():
        for word in ends["lower"] + ends["higher"]:
            pattern = rf"(?<!\w){re.escape(word.lower())}(?!\w)"
            assert not [t for t in wordings if re.search(pattern, t)], (name, word)
            assert split_negation(word) == (word, []), (name, word)


@pytest.mark.timeout(300)
@pytest.mark.parametrize(
    "descriptions", [pytest.param("aistpp_augmented", marks=pytest.mark.slow), "aistpp_reader"]
)  # the quick start reads through aistpp_reader; the style recipes before row 20 through aistpp_augmented
def test_minilm_reads_the_shipped_descriptions_way(descriptions):
    """The shipped reader (MiniLM, the augmented descriptions and the reader's, which add 24 a genre): genre names go
    to their genre, a slower word reads slower than a faster one for every genre, and a text about no dance is
    unknown."""
    from dgsdp.resources import RESOURCES_DIR
    from dgsdp.style import MiniLMTextEncoder
    from dgsdp.style.embeddings import load_prompts
    from dgsdp.style.vocab import AISTPP_GENRES

    per_genre = load_prompts(RESOURCES_DIR / "style_prompts" / f"{descriptions}.yaml", AISTPP_GENRES)
    names = [n.lower() for n in AISTPP_GENRES.names]
    shipped = load_attributes()
    genre_and_energy = {k: shipped[k] for k in ("slow", "fast", "templates", "neutral_templates")}
    reader = TextRouter(per_genre, MiniLMTextEncoder().encode, names, genre_and_energy)  # movement: the slow test
    for g, name in enumerate(names):
        probs, energy, known, _, _ = reader.read(f"{name} dance")
        assert probs.argmax() == g and known, name
        assert reader.read(f"slow {name}")[1] < reader.read(f"fast {name}")[1], name
    assert not reader.read("sitting still on a chair")[2]
    assert np.isclose(reader.read("krump")[0].sum(), 1.0)
    # a dance it was never told of is unknown (its closest texts were composed phrases: "tango" read as LA hip-hop)
    assert not reader.read("tango")[2] and not reader.read("salsa")[2]
    # negations read the right way round
    krump = names.index("krump")
    for text in ("not krump", "anything but krump"):
        probs, _, known, _, _ = reader.read(text)
        assert probs[krump] == 0.0 and not known, text
    probs, energy, known, _, _ = reader.read("not fast at all")
    assert energy < -0.5 and not known
    house = names.index("house")
    probs, energy, known, _, _ = reader.read("house, not fast")
    assert probs.argmax() == house and known and energy < reader.read("house")[1] - 0.5


@pytest.mark.slow
@pytest.mark.timeout(600)
def test_minilm_reads_the_shipped_movement_words_way():
    """The shipped reader with its movement words (MiniLM, the augmented descriptions): for every genre, a phrase
    with a word of each attribute's higher end reads higher than one with a word of its lower end (in a wording the
    reader was not fitted on), the genre's name alone reads near its usual, and a negated word reads the other way."""
    from dgsdp.resources import RESOURCES_DIR
    from dgsdp.style import MiniLMTextEncoder
    from dgsdp.style.embeddings import load_prompts
    from dgsdp.style.vocab import AISTPP_GENRES

    per_genre = load_prompts(RESOURCES_DIR / "style_prompts" / "aistpp_augmented.yaml", AISTPP_GENRES)
    names = [n.lower() for n in AISTPP_GENRES.names]
    reader = TextRouter(per_genre, MiniLMTextEncoder().encode, names)
    words = load_attributes()["movement"]
    for name in names:
        plain = reader.read_attributes(f"{name} dance")
        for attribute, ends in words.items():
            lower = reader.read_attributes(f"I want {name} {ends['lower'][0]}")[attribute]
            higher = reader.read_attributes(f"I want {name} {ends['higher'][0]}")[attribute]
            assert lower < plain[attribute] < higher, (name, attribute, lower, plain[attribute], higher)
    assert reader.read_attributes("house without spinning")["turning"] < reader.read_attributes("house")["turning"]
