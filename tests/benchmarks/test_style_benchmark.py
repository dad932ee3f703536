"""The style benchmark (python -m dgsdp.benchmarks.style): its measures on hand-made figures, the held-out
descriptions kept apart from training, and the command end to end on a tiny prompt-conditioned checkpoint."""

import json
import math

import numpy as np
import pytest
import torch
import yaml

from dgsdp.benchmarks import style as sb
from dgsdp.resources import STYLE_PROMPTS_FILE
from dgsdp.style.embeddings import load_prompts
from dgsdp.style.vocab import AISTPP_GENRES


def test_confusion_matrix_and_accuracy_by_hand():
    true, predicted = [0, 0, 1, 2, 2, 2], [0, 1, 1, 2, 0, 2]
    matrix = sb.confusion_matrix(true, predicted, 3)
    assert matrix.tolist() == [[1, 1, 0], [0, 1, 0], [1, 0, 2]]
    assert sb.accuracy(true, predicted) == pytest.approx(4 / 6)
    assert np.trace(matrix) / matrix.sum() == pytest.approx(sb.accuracy(true, predicted))
    assert math.isnan(sb.accuracy([], []))


def test_speed_ratios_per_genre_and_the_30_percent_band():
    speeds, genres = [1.0, 3.0, 0.5, 0.7], [0, 0, 1, 1]
    ratios = sb.speed_ratios(speeds, genres, {0: 2.0, 1: 0.4, 2: 1.0})
    assert ratios == pytest.approx({0: 1.0, 1: 1.5})  # genre 2 has no dances: no ratio
    assert sb.within(1.3) and sb.within(0.7) and not sb.within(1.31) and not sb.within(0.69)


@pytest.mark.parametrize(
    "labels, frames",
    [
        ([0, 0, 0, 1, 1, 1], 0),  # a clean switch from one window to the next
        ([0, 0, 2, 1, 1, 1], 5),  # one window of neither genre between them: one grid step
        ([0, 0, 1, 0, 2, 1, 1], 5),  # settled from the sixth window on, the last 0 is the fourth: one between
        ([1, 1, 1, 1], None),  # never showed the first genre
        ([0, 0, 1, 1, 0], None),  # never settled in the second
    ],
)
def test_switch_frames_by_hand(labels, frames):
    assert sb.switch_frames(labels, 0, 1, grid_frames=5) == frames


HELDOUT_LISTS = sorted(sb.HELDOUT_DIR.glob("aistpp*.yaml"))


def test_the_shipped_heldout_lists():
    assert [f.stem for f in HELDOUT_LISTS] == ["aistpp", "aistpp_second", "aistpp_third"]
    lists = [set(t.lower() for texts in load_prompts(f, AISTPP_GENRES) for t in texts) for f in HELDOUT_LISTS]
    for i, a in enumerate(lists):
        for b in lists[i + 1 :]:
            assert not a & b  # no list repeats a description of another


def test_resolve_heldout_by_name_path_or_default(tmp_path):
    assert sb.resolve_heldout(None) == sb.HELDOUT_FILE
    assert sb.resolve_heldout("aistpp_second") == sb.HELDOUT_DIR / "aistpp_second.yaml"
    own = tmp_path / "mine.yaml"
    own.write_text("BR: [a spinning floor dance]\n")
    assert sb.resolve_heldout(str(own)) == own
    with pytest.raises(sb.ConfigError, match=r"--heldout nope: no such file.*aistpp, aistpp_second"):
        sb.resolve_heldout("nope")


