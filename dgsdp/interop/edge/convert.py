"""EDGE's checkpoint as an ordinary dgsdp checkpoint.

The run spec is ``experiment=edge`` (EDGE's denoiser, no style) with the audio encoder of EDGE's feature type:
``audio=jukebox`` for 4800-d features, ``audio=librosa`` with EDGE's plain settings (no loudness normalisation,
no per-song standardisation, MFCCs up to Nyquist) for its 35-d baseline features. The weights go into both the
model and its EMA copy (EDGE's EMA weights by default), the normaliser takes EDGE's fitted scaler, and the floor
height is measured from the model's own unconditional dances unless given. What EDGE's sampling used (guidance
weight, window, stride, frame rate) is recorded under ``edge_import`` in the stored config.
"""

from __future__ import annotations

import hashlib
import logging
import math
from pathlib import Path
from typing import Any

import torch

from dgsdp.errors import CheckpointError
from dgsdp.interop.edge.checkpoint import EdgeCheckpoint, EdgeScaler, read_edge_checkpoint
from dgsdp.interop.edge.weights import EDGE_HEADS, EdgeArchitecture, edge_architecture, to_dgsdp
from dgsdp.safety.checkpoint_file import reading
from dgsdp.utils.io import atomic_path

log = logging.getLogger(__name__)

# How EDGE's test.py samples (EDGE.py, model/diffusion.py): recorded with every import.
EDGE_SAMPLING = {"guidance_weight": 2.0, "window_frames": 150, "stride_frames": 75, "fps": 30, "ddim_steps": 50}
# audio config group and overrides per EDGE feature type
# (EDGE trained and sampled on features computed per 5 s slice: per_window)
AUDIO_GROUPS = {"jukebox": "jukebox", "baseline": "librosa"}
AUDIO_OVERRIDES = {
    "jukebox": ["audio.per_window=true", "audio.fp16=false"],  # EDGE: float32 activations
    "baseline": [
        "audio.loudness_lufs=null", "audio.standardize=none", "audio.mfcc_fmax_hz=null",
        "audio.per_window=true",
    ],
}  # fmt: skip
PAPER_SIZE = {"d_model": 512, "n_layers": 8, "ff_dim": 1024, "seq_len": 150}
FLOOR_SAMPLES = 8


def edge_overrides(arch: EdgeArchitecture, n_heads: int = EDGE_HEADS) -> list[str]:
    """The train.py overrides that build this EDGE model: ``experiment=edge``, its audio, and its sizes."""
    overrides = ["experiment=edge", f"audio={AUDIO_GROUPS[arch.feature_type]}", *AUDIO_OVERRIDES[arch.feature_type]]
    sizes = {"d_model": arch.d_model, "n_layers": arch.n_layers, "ff_dim": arch.ff_dim, "seq_len": arch.seq_len}
    overrides += [f"model.{k}={v}" for k, v in sizes.items() if PAPER_SIZE[k] != v]
    if n_heads != EDGE_HEADS:
        overrides.append(f"model.n_heads={n_heads}")
    if arch.encoder_layers != 2:
        overrides.append(f"model.music_encoder_layers={arch.encoder_layers}")
    overrides.append(f"data.window_seconds={arch.seq_len / EDGE_SAMPLING['fps']}")
    return overrides


def edge_run_spec(arch: EdgeArchitecture, n_heads: int = EDGE_HEADS, record: dict[str, Any] | None = None) -> Any:
    """The RunSpec of an EDGE model: the composed train config of :func:`edge_overrides`."""
    from omegaconf import open_dict

    from dgsdp.cli.config import compose_config
    from dgsdp.registry import build
    from dgsdp.trained.spec import RunSpec

    overrides = edge_overrides(arch, n_heads)
    cfg = compose_config("train", overrides)
    with open_dict(cfg):
        cfg.edge_import = record or {}
    audio_encoder = build(cfg.audio, "audio", where="audio")
    groups = {"experiment": "edge", "audio": AUDIO_GROUPS[arch.feature_type], "style": "none", "model": "paper"}
    return RunSpec.from_config(cfg, audio_encoder=audio_encoder, style_embedder=None, style_bank_size=0, groups=groups)


