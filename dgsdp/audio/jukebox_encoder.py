"""OpenAI Jukebox features (EDGE): activations of one layer of the 5B top-level prior, at 30 FPS.

Built on the model classes of the optional package ``jukebox-infer`` (``pip install 'dgsdp[jukebox]'``).
Per slice of ``slice_seconds`` (EDGE: 5 s), as EDGE's extractor (jukemirlib) does:

1. the slice, mono at 44.1 kHz, is peak-normalised (EDGE loads every 5 s slice file and normalises it);
2. the VQ-VAE turns it into top-level tokens (44100 / 128 = 344.53 Hz);
3. the prior's label conditioning is built for artist "unknown", genre "unknown", a 62 s total length
   (the prior accepts 60-600 s) and offset 0;
4. tokens are embedded, shifted right behind the label embedding, summed with the position and timing
   embeddings and run through the first ``layer`` transformer blocks (EDGE: 66 of 72); the residual
   stream after block ``layer`` is the feature (4800-d);
5. the token-rate activations are resampled to 30 FPS with librosa's FFT resampling.

A whole song is cut into consecutive slices; the last one is aligned to the song's end so every slice is
full length, and only the frames not covered by earlier slices are taken from it. Each slice starts with
an empty context, as in EDGE.

Memory: the models are built on the meta device (no allocation), the prior is cut to ``layer`` blocks
before the checkpoint is read, only the tensors of the kept blocks are loaded, and the prior's linear
weights are kept in fp16 (``fp16=True``) as Jukebox itself does.

The conditioning and the layer loop call the package's modules (embeddings, ``LabelConditioner`` parts,
``ResAttnBlock``) directly instead of its ``forward`` methods, because those assert CUDA tensors and run
all 72 blocks; the arithmetic is the same.
"""

from __future__ import annotations

import contextlib
import io
import os
import zipfile
from collections.abc import Mapping
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import torch
from torch import nn

from dgsdp.audio.base import AudioEncoder, fit_frames, resample_frames
from dgsdp.errors import CheckpointError, ConfigError, WeightsError
from dgsdp.safety.checkpoint_file import load_checkpoint
from dgsdp.utils.device import resolve_device

JUKEBOX_SAMPLE_RATE = 44100
# Total song length given to the label conditioner; the 5B prior was trained on 60-600 s songs.
CONDITIONING_TOTAL_SECONDS = 62.0
WEIGHT_FILES = {"vqvae": "vqvae.pth.tar", "prior": "prior_level_2.pth.tar"}
WEIGHTS_URL = "https://openaipublic.azureedge.net/jukebox/models/5b/"
PIP_EXTRA = "pip install 'dgsdp[jukebox]'  (installs jukebox-infer)"


def _import_jukebox() -> Any:
    """The ``jukebox_infer`` package, or a WeightsError naming the pip extra."""
    try:
        import jukebox_infer  # noqa: F401
        from jukebox_infer import hparams, make_models
    except ImportError as err:
        raise WeightsError(
            f"Jukebox features need the optional package jukebox-infer, which is not installed: {PIP_EXTRA}. "
            "Or use another audio encoder (audio=librosa or audio=encodec)."
        ) from err
    return hparams, make_models


def slice_starts(n_samples: int, slice_samples: int) -> list[int]:
    """Start samples of consecutive full slices covering ``n_samples``; the last one ends at the end.

    A song shorter than one slice is a single (short) slice starting at 0.
    """
    if n_samples <= slice_samples:
        return [0]
    starts = list(range(0, n_samples - slice_samples + 1, slice_samples))
    if starts[-1] + slice_samples < n_samples:
        starts.append(n_samples - slice_samples)
    return starts


def prior_block_index(key: str) -> int | None:
    """Transformer block number of a prior state-dict key (``prior.transformer._attn_mods.<i>.``), else None."""
    marker = "prior.transformer._attn_mods."
    if not key.startswith(marker):
        return None
    return int(key[len(marker) :].split(".", 1)[0])


def select_prior_state(state: Mapping[str, torch.Tensor], layer: int) -> dict[str, torch.Tensor]:
    """Keep the tensors the first ``layer`` blocks need: drop later blocks and the output projection."""
    kept = {}
    for key, value in state.items():
        key = key.removeprefix("module.")
        block = prior_block_index(key)
        if block is not None and block >= layer:
            continue
        if key.startswith("prior.x_out."):
            continue
        kept[key] = value
    return kept