@pytest.mark.parametrize("heldout_file", HELDOUT_LISTS, ids=lambda f: f.stem)
def test_heldout_descriptions_are_apart_from_training(heldout_file):
    heldout = load_prompts(heldout_file, AISTPP_GENRES)
    # every shipped AIST++ training file: the prompts, their augmented set (quickstart_row11) and the free-text
    # reader's descriptions (quickstart_row20 on)
    files = sorted(STYLE_PROMPTS_FILE.parent.glob("aistpp*.yaml"))
    assert [f.stem for f in files] == ["aistpp", "aistpp_augmented", "aistpp_reader"]
    training = [texts for f in files for texts in load_prompts(f, AISTPP_GENRES)]
    assert sb.HELDOUT_FILE.parent != STYLE_PROMPTS_FILE.parent  # nothing that trains reads this folder
    assert all(len(texts) >= 4 for texts in heldout)
    training_text = " ".join(t.lower() for texts in training for t in texts)
    for texts in heldout:
        for text in texts:
            assert text.lower() not in training_text
    # the first two of each genre name it (the report's "naming the genre" split), the others do not
    names = {code: name.lower() for code, name in zip(AISTPP_GENRES.codes, AISTPP_GENRES.names)}
    raw = yaml.safe_load(heldout_file.read_text())
    stems = {"BR": ("break", "b-boy"), "PO": ("pop",), "LO": ("lock",), "MH": ("hip hop", "hip-hop"),
             "LH": ("hip hop", "hip-hop"), "HO": ("house",), "WA": ("waack",), "KR": ("krump",), "JS": ("jazz",),
             "JB": ("jazz", "ballet")}  # fmt: skip

    def names_it(code: str, text: str) -> bool:
        return any(stem in text.lower() for stem in stems[code])

    named = sb.NAMED_FIRST.get(heldout_file.stem, 2)  # the third list names no genre
    for code, texts in raw.items():
        assert names[code]  # a genre of the vocabulary
        assert all(names_it(code, t) for t in texts[:named]), code
        assert not any(names_it(code, t) for t in texts[named:]), code
    if heldout_file.stem == "aistpp_third":  # its layout: long, three words, a feeling, middle length
        for texts in raw.values():
            assert len(texts) == 4 and len(texts[0].split()) >= 30 and len(texts[1].replace(",", "").split()) == 3


def test_last_line_means_over_checkpoints():
    results = [
        {"genres": list("ab"), "gt_acc": 0.9, "raw": {"genre_acc": 0.5, "text_acc": 0.2, "genre_speed_within": 1,
                                                      "speed_spearman": 0.5, "modifiers_right": 0.8}},
        {"genres": list("ab"), "gt_acc": 0.9, "raw": {"genre_acc": 0.7, "text_acc": 0.4, "genre_speed_within": 2,
                                                      "speed_spearman": 0.7, "modifiers_right": 1.0}},
    ]  # fmt: skip
    assert sb.last_line(results) == (
        "style_acc=0.600 text_acc=0.300 genre_speed_within_30pct=1/2 speed_spearman=0.600 modifiers=0.900 gt_acc=0.900"
    )


def test_speed_rank_and_modifier_pairs_by_hand():
    # genres 0, 1, 2 trained at 0.2, 0.5, 0.4 m/s; their dances average 0.3, 0.9, 0.6: the same order, rho = 1
    speeds, genres = [0.2, 0.4, 1.0, 0.8, 0.6], [0, 0, 1, 1, 2]
    assert sb.speed_rank_correlation(speeds, genres, {0: 0.2, 1: 0.5, 2: 0.4}) == pytest.approx(1.0)
    # genre 2's dances now the fastest: ranks (1, 3, 2) against (1, 2, 3): 1 - 6 * 2 / (3 * 8) = 0.5
    assert sb.speed_rank_correlation([0.3, 0.9, 1.2], [0, 1, 2], {0: 0.2, 1: 0.5, 2: 0.4}) == pytest.approx(0.5)
    assert math.isnan(sb.speed_rank_correlation([0.3, 0.9], [0, 1], {0: 0.2, 1: 0.5}))  # two genres: no rank
    assert sb.ordered_right([0.3, 0.5, 0.4, 0.2], [0.4, 0.5, 0.6, 0.1]) == 0.5  # a tie is not ordered right
    assert [p[0].format(genre="house") for p in sb.MODIFIER_PAIRS] == [
        "slow house",
        "gentle house",
        "slow gentle house",
    ]