def normalizer_state(scaler: EdgeScaler) -> dict[str, torch.Tensor]:
    """EDGE's scaler as the MinMaxNormalizer's buffers. EDGE maps x to x * scale + min with scale = 2 / range
    (range 1 where the data range is below 10 float32 epsilons); the effective range 2 / scale is kept, so both
    map every value alike."""
    data_min = scaler.data_min
    return {"data_min": data_min.clone(), "data_max": data_min + 2.0 / scaler.scale, "fitted": torch.tensor(True)}


def sha256(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def build_model(edge: EdgeCheckpoint, weights: str = "ema", n_heads: int = EDGE_HEADS) -> Any:
    """A :class:`~dgsdp.trained.TrainedModel` holding EDGE's weights and normaliser (floor height 0)."""
    from dgsdp.trained import TrainedModel

    state = edge.weights(weights)
    arch = edge_architecture(state)
    if arch.d_model % n_heads or (arch.d_model // n_heads) % 2:
        raise CheckpointError(f"width {arch.d_model} does not split into {n_heads} heads of even width")
    if edge.scaler.scale.shape[0] != 151:
        raise CheckpointError(f"{edge.path}: the normaliser has {edge.scaler.scale.shape[0]} channels, EDGE's 151")
    record = {
        "source": edge.path.name,
        "sha256": sha256(edge.path) if edge.path.is_file() else None,
        "weights": weights,
        "feature_type": arch.feature_type,
        **EDGE_SAMPLING,
    }
    spec = edge_run_spec(arch, n_heads, record)
    model = TrainedModel(spec, source="checkpoint")
    ours = to_dgsdp(state, arch)
    model.denoiser.load_state_dict(ours)
    model.ema.module.load_state_dict(ours)
    model.normalizer.load_state_dict(normalizer_state(edge.scaler))
    return model.eval()


def measure_floor(model: Any, n_samples: int = FLOOR_SAMPLES, seed: int = 0) -> float:
    """The floor of the model's own dances: :func:`dgsdp.motion.measure_floor_height` of ``n_samples``
    unconditional windows (null music, dpmpp_2m with 10 steps), as train.py measures it on the training data."""
    from dgsdp.generation.longform import DanceRequest, sample_items
    from dgsdp.motion import measure_floor_height
    from dgsdp.sampling import Guidance

    request = DanceRequest(model.spec.window_frames, num_samples=n_samples, seed=seed)
    (motions,) = sample_items(
        model.sampler(), model.normalizer, [request], window=model.spec.window_frames, method="dpmpp_2m", steps=10,
        guidance=Guidance(1.0, 1.0),
    )  # fmt: skip
    return measure_floor_height(motions)


def import_edge(
    source: str | Path,
    out: str | Path,
    *,
    weights: str = "ema",
    floor_height: float | None = None,
    n_heads: int = EDGE_HEADS,
) -> Path:
    """Read EDGE's checkpoint ``source`` safely and write it to ``out`` as a dgsdp checkpoint (atomically: a
    failed import leaves nothing at ``out``, and an existing ``out`` is replaced only by a complete file)."""
    from dgsdp.trained.model import CHECKPOINT_FORMAT, check_floor_height, plain

    out = Path(out).expanduser()
    if out.is_dir():
        raise CheckpointError(f"{out} is a folder; give the path of the checkpoint file to write")
    edge = read_edge_checkpoint(source)
    with reading(edge.path, "EDGE checkpoint"):
        model = build_model(edge, weights, n_heads)
    if floor_height is None:
        floor_height = measure_floor(model)
        how = f"measured on {FLOOR_SAMPLES} unconditional samples"
    else:
        how = "given"
    if not math.isfinite(floor_height):
        raise CheckpointError("the floor height is not finite; give --floor-height")
    model.set_floor_height(check_floor_height(floor_height, "the floor height"))
    log.info("floor height %.3f m (%s)", floor_height, how)
    hyper = plain(model.spec.to_dict())
    hyper["record"]["edge_import"]["floor_height"] = {"metres": float(floor_height), "how": how}
    checkpoint = {
        "state_dict": model.state_dict(),
        "hyper_parameters": hyper,
        "dgsdp_format": CHECKPOINT_FORMAT,
        "epoch": 0,
        "global_step": 0,
        "logger_run_ids": {},
    }
    with atomic_path(out) as tmp:
        torch.save(checkpoint, tmp)
    return out