def truncate_prior(prior: nn.Module, layer: int) -> None:
    """Cut ``prior.prior.transformer`` to its first ``layer`` blocks and drop the token output head."""
    autoregressive = prior.prior
    blocks = autoregressive.transformer._attn_mods
    if not 1 <= layer <= len(blocks):
        raise ConfigError(f"audio.layer must be in 1..{len(blocks)} for this prior, got {layer}.")
    autoregressive.transformer._attn_mods = nn.ModuleList(list(blocks)[:layer])
    if hasattr(autoregressive, "x_out"):
        del autoregressive.x_out
    autoregressive.only_encode = True


def _load_checkpoint_state(path: Path) -> dict[str, torch.Tensor]:
    """The ``model`` state dict of an official Jukebox checkpoint file, read as tensors and plain values only.

    OpenAI's files hold ``{"hps": dict, "model": state dict, "opt": ..., "step": int}`` in torch's pre-zip format,
    which ``weights_only=True`` reads (jukebox-infer itself loads them that way); memory mapping needs the zip format
    and is used when the file has it. The file is scanned first (:mod:`dgsdp.safety.checkpoint_file`); nothing else is
    tried: a file that needs arbitrary objects is refused.
    """
    try:
        checkpoint = load_checkpoint(
            path, what="Jukebox checkpoint", hint=f"Re-download {path.name} from {WEIGHTS_URL}.",
            mmap=zipfile.is_zipfile(path),
        )  # fmt: skip
    except CheckpointError as e:  # the weights of an encoder: the error a user meets for missing or bad weights
        raise WeightsError(str(e)) from e
    if not isinstance(checkpoint, Mapping) or not isinstance(checkpoint.get("model"), Mapping):
        raise WeightsError(f"{path} is not a Jukebox checkpoint (no 'model' entry). Re-download it.")
    return dict(checkpoint["model"])


def _quiet() -> contextlib.AbstractContextManager:
    """The package prints progress while building models; keep the extractor's output clean."""
    return contextlib.redirect_stdout(io.StringIO())