def test_attribute_pairs_by_hand():
    """A pair is ordered right when the dance asked for more measures more (a tie is not); the genre accuracy is over
    both dances of every pair."""
    figures = sb.attribute_figures([0.9, 0.8, 0.7], [1.0, 0.8, 0.5], asked=[0, 0, 1, 1, 2, 2], seen=[0, 1, 1, 1, 2, 0])
    assert figures == pytest.approx({"right": 1 / 3, "genre_acc": 4 / 6})
    results = [{"genres": list("ab"), "gt_acc": 0.9, "raw": {
        "genre_acc": 0.5, "text_acc": 0.2, "genre_speed_within": 1, "speed_spearman": 0.5, "modifiers_right": 0.8,
        "attributes_right": {"level": 0.6, "turning": 0.25}, "attribute_genre_acc": 0.4}}]  # fmt: skip
    assert sb.last_line(results).endswith("gt_acc=0.900 level=0.600 turning=0.250 attribute_genre_acc=0.400")
    lines = sb.report_lines({**results[0], "checkpoint": "c", "n_clips": 2, "data_root": "d", "finished": None,
                             "sampling": {"method": "ddim", "steps": 2, "guidance": {"music": 1.0, "style": 1.0}},
                             "heldout_descriptions": "aistpp.yaml", "attribute_wordings": "aistpp.yaml",
                             "raw": {**results[0]["raw"], "speed_ratio": {}, "confusion": [[1, 0], [0, 1]]}})  # fmt: skip
    assert any(line.startswith("attribute pairs right, level") and "0.60" in line for line in lines)
    assert any(line.startswith("genre acc., attribute words") and "0.40" in line for line in lines)


def test_the_shipped_attribute_wordings(tmp_path):
    path = sb.resolve_attribute_wordings("aistpp")
    assert path == sb.ATTRIBUTE_HELDOUT_DIR / "aistpp.yaml"
    pairs = sb.load_attribute_pairs(path)
    assert list(pairs) == list(sb.ATTRIBUTE_NAMES) and all(len(p) >= 4 for p in pairs.values())
    texts = [t for p in pairs.values() for pair in p for t in pair]
    assert len(set(texts)) == len(texts)  # no wording twice
    training = {t.lower() for texts in load_prompts(STYLE_PROMPTS_FILE, AISTPP_GENRES) for t in texts}
    assert not {t.format(genre=n.lower()).lower() for t in texts for n in AISTPP_GENRES.names} & training
    with pytest.raises(sb.ConfigError, match="no such file"):
        sb.resolve_attribute_wordings("nowhere")
    bad = tmp_path / "bad.yaml"
    for text, message in (("speed: [['slow {genre}', 'fast {genre}']]", "unknown attribute 'speed'"),
                          ("level: [['low {genre}']]", "not a pair"), ("arms: [['up', 'down {genre}']]", "not a pair"),
                          ("- a list", "must map")):  # fmt: skip
        bad.write_text(text)
        with pytest.raises(sb.ConfigError, match=message):
            sb.load_attribute_pairs(sb.resolve_attribute_wordings(str(bad)))


@pytest.fixture(scope="module")
def prompt_checkpoint(tmp_path_factory):
    """A tiny prompt-conditioned model (MiniLM, offline) trained for 2 steps on a small synthetic dataset."""
    from dgsdp.cli.config import compose_config
    from dgsdp.cli.train import train
    from dgsdp.data.synthetic import generate_synthetic_aistpp

    base = tmp_path_factory.mktemp("style_bench")
    root = generate_synthetic_aistpp(base / "data", seed=0, sequences_per_genre=2, seconds=7.0, num_ignored=0)
    overrides = [
        "debug=tiny", f"data.root={root}", "data.synthetic=null", f"paths.cache_dir={base / 'cache'}",
        "data.progress=false", "logger=none", "~callbacks.progress", "style=prompt", "trainer.max_steps=2",
        "trainer.limit_val_batches=0",
    ]  # fmt: skip
    result = train(compose_config("train", overrides, output_dir=base / "run"))
    return {"checkpoint": result["checkpoint"], "root": str(root), "cache": str(base / "cache"), "base": base}


