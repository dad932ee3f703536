"""Reading EDGE's ``checkpoint.pt`` without running code from it.

EDGE saves ``{"ema_state_dict", "model_state_dict", "optimizer_state_dict", "normalizer"}`` with ``torch.save``;
the normaliser is a pickled ``dataset.preprocess.Normalizer`` holding a ``dataset.scaler.MinMaxScaler``.
``torch.load(weights_only=True)`` refuses those two classes, and a full unpickling would call whatever
global the pickle names. Here torch's weights-only unpickler reads the file with exactly two extra globals
allowed: two empty stand-in classes of ours under EDGE's names, which only receive the attributes stored in the
file (no ``__init__`` or ``__setstate__`` of anyone's runs). Every other global is refused by torch before
anything is called, and the error names it. The stand-ins are then read into plain tensors and numbers.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import torch

from dgsdp.errors import CheckpointError
from dgsdp.safety.checkpoint_file import load_checkpoint, reading

NORMALIZER_CLASS = ("dataset.preprocess", "Normalizer")
SCALER_CLASS = ("dataset.scaler", "MinMaxScaler")
REQUIRED_KEYS = ("ema_state_dict", "model_state_dict", "normalizer")
SCALER_TENSORS = ("scale_", "min_", "data_min_", "data_max_", "data_range_")
SCALER_ATTRIBUTES = frozenset((*SCALER_TENSORS, "feature_range", "copy", "clip", "n_samples_seen_"))
DOWNLOAD_HINT = "EDGE's release is fetched by download_model.sh in its repository (Stanford-TML/EDGE)"


@dataclass(frozen=True)
class EdgeScaler:
    """EDGE's fitted MinMaxScaler as plain data: x_normalised = x * scale + min (per channel)."""

    scale: torch.Tensor  # (C,)
    min: torch.Tensor  # (C,)
    data_min: torch.Tensor  # (C,)
    data_max: torch.Tensor  # (C,)
    data_range: torch.Tensor  # (C,)
    feature_range: tuple[float, float]
    clip: bool
    n_samples_seen: int


@dataclass(frozen=True)
class EdgeCheckpoint:
    """The parts of an EDGE checkpoint that make a model: both weight sets (DanceDecoder keys, without a
    ``module.`` prefix) and the normaliser."""

    path: Path
    ema: dict[str, torch.Tensor]
    model: dict[str, torch.Tensor]
    scaler: EdgeScaler

    def weights(self, which: str) -> dict[str, torch.Tensor]:
        if which not in ("ema", "model"):
            raise ValueError(f"weights must be 'ema' or 'model', got {which!r}")
        return self.ema if which == "ema" else self.model


def _stand_in(module: str, name: str) -> type:
    """An empty class that torch's weights-only unpickler may instantiate under EDGE's name."""
    return type(name, (), {"__module__": module, "__qualname__": name, "__doc__": f"stand-in for {module}.{name}"})


def read_edge_checkpoint(path: str | Path) -> EdgeCheckpoint:
    """EDGE's checkpoint as tensors and numbers, or one CheckpointError saying what is wrong (an
    :class:`UnsafeCheckpointError` naming the refused global for a file that would run code). The file is scanned
    before it is read (:mod:`dgsdp.safety.checkpoint_file`), and every check of what it holds runs inside the error
    boundary."""
    p = Path(path).expanduser()
    normalizer_cls, scaler_cls = _stand_in(*NORMALIZER_CLASS), _stand_in(*SCALER_CLASS)
    raw = load_checkpoint(
        p, what="EDGE checkpoint", safe_globals=[normalizer_cls, scaler_cls],
        hint=f"EDGE's checkpoints hold only tensors and its Normalizer/MinMaxScaler; get it from EDGE's release "
        f"({DOWNLOAD_HINT}).",
    )  # fmt: skip
    with reading(p, "EDGE checkpoint"):
        if not isinstance(raw, Mapping):
            raise CheckpointError(f"{p} is not an EDGE checkpoint: it holds a {type(raw).__name__}, not a dict")
        missing = [k for k in REQUIRED_KEYS if k not in raw]
        if missing:
            raise CheckpointError(
                f"{p} is not an EDGE checkpoint: it has no {', '.join(missing)} (found: {', '.join(map(str, raw))})"
            )
        return EdgeCheckpoint(
            path=p,
            ema=_state_dict(raw["ema_state_dict"], "ema_state_dict", p),
            model=_state_dict(raw["model_state_dict"], "model_state_dict", p),
            scaler=_scaler(raw["normalizer"], normalizer_cls, scaler_cls, p),
        )


