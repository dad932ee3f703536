"""Fixtures of the audio tests."""

from __future__ import annotations

from pathlib import Path

import pytest
from audio_synth import click_track, write_audio


@pytest.fixture
def song_dir(tmp_path: Path) -> Path:
    """Three short click-track songs named like AIST++ music ids."""
    folder = tmp_path / "wavs"
    for name, bpm, seconds in (("mBR4", 120.0, 3.0), ("mPO2", 100.0, 2.0), ("mHO2", 120.0, 2.5)):
        write_audio(folder / f"{name}.wav", click_track(seconds, bpm, 22050), 22050)
    return folder