def test_benchmark_end_to_end(prompt_checkpoint, capsys):
    run = prompt_checkpoint
    out = run["base"] / "out"
    wordings = run["base"] / "wordings.yaml"  # one pair: ten more pairs of dances, one per genre
    wordings.write_text("turning:\n  - ['{genre} facing ahead', '{genre} spinning']\n")
    code = sb.main([
        "--checkpoint", run["checkpoint"], "--data-root", run["root"], "--max-clips", "10", "--no-progress",
        "--json", str(out / "style.json"), "--png", str(out / "confusion.png"), "--heldout", "aistpp_second",
        "--heldout", "aistpp_third", "--attributes", str(wordings),
        "device=cpu", "sampling.steps=2", f"paths.cache_dir={run['cache']}",
    ])  # fmt: skip
    assert code == 0
    printed = capsys.readouterr().out.splitlines()
    data = json.loads((out / "style.json").read_text())[0]
    assert (out / "confusion.png").stat().st_size > 1000
    assert data["n_clips"] == 10
    assert data["text_reading"] == {"how": "off", "temperature": None, "descriptions": None}  # its own embedding
    assert data["heldout_descriptions"] == "aistpp_second.yaml"
    assert any(line.startswith("free text (held out)") and "(aistpp_second.yaml)" in line for line in printed)
    assert any(line.startswith("free text, aistpp_third") for line in printed)  # a second list, the same clips
    for name in ("raw", "finished"):
        figures = data[name]
        matrix = np.asarray(figures["confusion"])
        assert matrix.shape == (10, 10) and matrix.sum() == 10
        assert matrix.sum(axis=1).tolist() == [1] * 10  # --max-clips takes the genres in turn
        assert figures["genre_acc"] == pytest.approx(np.trace(matrix) / 10)
        assert 0.0 <= figures["text_acc"] <= 1.0
        assert set(figures["text_by_list"]) == {"aistpp_second", "aistpp_third"}
        assert figures["text_acc"] == figures["text_by_list"]["aistpp_second"]["text_acc"]
        assert np.isnan(figures["text_by_list"]["aistpp_third"]["text_acc_named"])  # the third names no genre
        assert figures["genre_speed_within"] == sum(sb.within(r) for r in figures["speed_ratio"].values())
        pairs = figures["modifier_pairs"]  # one clip of each genre's (here: only) held-out dance, three phrasings
        assert len(pairs) == 30 and {p["genre"] for p in pairs} == set(AISTPP_GENRES.codes)
        assert len({p["dance"] for p in pairs}) == 10
        assert pairs[0]["slower"] == "slow break" and pairs[0]["faster"] == "fast break"
        right = np.mean([p["faster_m_s"] > p["slower_m_s"] for p in pairs])
        assert figures["modifiers_right"] == pytest.approx(right)
        assert -1.0 <= figures["speed_spearman"] <= 1.0
        pairs = figures["attribute_pairs"]
        assert len(pairs) == 10 and {p["genre"] for p in pairs} == set(AISTPP_GENRES.codes)
        assert pairs[0]["less"] == "break facing ahead" and pairs[0]["more"] == "break spinning"
        right = np.mean([p["more_value"] > p["less_value"] for p in pairs])
        assert set(figures["attributes_right"]) == {"turning"} and figures["attributes_right"]["turning"] == right
        assert 0.0 <= figures["attribute_genre_acc"] <= 1.0
    schedule = data["schedule"]
    assert len(schedule["rows"]) == 5 and schedule["span_seconds"] == 10.0  # the 7 s songs looped to 20 s
    assert {r["first"] for r in schedule["rows"]} == set(AISTPP_GENRES.codes[:5])
    expected = (
        f"style_acc={data['raw']['genre_acc']:.3f} text_acc={data['raw']['text_acc']:.3f} "
        f"genre_speed_within_30pct={data['raw']['genre_speed_within']}/10 "
        f"speed_spearman={data['raw']['speed_spearman']:.3f} modifiers={data['raw']['modifiers_right']:.3f} "
        f"gt_acc={data['gt_acc']:.3f} turning={data['raw']['attributes_right']['turning']:.3f} "
        f"attribute_genre_acc={data['raw']['attribute_genre_acc']:.3f}"
    )
    assert printed[-1] == expected
    assert data["attribute_wordings"] == "wordings.yaml"
    assert any(line.startswith("attribute pairs right, turning") for line in printed)
    assert any(line.startswith("confusion matrix, raw") for line in printed)


