"""The FineDance files shipped with the package: official splits, genres, description prompts."""

import re

import yaml

from dgsdp.data.aistpp import read_list
from dgsdp.resources import FINEDANCE_DIR, FINEDANCE_HELDOUT_FILE, FINEDANCE_PROMPTS_FILE, STYLE_PROMPTS_FILE
from dgsdp.style.embeddings import load_prompts
from dgsdp.style.vocab import GenreVocab

ALL_IDS = {f"{i:03d}" for i in range(1, 212)}


def ids(name: str) -> list[str]:
    return read_list(FINEDANCE_DIR / name)


def test_cross_genre_split_is_the_official_one():
    test, train, ignore = ids("crossgenre_test.txt"), ids("crossgenre_train.txt"), ids("crossgenre_ignore.txt")
    # the 20 test ids of FineDance's dataset code, in its order
    assert test == "063 132 143 036 098 198 130 012 211 193 179 065 137 161 092 120 037 109 204 144".split()
    assert set(ignore) == {"116", "117", "118", "119", "120", "121", "122", "123", "202", "130"}
    assert not set(train) & set(test) and not set(train) & set(ignore)
    assert set(train) | set(test) | set(ignore) == ALL_IDS
    assert len(train) == 183 and len(set(test) - set(ignore)) == 18


def test_cross_dancer_split_is_the_official_one():
    test, val, train = ids("crossdancer_test.txt"), ids("crossdancer_val.txt"), ids("crossdancer_train.txt")
    ignore = ids("crossdancer_ignore.txt")
    assert test == [f"{i:03d}" for i in range(1, 14)] + ["124", "126", "128", "130", "132"]
    assert val == "115 117 119 121 122 135 137 139 141 143 145 147".split()
    assert set(ignore) == {"116", "118", "120", "123", "202", "159", "130"}
    assert set(train) == ALL_IDS - set(test) - set(val) - set(ignore)


def test_genres_are_the_label_files_names():
    vocab = GenreVocab.from_yaml(FINEDANCE_DIR / "genres.yaml")
    # the "style2" values of the released label files, in LODGE's class order
    assert vocab.names == [
        "Breaking", "Popping", "Locking", "Hiphop", "Urban", "Jazz", "Dai", "Wei", "Miao", "HanTang", "ShenYun",
        "Kun", "DunHuang", "Korean", "Choreography", "Chinese",
    ]  # fmt: skip
    assert vocab.index("jazz") == vocab.index("Jazz") == 5
    aliases = yaml.safe_load((FINEDANCE_DIR / "genre_aliases.yaml").read_text())
    assert all(target in vocab.names and alias not in vocab for alias, target in aliases.items())


def test_prompts_cover_every_genre_and_held_out_texts_are_apart():
    vocab = GenreVocab.from_yaml(FINEDANCE_DIR / "genres.yaml")
    training = load_prompts(FINEDANCE_PROMPTS_FILE, vocab)
    heldout = load_prompts(FINEDANCE_HELDOUT_FILE, vocab)
    assert FINEDANCE_PROMPTS_FILE.parent == STYLE_PROMPTS_FILE.parent != FINEDANCE_HELDOUT_FILE.parent
    assert all(len(texts) == 4 for texts in training) and all(len(texts) == 4 for texts in heldout)
    training_text = " ".join(t.lower() for texts in training for t in texts)
    assert not any(t.lower() in training_text for texts in heldout for t in texts)
    # the first two held-out texts of each genre name it, the last two describe movement only
    stems = {
        "BR": ("break", "b-boy"), "PO": ("popp",), "LO": ("lock",), "HH": ("hip hop", "hiphop"), "UR": ("urban",),
        "JZ": ("jazz",), "DA": ("dai", "tai"), "WE": ("uyghur", "uighur", "xinjiang"), "MI": ("miao", "hmong"),
        "HT": ("han and tang", "court dance"), "SY": ("shen yun", "shenyun"), "KU": ("kun",),
        "DH": ("dunhuang",), "KO": ("korean",), "CH": ("choreograph",), "CN": ("chinese",),
    }  # fmt: skip
    raw = yaml.safe_load(FINEDANCE_HELDOUT_FILE.read_text())
    assert list(raw) == vocab.codes
    for code, texts in raw.items():
        pattern = re.compile(r"\b(" + "|".join(re.escape(s) for s in stems[code]) + r")", re.IGNORECASE)
        assert all(pattern.search(t) for t in texts[:2]), code
        assert not any(pattern.search(t) for t in texts[2:]), code