def _state_dict(value: Any, key: str, p: Path) -> dict[str, torch.Tensor]:
    """A name -> tensor mapping without the ``module.`` prefix of a multi-process save."""
    if not isinstance(value, Mapping) or not value:
        raise CheckpointError(f"{p}: {key} is not a non-empty mapping of weights")
    bad = [str(k) for k, v in value.items() if not isinstance(k, str) or not torch.is_tensor(v)]
    if bad:
        raise CheckpointError(f"{p}: {key} holds entries that are not named tensors: {', '.join(bad[:5])}")
    if all(k.startswith("module.") for k in value):
        return {k.removeprefix("module."): v for k, v in value.items()}
    return dict(value)


def _scaler(normalizer: Any, normalizer_cls: type, scaler_cls: type, p: Path) -> EdgeScaler:
    where = f"{p}: the normalizer"
    if type(normalizer) is not normalizer_cls or set(vars(normalizer)) != {"scaler"}:
        raise CheckpointError(f"{where} is not EDGE's dataset.preprocess.Normalizer holding one scaler")
    scaler = normalizer.scaler
    if type(scaler) is not scaler_cls:
        raise CheckpointError(f"{where}'s scaler is a {type(scaler).__name__}, not EDGE's dataset.scaler.MinMaxScaler")
    attributes = vars(scaler)
    if set(attributes) != SCALER_ATTRIBUTES:
        missing, extra = SCALER_ATTRIBUTES - set(attributes), set(attributes) - SCALER_ATTRIBUTES
        raise CheckpointError(
            f"{where}'s MinMaxScaler has other attributes than EDGE's fitted one"
            + (f"; missing: {', '.join(sorted(missing))}" if missing else "")
            + (f"; unexpected: {', '.join(sorted(extra))}" if extra else "")
        )
    tensors = {}
    for name in SCALER_TENSORS:
        value = attributes[name]
        if not torch.is_tensor(value) or value.ndim != 1 or not value.is_floating_point():
            raise CheckpointError(f"{where}'s {name} is not a 1-d float tensor")
        if not torch.isfinite(value).all():
            raise CheckpointError(f"{where}'s {name} holds values that are not finite")
        tensors[name] = value.detach().float().clone()
    sizes = {v.shape[0] for v in tensors.values()}
    if len(sizes) != 1:
        raise CheckpointError(f"{where}'s statistics have different lengths: {sorted(sizes)}")
    feature_range = attributes["feature_range"]
    if (
        not isinstance(feature_range, tuple | list)
        or not all(isinstance(v, int | float) and not isinstance(v, bool) for v in feature_range)
        or [float(v) for v in feature_range] != [-1.0, 1.0]
    ):
        raise CheckpointError(f"{where} scales to {feature_range!r}; EDGE's normaliser scales to (-1, 1)")
    if not (tensors["scale_"] > 0).all():
        raise CheckpointError(f"{where}'s scale_ is not positive on every channel")
    expected_min = -1.0 - tensors["data_min_"] * tensors["scale_"]
    if not torch.allclose(tensors["min_"], expected_min, rtol=1e-4, atol=1e-4):
        raise CheckpointError(f"{where}'s min_ does not match its data_min_ and scale_; the file is damaged")
    if not isinstance(attributes["clip"], bool):
        raise CheckpointError(f"{where}'s clip is a {type(attributes['clip']).__name__}, not true or false")
    n_seen = attributes["n_samples_seen_"]
    if isinstance(n_seen, bool) or not isinstance(n_seen, int):
        raise CheckpointError(f"{where}'s n_samples_seen_ is not an integer")
    return EdgeScaler(
        scale=tensors["scale_"],
        min=tensors["min_"],
        data_min=tensors["data_min_"],
        data_max=tensors["data_max_"],
        data_range=tensors["data_range_"],
        feature_range=(-1.0, 1.0),
        clip=attributes["clip"],
        n_samples_seen=int(n_seen),
    )
