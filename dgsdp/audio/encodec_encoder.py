"""Encodec features (DGSDP ablation): the continuous latent of Meta's 24 kHz neural codec at 30 FPS.

Tensor choice: the output of ``model.encoder`` (before residual vector quantisation), ``(hidden_size=128)``
channels at 75 Hz for ``facebook/encodec_24khz``. It keeps all information the quantiser would round away
and is a single fixed-size vector per frame. Resampling 75 Hz -> 30 FPS uses an anti-aliased polyphase
filter (soxr, via librosa) by default, so fast latent changes do not alias into the 30 FPS rows.

Long songs are encoded in chunks (``chunk_seconds``) with ``context_seconds`` of audio on each side that is
encoded and dropped, so memory stays bounded; the encoder's final LSTM sees that much context across a
chunk boundary. Weights load lazily on the first :meth:`encode`, so building the encoder from config is cheap.
"""

from __future__ import annotations

import math
import os
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np
import torch

from dgsdp.audio.base import AudioEncoder, resample_frames
from dgsdp.errors import ConfigError, WeightsError
from dgsdp.utils.device import resolve_device

if TYPE_CHECKING:
    from transformers import EncodecConfig, EncodecModel

DEFAULT_MODEL_ID = "facebook/encodec_24khz"


class EncodecEncoder(AudioEncoder):
    """Continuous Encodec encoder latent, ``(n_frames, hidden_size)`` at 30 FPS."""

    name: ClassVar[str] = "encodec"

    def __init__(
        self,
        model_id: str = DEFAULT_MODEL_ID,
        local_dir: str | os.PathLike | None = None,
        device: str = "cpu",
        half_precision: bool = False,
        chunk_seconds: float | None = 30.0,
        context_seconds: float = 1.0,
        resample_type: str = "soxr_hq",
        feature_dim: int = 128,
        sample_rate: int = 24000,
        per_window: bool = False,
        beat_phase: bool = False,
    ) -> None:
        if chunk_seconds is not None and chunk_seconds <= 0:
            raise ConfigError(f"audio.chunk_seconds must be > 0 or null, got {chunk_seconds}")
        self.model_id = str(model_id)
        self.local_dir = None if local_dir in (None, "") else str(local_dir)
        self.device = resolve_device(device)
        self.half_precision = bool(half_precision)
        self.chunk_seconds = None if chunk_seconds is None else float(chunk_seconds)
        self.context_seconds = float(context_seconds)
        self.resample_type = str(resample_type)
        self.per_window = bool(per_window)  # not a settings() key: whole-song features are the same
        self.beat_phase = bool(beat_phase)
        # Until the model is loaded these describe the default 24 kHz model; loading overwrites them.
        self.feature_dim = int(feature_dim)
        self.sample_rate = int(sample_rate)
        self._model: EncodecModel | None = None
        self._config_source = "pretrained"

    @classmethod
    def from_config(cls, config: EncodecConfig, **kwargs: Any) -> EncodecEncoder:
        """An encoder around a randomly initialised ``EncodecModel(config)`` (tests, custom codecs)."""
        from transformers import EncodecModel

        encoder = cls(**kwargs)
        encoder._set_model(EncodecModel(config))
        encoder._config_source = f"random:{config.to_json_string(use_diff=True)}"
        return encoder

    def _set_model(self, model: EncodecModel) -> None:
        dtype = torch.float16 if self.half_precision else torch.float32
        self._model = model.eval().to(device=self.device, dtype=dtype)
        self.feature_dim = int(model.config.hidden_size)
        self.sample_rate = int(model.config.sampling_rate)

    @property
    def model(self) -> EncodecModel:
        """The loaded model (loads the pretrained weights on first use)."""
        if self._model is None:
            self._set_model(self._load_pretrained())
        return self._model

    def _load_pretrained(self) -> EncodecModel:
        from transformers import EncodecModel

        source = self.local_dir if self.local_dir is not None else self.model_id
        how_to = (
            f"Download the weights on a machine with internet access, e.g. "
            f"`huggingface-cli download {self.model_id} --local-dir data/weights/encodec_24khz`, "
            "then set `audio.local_dir=<that folder>` (or the DGSDP_ENCODEC_DIR environment variable)."
        )
        if self.local_dir is not None and not Path(self.local_dir).is_dir():
            raise WeightsError(f"Encodec weights folder {self.local_dir} does not exist. {how_to}")
        try:
            return EncodecModel.from_pretrained(source)
        except (OSError, ValueError) as err:
            offline = os.environ.get("HF_HUB_OFFLINE", "0") not in ("", "0", "false", "False")
            reason = "offline mode (HF_HUB_OFFLINE) is set" if offline else "the hub could not be reached"
            raise WeightsError(
                f"Cannot load Encodec weights from '{source}' ({reason} or the files are missing: {err}). {how_to}"
            ) from err

    def settings(self) -> dict[str, Any]:
        return {
            "model_id": self.model_id,
            "local_dir": self.local_dir,
            "config": self._config_source,
            "half_precision": self.half_precision,
            "chunk_seconds": self.chunk_seconds,
            "context_seconds": self.context_seconds,
            "resample_type": self.resample_type,
        }

    @property
    def hop_length(self) -> int:
        """Audio samples per latent frame (320 for the 24 kHz model: 75 Hz)."""
        return int(np.prod(self.model.config.upsampling_ratios))

    @torch.no_grad()
    def _latent(self, waveform: np.ndarray) -> np.ndarray:
        """Encoder output of one piece of audio: ``(samples,)`` -> ``(ceil(samples / hop), D)``."""
        model = self.model
        x = torch.from_numpy(waveform).to(device=self.device, dtype=next(model.parameters()).dtype)
        x = x.view(1, 1, -1).expand(1, model.config.audio_channels, -1)
        if model.config.normalize:
            # Same input scaling as EncodecModel.encode applies before its encoder.
            x = x / (x.pow(2).mean(dim=-1, keepdim=True).sqrt() + 1e-8)
        latent = model.encoder(x)  # (1, D, frames)
        return latent[0].float().T.cpu().numpy()

    def _encode(self, waveform: np.ndarray, music_id: str | None) -> np.ndarray:
        hop = self.hop_length
        n_latent = math.ceil(waveform.shape[0] / hop)
        if self.chunk_seconds is None:
            latent = self._latent(waveform)
        else:
            chunk = max(1, round(self.chunk_seconds * self.sample_rate / hop)) * hop
            context = round(self.context_seconds * self.sample_rate / hop) * hop
            pieces = []
            for start in range(0, waveform.shape[0], chunk):
                lo = max(0, start - context)
                hi = min(waveform.shape[0], start + chunk + context)
                part = self._latent(waveform[lo:hi])
                first = (start - lo) // hop
                pieces.append(part[first : first + chunk // hop])
            latent = np.concatenate(pieces, axis=0)
        latent = latent[:n_latent]
        rate_hz = self.sample_rate / hop
        return resample_frames(latent, rate_hz, self.fps, res_type=self.resample_type)