class JukeboxEncoder(AudioEncoder):
    """Jukebox 5B prior activations of block ``layer``, ``(n_frames, 4800)`` at 30 FPS."""

    name: ClassVar[str] = "jukebox"

    def __init__(
        self,
        weights_dir: str | os.PathLike | None = None,
        layer: int = 66,
        device: str = "auto",
        fp16: bool = True,
        slice_seconds: float = 5.0,
        resample_type: str = "fft",
        feature_dim: int = 4800,
        vqvae_overrides: Mapping[str, Any] | None = None,
        prior_overrides: Mapping[str, Any] | None = None,
        per_window: bool = False,
        beat_phase: bool = False,
    ) -> None:
        """``vqvae_overrides`` / ``prior_overrides`` change the package's ``vqvae`` / ``prior_5b``
        hyper-parameters (small models in tests); leave them empty for the released 5B weights."""
        if slice_seconds <= 0:
            raise ConfigError(f"audio.slice_seconds must be > 0, got {slice_seconds}")
        if layer < 1:
            raise ConfigError(f"audio.layer must be >= 1 (1-based block number), got {layer}")
        self.weights_dir = None if weights_dir in (None, "") else str(weights_dir)
        self.layer = int(layer)
        self.device = resolve_device(device)
        self.fp16 = bool(fp16)
        self.slice_seconds = float(slice_seconds)
        self.resample_type = str(resample_type)
        self.sample_rate = JUKEBOX_SAMPLE_RATE
        self.feature_dim = int(feature_dim)
        self.vqvae_overrides = dict(vqvae_overrides or {})
        self.prior_overrides = dict(prior_overrides or {})
        self.per_window = bool(per_window)  # not a settings() key: whole-song features are the same
        self.beat_phase = bool(beat_phase)
        self._vqvae: nn.Module | None = None
        self._prior: nn.Module | None = None
        self._source = "pretrained-5b"
        self._y_cache: dict[int, tuple[torch.Tensor, torch.Tensor]] = {}

    # ------------------------------------------------------------------ construction
    @classmethod
    def from_hparams(
        cls,
        vqvae_overrides: Mapping[str, Any] | None = None,
        prior_overrides: Mapping[str, Any] | None = None,
        **kwargs: Any,
    ) -> JukeboxEncoder:
        """Randomly initialised models of the 5B architecture with hyper-parameters overridden (tests)."""
        hparams, _ = _import_jukebox()
        encoder = cls(vqvae_overrides=vqvae_overrides, prior_overrides=prior_overrides, **kwargs)
        encoder._build(*encoder._hparams(hparams), on_meta=False)
        encoder._finish()
        encoder._source = "random"
        return encoder

    def _hparams(self, hparams: Any) -> tuple[Any, Any]:
        # Empty restore paths: the package's builders then skip their own (downloading) checkpoint loading.
        vqvae_hps = hparams.setup_hparams(
            "vqvae", {"sample_length": 1048576, "restore_vqvae": "", **self.vqvae_overrides}
        )
        prior_hps = hparams.setup_hparams("prior_5b", {"restore_prior": "", **self.prior_overrides})
        return vqvae_hps, prior_hps

    def _build(self, vqvae_hps: Any, prior_hps: Any, on_meta: bool) -> None:
        _, make_models = _import_jukebox()
        device = "meta" if on_meta else "cpu"
        with torch.device(device), _quiet():
            vqvae = make_models.make_vqvae(vqvae_hps, device=device)
            prior = make_models.make_prior(prior_hps, vqvae, device=device)
        if prior.x_cond or not prior.y_cond:
            raise ConfigError("Jukebox features need the top-level, label-conditioned prior (level 2).")
        truncate_prior(prior, self.layer)
        self._vqvae, self._prior = vqvae, prior

    def _finish(self) -> None:
        """Dtypes and device after the weights are in place."""
        from jukebox_infer.transformer.ops import Conv1D

        vqvae, prior = self._vqvae, self._prior
        for model in (vqvae, prior):
            left = [n for n, t in [*model.named_parameters(), *model.named_buffers()] if t.is_meta]
            if left:
                raise WeightsError(f"Jukebox checkpoint left tensors unset ({left[:3]}...); re-download it.")
        vqvae.float()
        prior.float()
        if self.fp16:
            for module in prior.modules():
                if isinstance(module, Conv1D):
                    module.w.data = module.w.data.half()
        self._vqvae = vqvae.to(self.device).eval().requires_grad_(False)
        self._prior = prior.to(self.device).eval().requires_grad_(False)
        self.feature_dim = int(self._prior.prior.width)

    def weight_paths(self) -> dict[str, Path]:
        """Where the two checkpoint files are expected."""
        folder = self.weights_dir or os.environ.get("DGSDP_JUKEBOX_DIR")
        root = Path(folder) if folder else Path.home() / ".cache" / "jukebox" / "models" / "5b"
        return {name: root / file for name, file in WEIGHT_FILES.items()}

    def _load_pretrained(self) -> None:
        hparams, _ = _import_jukebox()
        paths = self.weight_paths()
        missing = [p for p in paths.values() if not p.is_file()]
        if missing:
            folder = next(iter(paths.values())).parent
            downloads = " && ".join(f"curl -L -o {folder / f} {WEIGHTS_URL}{f}" for f in WEIGHT_FILES.values())
            raise WeightsError(
                f"Jukebox weights not found: {', '.join(str(p) for p in missing)}. Put OpenAI's 5B files "
                f"vqvae.pth.tar and prior_level_2.pth.tar (about 10 GB together) in {folder} "
                f"(set audio.weights_dir or DGSDP_JUKEBOX_DIR to use another folder). Download them with: "
                f"{downloads}"
            )
        self._build(*self._hparams(hparams), on_meta=True)
        for model, path, select in (
            (self._vqvae, paths["vqvae"], lambda s: {k.removeprefix("module."): v for k, v in s.items()}),
            (self._prior, paths["prior"], lambda s: select_prior_state(s, self.layer)),
        ):
            state = select(_load_checkpoint_state(path))
            try:
                model.load_state_dict(state, strict=True, assign=True)
            except RuntimeError as err:
                raise WeightsError(
                    f"{path} does not match the Jukebox 5B architecture ({err}). Re-download it from "
                    f"{WEIGHTS_URL}{path.name}."
                ) from err
            del state
        self._finish()

    def _models(self) -> tuple[nn.Module, nn.Module]:
        if self._prior is None:
            self._load_pretrained()
        return self._vqvae, self._prior

    def settings(self) -> dict[str, Any]:
        return {
            "source": self._source,
            "vqvae_overrides": self.vqvae_overrides,
            "prior_overrides": self.prior_overrides,
            "layer": self.layer,
            "fp16": self.fp16,
            "slice_seconds": self.slice_seconds,
            "resample_type": self.resample_type,
        }

    # ------------------------------------------------------------------ extraction
    @property
    def token_rate_hz(self) -> float:
        """Top-level token rate of the VQ-VAE (44100 / 128 = 344.53 Hz for Jukebox)."""
        _, prior = self._models()
        return self.sample_rate / float(prior.raw_to_tokens)

    @torch.no_grad()
    def _tokens(self, audio: np.ndarray) -> torch.Tensor:
        """Top-level VQ-VAE codes of mono audio ``(samples,)`` -> ``(1, T)`` long."""
        vqvae, _ = self._models()
        x = torch.from_numpy(audio).to(self.device, torch.float32).view(1, -1, 1)
        return vqvae.encode(x, start_level=vqvae.levels - 1)[0]

    @torch.no_grad()
    def _conditioning(self, n_tokens: int) -> tuple[torch.Tensor, torch.Tensor]:
        """Timing embedding ``(1, n_tokens, W)`` and label embedding ``(1, 1, W)`` of the prior."""
        _, prior = self._models()
        if n_tokens not in self._y_cache:
            total = int(CONDITIONING_TOTAL_SECONDS * self.sample_rate) // prior.raw_to_tokens
            meta = {
                "artist": "unknown",
                "genre": "unknown",
                "total_length": int(total * prior.raw_to_tokens),
                "offset": 0,
                "lyrics": "",
            }
            with _quiet():
                labels = prior.labeller.get_batch_labels([meta], "cpu")
            y = prior.get_y(labels, 0).to(self.device)
            y = y[:, : y.shape[1] - prior.n_tokens]
            emb = prior.y_emb
            total_length, offset, length = y[:, 0:1], y[:, 1:2], y[:, 2:3]
            artist, genre = y[:, 3:4], y[:, 4:]
            genre_mask = (genre >= 0).float().unsqueeze(2)
            y_cond = emb.artist_emb.emb(artist) + (emb.bow_genre_emb.emb(genre.clamp(0)) * genre_mask).sum(
                dim=1, keepdim=True
            )
            start, end, total_length = offset.float(), (offset + length).float(), total_length.float()
            x_cond = (
                emb.total_length_emb(total_length)
                + emb.absolute_pos_emb(start, end)
                + emb.relative_pos_emb(start / total_length, end / total_length)
            )
            self._y_cache[n_tokens] = (x_cond[:, :n_tokens].float(), y_cond.float())
        return self._y_cache[n_tokens]

    @torch.no_grad()
    def _activations(self, tokens: torch.Tensor) -> torch.Tensor:
        """Residual stream after block ``layer`` for tokens ``(1, T)`` -> ``(T, W)`` float32."""
        _, prior = self._models()
        net = prior.prior
        n_tokens = tokens.shape[1]
        if n_tokens > net.input_dims:
            raise ConfigError(
                f"audio.slice_seconds={self.slice_seconds} gives {n_tokens} tokens, more than the prior's "
                f"context of {net.input_dims}; use slices of at most {net.input_dims / self.token_rate_hz:.1f} s."
            )
        x_cond, y_cond = self._conditioning(n_tokens)
        x = net.x_emb(tokens)  # (1, T, W)
        x = torch.cat([y_cond.to(x.dtype), x[:, :-1]], dim=1)  # shift right behind the label embedding
        x = x + net.pos_emb()[:n_tokens] + x_cond
        if self.fp16:
            x = x.half()
        for block in net.transformer._attn_mods:
            # sample=True runs the block on any length (padded to whole attention blocks inside) and fills a
            # key/value cache that must be emptied before and after.
            block.attn.del_cache()
            x = block(x, encoder_kv=None, sample=True)
            block.attn.del_cache()
        return x[0].float()

    def _slice_activations(self, audio: np.ndarray) -> np.ndarray:
        """Token-rate features of one slice: ``(samples,)`` -> ``(T, W)``."""
        return self._activations(self._tokens(audio)).cpu().numpy()

    def _encode(self, waveform: np.ndarray, music_id: str | None) -> np.ndarray:
        slice_samples = int(round(self.slice_seconds * self.sample_rate))
        n_frames = (waveform.shape[0] * self.fps) // self.sample_rate
        out: np.ndarray | None = None  # allocated at the first slice, once the model (and its width) is loaded
        filled = 0
        for start in slice_starts(waveform.shape[0], slice_samples):
            piece = waveform[start : start + slice_samples]
            peak = float(np.abs(piece).max())
            if peak > 0:
                piece = piece / peak
            acts = self._slice_activations(np.ascontiguousarray(piece, dtype=np.float32))
            frames = resample_frames(acts, self.token_rate_hz, self.fps, res_type=self.resample_type)
            first = int(round(start * self.fps / self.sample_rate))
            piece_frames = (piece.shape[0] * self.fps) // self.sample_rate
            frames = fit_frames(frames, max(1, piece_frames))
            if out is None:
                out = np.zeros((n_frames, frames.shape[1]), dtype=np.float32)
            # Frames already written by an earlier slice keep it: they had more context there.
            skip = max(0, filled - first)
            end = min(n_frames, first + frames.shape[0])
            if end > first + skip:
                out[first + skip : end] = frames[skip : end - first]
                filled = max(filled, end)
        if n_frames == 0:
            return out
        if filled < n_frames:  # a rounding gap at the very end: repeat the last frame
            out[filled:] = out[filled - 1] if filled > 0 else 0.0
        return out
