"""Audio loading and interchangeable music encoders (librosa, Encodec, Jukebox) at 30 FPS, with a feature cache."""

from __future__ import annotations

from typing import Any

from dgsdp.audio.base import AudioEncoder
from dgsdp.audio.cache import FeatureCache, extract_dataset
from dgsdp.audio.encodec_encoder import EncodecEncoder
from dgsdp.audio.io import audio_duration_seconds, load_audio
from dgsdp.audio.jukebox_encoder import JukeboxEncoder
from dgsdp.audio.librosa_encoder import LibrosaEncoder
from dgsdp.audio.tempo import tempo_from_music_id
from dgsdp.errors import ConfigError

AUDIO_ENCODERS: dict[str, type[AudioEncoder]] = {
    LibrosaEncoder.name: LibrosaEncoder,
    EncodecEncoder.name: EncodecEncoder,
    JukeboxEncoder.name: JukeboxEncoder,
}


def build_audio_encoder(name: str, **kwargs: Any) -> AudioEncoder:
    """Build an encoder by name (``librosa``, ``encodec``, ``jukebox``) with constructor keyword arguments."""
    if name not in AUDIO_ENCODERS:
        raise ConfigError(f"Unknown audio encoder '{name}'. Choose one of: {', '.join(AUDIO_ENCODERS)}.")
    return AUDIO_ENCODERS[name](**kwargs)


__all__ = [
    "AUDIO_ENCODERS",
    "AudioEncoder",
    "EncodecEncoder",
    "FeatureCache",
    "JukeboxEncoder",
    "LibrosaEncoder",
    "audio_duration_seconds",
    "build_audio_encoder",
    "extract_dataset",
    "load_audio",
    "tempo_from_music_id",
]
