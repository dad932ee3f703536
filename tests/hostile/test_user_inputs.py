"""Silent acceptance turned into clear errors or visible warnings: near-miss genres, schedules without a colon,
unknown output formats, a mistyped data.root, short motions, one unreadable file among many, report on a binary
file, sweep --jobs 0, and command-line values Hydra's lexer cannot read."""

from __future__ import annotations

import logging
import pickle
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import torch
from conftest import TALLY, accepted, refused

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "generation"))
from gen_helpers import SEQUENCES, make_tiny_dataset  # noqa: E402

from dgsdp.errors import ConfigError, DataError  # noqa: E402
from dgsdp.style import StyleEmbedder  # noqa: E402
from dgsdp.style.text_encoders import TextEncoder  # noqa: E402
from dgsdp.style.vocab import AISTPP_GENRES  # noqa: E402


class RecordingEncoder(TextEncoder):
    """Deterministic 4-d vectors; remembers what it was asked to encode."""

    name = "recording"

    def __init__(self) -> None:
        self.seen: list[str] = []

    @property
    def dim(self) -> int:
        return 4

    def settings(self) -> dict[str, Any]:
        return {"name": self.name}

    @property
    def loaded(self) -> bool:
        return True

    def _encode_batch(self, texts: list[str]) -> torch.Tensor:
        self.seen.extend(texts)
        return torch.stack([torch.full((4,), float(len(t))) for t in texts])


# --- style ------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "style, genre", [("locking", "lock"), ("popping", "pop"), ("krumpp", "krump"), ("balet jazz", "ballet jazz")]
)
def test_near_miss_genre_says_did_you_mean(style, genre):
    embedder = StyleEmbedder("prompt", text_encoder=RecordingEncoder())
    with pytest.raises(ConfigError) as exc:
        embedder.embed_text(style)
    refused(exc, f"did you mean {genre!r}", f"text: {style}")
    assert embedder.text_encoder.seen == []  # nothing was embedded as free text


def test_free_text_on_purpose_with_prefix():
    encoder = RecordingEncoder()
    embedder = StyleEmbedder("prompt", text_encoder=encoder)
    vector = embedder.embed_text("text:  locking")
    assert encoder.seen == ["locking"] and torch.equal(vector, torch.full((4,), 7.0))
    assert AISTPP_GENRES.suggest("sharp, powerful krump with chest pops") is None  # a description is not a typo
    assert AISTPP_GENRES.suggest("Lock") is None  # a genre is not a near miss
    # a genre with a speed word is a description, not a misspelt genre; a misspelt genre with one still is
    assert AISTPP_GENRES.suggest("slow ballet jazz") is None and AISTPP_GENRES.suggest("fast krump") is None
    assert AISTPP_GENRES.suggest("balet jazz") == "Ballet Jazz" and AISTPP_GENRES.suggest("krumpp") == "Krump"
    accepted()


def test_one_hot_model_refuses_prefixed_free_text():
    with pytest.raises(ConfigError) as exc:
        StyleEmbedder("onehot").embed_text("text: krump")
    refused(exc, "only accepts genre names")


@pytest.mark.parametrize(
    "schedule, entry", [("0-30 krump; 30-60: house", "0-30 krump"), ("0-30: krump; 30-end house", "30-end house")]
)
def test_schedule_entry_without_colon(schedule, entry):
    from dgsdp.generation.schedule import is_schedule, parse_schedule

    assert is_schedule(schedule)  # not mistaken for a free-text description
    with pytest.raises(ConfigError) as exc:
        parse_schedule(schedule)
    refused(exc, f"entry {entry!r} has no ':'")


# --- output formats ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize(
    "formats, fragment", [(["vido"], "did you mean 'video'"), (["fbx"], "valid formats"), ([], "no output format")]
)
def test_unknown_output_format(formats, fragment):
    from dgsdp.export import check_formats

    with pytest.raises(ConfigError) as exc:
        check_formats(formats)
    refused(exc, fragment, "pkl", "bvh", "video", "npy")


# --- data -------------------------------------------------------------------------------------------------------
def _datamodule(root: Path, tmp_path: Path, **kwargs):
    from dgsdp.data.datamodule import DanceDataModule

    return DanceDataModule(str(root), str(tmp_path / "cache"), progress=False, **kwargs)