def test_benchmark_refuses_a_model_without_style(tmp_path, capsys):
    import sys
    from pathlib import Path

    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generation"))
    from gen_helpers import train_tiny_checkpoint

    checkpoint = train_tiny_checkpoint(tmp_path, ("style=none",))
    code = sb.main(["--checkpoint", checkpoint, "--no-progress", "device=cpu", f"paths.cache_dir={tmp_path / 'c'}"])
    assert code == 2
    assert "trained without style" in capsys.readouterr().err


def test_free_text_read_through_other_descriptions_asks_for_their_genres(prompt_checkpoint):
    """style_text_descriptions: text read through the augmented descriptions becomes a blend of the model's genre
    means, weighted by the genres of the descriptions it resembles (one description: exactly its genre's mean)."""
    from dgsdp.errors import ConfigError
    from dgsdp.generation.pipeline import DanceGenerator
    from dgsdp.style.embeddings import load_prompts, resolve_prompts_file

    run = prompt_checkpoint
    kr_text = load_prompts(resolve_prompts_file("aistpp_augmented"))[AISTPP_GENRES.index("KR")][-1]
    gen = DanceGenerator.from_checkpoint(
        run["checkpoint"], cache_dir=run["cache"], text_temperature=1e-4, text_descriptions="aistpp_augmented"
    )
    bank = gen.model.style_bank
    kr_mean = bank.mean_for(torch.tensor([AISTPP_GENRES.index("KR")], device=bank.vectors.device))[0].cpu()
    assert torch.allclose(gen.embed_style(kr_text), kr_mean, atol=1e-5)
    # at a large temperature every description weighs the same, and every genre has 20: the mean of the genre means
    flat = DanceGenerator.from_checkpoint(
        run["checkpoint"], cache_dir=run["cache"], text_temperature=1e4, text_descriptions="aistpp_augmented"
    )
    all_means = bank.mean_for(torch.arange(10, device=bank.vectors.device)).cpu()
    assert torch.allclose(flat.embed_style("anything at all, moving"), all_means.mean(0), atol=1e-4)
    # the model's own descriptions (the default) keep their own embeddings, not the genre means
    own = DanceGenerator.from_checkpoint(run["checkpoint"], cache_dir=run["cache"], text_temperature=1e-4)
    assert not torch.allclose(own.embed_style(kr_text), kr_mean, atol=1e-3)
    with pytest.raises(ConfigError, match="style_text_reading=router"):
        DanceGenerator.from_checkpoint(run["checkpoint"], cache_dir=run["cache"], text_descriptions="aistpp_augmented")


def test_a_run_that_chose_a_reading_is_read_that_way_unless_told_otherwise(prompt_checkpoint):
    """The style recipes record generation.style_text_*: generate.py, the studio and the benchmarks read free text
    that way by default; off or explicit settings win."""
    from dgsdp.generation.pipeline import DanceGenerator, TextReadingChoice
    from dgsdp.trained import load_model

    run = prompt_checkpoint
    model = load_model(run["checkpoint"])
    assert DanceGenerator(model, cache_dir=run["cache"]).text_choice == TextReadingChoice()  # the run chose none
    model.spec.record["generation"] = {"style_text_temperature": 0.02, "style_text_descriptions": "aistpp_augmented"}
    chosen = DanceGenerator(model, cache_dir=run["cache"])
    assert chosen.text_choice == TextReadingChoice("blend", 0.02, "aistpp_augmented")
    bank = model.style_bank
    kr = AISTPP_GENRES.index("KR")
    kr_mean = bank.mean_for(torch.tensor([kr], device=bank.vectors.device))[0].cpu()
    text = "heavy stomping with the chest thrust forward and the arms thrown out violently"
    own = DanceGenerator(model, cache_dir=run["cache"], text_temperature="off")
    assert own.text_choice == TextReadingChoice("off")
    assert torch.allclose(own.embed_style(text), own.embedder().embed_text(text).float().cpu())
    # read, the text is a blend of the model's genre means: nearer the krump mean than its own embedding is
    read = chosen.embed_style(text)
    assert torch.dist(read, kr_mean) < torch.dist(own.embed_style(text), kr_mean)
    mine = DanceGenerator(model, cache_dir=run["cache"], text_temperature=0.5)
    assert mine.text_choice == TextReadingChoice("blend", 0.5, None)  # the model's own descriptions