def test_mistyped_data_root_is_an_error_not_a_new_dataset(tmp_path):
    typo = tmp_path / "datsets" / "aistpp"
    dm = _datamodule(typo, tmp_path, synthetic={"seed": 0}, synthetic_root=str(tmp_path / "data" / "synthetic"))
    with pytest.raises(DataError) as exc:
        dm.prepare_data()
    refused(exc, str(typo), "data.generate_synthetic=true")
    assert not typo.exists()  # nothing written at the typed path


def test_synthetic_data_generated_where_asked(tmp_path):
    tiny = {"seed": 0, "sequences_per_genre": 2, "seconds": 6.0, "genres": ["BR"], "num_ignored": 0}
    root = tmp_path / "elsewhere"
    _datamodule(root, tmp_path, synthetic=tiny, generate_synthetic=True).prepare_data()
    assert any((root / "motions").glob("*.pkl"))
    accepted()


def test_one_unreadable_file_is_reported_not_the_whole_split(tmp_path, caplog):
    from dgsdp.data.datamodule import load_sequences

    root = tmp_path / "data"
    make_tiny_dataset(root, seconds=6.0)
    bad = SEQUENCES["train"][0]
    (root / "motions" / f"{bad}.pkl").write_bytes(b"\x80\x04garbage")
    errors: list[tuple[str, str]] = []
    with caplog.at_level(logging.ERROR):
        seqs = load_sequences(root, "train", cache_dir=tmp_path / "cache", progress=False, errors=errors)
    assert [s.name for s in seqs] == SEQUENCES["train"][1:]
    assert [name for name, _ in errors] == [bad] and bad in caplog.text
    with pytest.raises(DataError) as exc:  # without a collector: one error listing every bad file
        load_sequences(root, "train", cache_dir=tmp_path / "cache2", progress=False)
    refused(exc, "1 of 2 sequences", bad, "cannot read")


def test_short_motions_are_counted(tmp_path, caplog):
    root = tmp_path / "data"
    make_tiny_dataset(root, seconds=6.0)
    short = SEQUENCES["train"][1]
    with open(root / "motions" / f"{short}.pkl", "rb") as f:
        data = pickle.load(f)  # noqa: S301 - a file this test wrote
    data = {k: (v[:120] if isinstance(v, np.ndarray) and v.ndim == 2 else v) for k, v in data.items()}  # 2 s
    (root / "motions" / f"{short}.pkl").write_bytes(pickle.dumps(data))
    dm = _datamodule(root, tmp_path, window_seconds=5.0)
    with caplog.at_level(logging.WARNING):
        dm.setup("fit")
    assert "1 of 2 sequences are shorter than one window (5.0 s)" in caplog.text
    accepted()


# --- report, sweep, command line ----------------------------------------------------------------------------------
def test_report_on_a_binary_file(tmp_path):
    from dgsdp.report.__main__ import main

    path = tmp_path / "results.json"
    path.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(SystemExit) as exc:
        main([str(path), "--out", str(tmp_path / "r"), "--no-plots"])
    message = str(exc.value.code)
    assert "not a results.json" in message and str(path) in message
    refused_like(message)


def refused_like(message: str) -> None:
    """Count a refusal that reaches the user as a SystemExit message (entry points) rather than an exception."""
    assert message.startswith("error: ") and "Traceback" not in message
    TALLY["tried"] += 1
    TALLY["refused cleanly"] += 1


@pytest.mark.parametrize("jobs", ["0", "-2"])
def test_sweep_jobs_must_be_positive(jobs):
    from dgsdp.cli.sweep import main

    with pytest.raises(SystemExit) as exc:
        main(["table5", "--jobs", jobs, "--dry-run"])
    assert "--jobs must be" in str(exc.value.code) and jobs in str(exc.value.code)
    refused_like(str(exc.value.code))


@pytest.mark.parametrize("arg", ["music=/songs/Café del Mar.wav", "music=/songs/曲 (1).wav", "music=/songs/it's.wav"])
def test_command_line_values_hydra_cannot_read(arg):
    from hydra.core.override_parser.overrides_parser import OverridesParser

    from dgsdp.cli.runtime import check_command_line

    with pytest.raises(SystemExit) as exc:
        check_command_line([arg])
    message = str(exc.value.code)
    assert arg in message and "quoted" in message
    suggestion = message.rsplit("e.g. in bash: ", 1)[1]
    import shlex

    (fixed,) = shlex.split(suggestion)  # what the shell passes for the suggested spelling
    parsed = OverridesParser.create().parse_overrides([fixed])[0]
    assert parsed.value() == arg.split("=", 1)[1]  # the suggestion reads back as the intended path
    refused_like(message)
