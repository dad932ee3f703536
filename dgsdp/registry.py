"""The one list of classes a config may build, and the one function that builds them.

Configs name what they build by ``_target_`` (as in Hydra). A config the user composed on the command line is
their own code and may name any class: its module is imported, and a class that registered itself with
:func:`register` on import is built. A config read from a file someone else gave us (the run config stored in a
checkpoint) is data: only classes already in the registry are built, nothing is imported, no value is evaluated,
and anything else is refused with a :class:`~dgsdp.errors.CheckpointError` that names the key and the value.

The project's own classes are listed below by import path (:data:`BUILTINS`) and imported only when a config
names one, so the registry imports none of the packages it lists. A new audio encoder, style embedding, text
encoder, loss or sampler of yours plugs in by decorating its class with ``@register("audio")`` (or the kind it is)
in its own file and naming it in a config file.
"""

from __future__ import annotations

import functools
import importlib
from collections.abc import Callable, Mapping
from typing import Any, Literal

from dgsdp.errors import CheckpointError, ConfigError

Kind = Literal["audio", "style", "text_encoder", "model", "diffusion", "loss", "optimizer"]
Source = Literal["config", "checkpoint"]

# "<kind>" -> {"<module>.<Class>" and public aliases -> class}: classes registered with @register
_REGISTRY: dict[str, dict[str, type]] = {}


def _names(public: str, module: str, cls: str, *more: str) -> dict[str, str]:
    """The names a built-in class answers to (its public alias and its full path) -> ``"module:Class"``."""
    return dict.fromkeys((public, f"{module}.{cls}", *more), f"{module}:{cls}")


# The project's own buildable classes, by the names configs and stored checkpoints use; imported on first use.
BUILTINS: dict[str, dict[str, str]] = {
    "audio": {
        **_names("dgsdp.audio.LibrosaEncoder", "dgsdp.audio.librosa_encoder", "LibrosaEncoder"),
        **_names("dgsdp.audio.EncodecEncoder", "dgsdp.audio.encodec_encoder", "EncodecEncoder"),
        **_names("dgsdp.audio.JukeboxEncoder", "dgsdp.audio.jukebox_encoder", "JukeboxEncoder"),
    },
    "style": _names("dgsdp.style.StyleEmbedder", "dgsdp.style.embeddings", "StyleEmbedder"),
    "text_encoder": {
        **_names("dgsdp.style.MiniLMTextEncoder", "dgsdp.style.text_encoders", "MiniLMTextEncoder"),
        **_names("dgsdp.style.ClipTextEncoder", "dgsdp.style.text_encoders", "ClipTextEncoder"),
    },
    "model": _names("dgsdp.model.DanceDenoiser", "dgsdp.model.denoiser", "DanceDenoiser"),
    "diffusion": _names("dgsdp.diffusion.GaussianDiffusion", "dgsdp.diffusion.gaussian", "GaussianDiffusion"),
    "loss": _names("dgsdp.diffusion.LossWeights", "dgsdp.diffusion.losses", "LossWeights"),
    "optimizer": {
        **_names("dgsdp.training.Adan", "dgsdp.training.optim", "Adan"),
        "adan_pytorch.Adan": "dgsdp.training.optim:Adan",  # runs before it was ours: the same update and state
        "torch.optim.AdamW": "torch.optim:AdamW",
        "torch.optim.adamw.AdamW": "torch.optim:AdamW",
    },
}


def _builtin(kind: str, name: str) -> type | None:
    """The built-in class ``name`` of ``kind`` (its module imported now), or None if there is none."""
    path = BUILTINS.get(kind, {}).get(name)
    if path is None:
        return None
    module, _, cls = path.partition(":")
    return getattr(importlib.import_module(module), cls)


# Keys of a buildable node that steer Hydra-style building; anything else starting with "_" is refused.
_SPECIAL_KEYS = {"_target_", "_partial_", "_recursive_", "_convert_"}
_PLAIN = (str, int, float, bool, type(None))
# Nested nodes that the built class builds itself (through :func:`build`), by key: their kind.
_NESTED_KINDS: dict[str, Kind] = {"text_encoder": "text_encoder"}


def register(kind: Kind, *aliases: str) -> Callable[[type], type]:
    """Class decorator: make ``cls`` buildable as ``kind`` under its full name and ``aliases``."""

    def deco(cls: type) -> type:
        names = {f"{cls.__module__}.{cls.__qualname__}", *aliases}
        table = _REGISTRY.setdefault(kind, {})
        for name in names:
            table[name] = cls
        return cls

    return deco


def check_plain(value: Any, where: str, source: Source) -> None:
    """Refuse anything in a stored config that is not plain data (str, number, bool, None, list, dict)."""
    error = CheckpointError if source == "checkpoint" else ConfigError
    if isinstance(value, Mapping):
        for k, v in value.items():
            if not isinstance(k, str):
                raise error(f"{where}: key {k!r} is not a string; the stored config is not plain data")
            check_plain(v, f"{where}.{k}", source)
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            check_plain(v, f"{where}[{i}]", source)
    elif not isinstance(value, _PLAIN):
        raise error(f"{where} holds a {type(value).__name__}; only plain values may be stored in a config")


def check_no_targets(value: Any, where: str, source: Source) -> None:
    """Refuse a ``_target_`` (or other ``_x_`` building key) anywhere inside ``value``."""
    error = CheckpointError if source == "checkpoint" else ConfigError
    if isinstance(value, Mapping):
        for k, v in value.items():
            if isinstance(k, str) and k.startswith("_") and k.endswith("_"):
                raise error(
                    f"{where}.{k} = {v!r} refused: a building key is not allowed here; the stored config is data"
                )
            check_no_targets(v, f"{where}.{k}", source)
    elif isinstance(value, list | tuple):
        for i, v in enumerate(value):
            check_no_targets(v, f"{where}[{i}]", source)


def resolve(kind: Kind, target: Any, where: str, source: Source) -> type:
    """The registered class named ``target``; from a user's config, its module is imported first if needed."""
    if isinstance(target, str):
        found = _REGISTRY.get(kind, {}).get(target) or _builtin(kind, target)
        if found is not None:
            return found
    if source == "config" and isinstance(target, str) and "." in target:
        module = target.rpartition(".")[0]
        try:
            importlib.import_module(module)
        except ImportError as e:
            raise ConfigError(f"{where}._target_ = {target!r}: cannot import {module!r} ({e})") from e
        if target in _REGISTRY.get(kind, {}):
            return _REGISTRY[kind][target]
    table = {**BUILTINS.get(kind, {}), **_REGISTRY.get(kind, {})}
    allowed = ", ".join(sorted(n for n in table if n.count(".") <= 2)) or "none"
    if source == "checkpoint":
        raise CheckpointError(
            f"{where}._target_ = {target!r} refused: it is not one of the classes a stored config may build "
            f"({allowed}). The file was not loaded; it may be damaged or made to run code."
        )
    raise ConfigError(
        f"{where}._target_ = {target!r} is not a registered {kind} class ({allowed}); decorate your class with "
        f"@dgsdp.registry.register({kind!r}) in the module the _target_ names"
    )


def build(node: Mapping[str, Any], kind: Kind, *, where: str, source: Source = "config", **extra: Any) -> Any:
    """Build the object a config node describes: ``_target_`` names a registered class of ``kind``, the other
    keys are its keyword arguments, ``extra`` adds or replaces keyword arguments. ``_partial_: true`` returns a
    ``functools.partial`` (optimisers, which get their parameters later). Nested nodes are passed as plain dicts
    (the class builds its own parts through this function).

    From a checkpoint (``source="checkpoint"``), a key the class lists in its ``legacy_settings`` (a class
    attribute: setting -> the value runs used before the setting existed) and the stored node lacks gets that
    value, not the constructor's default."""
    error = CheckpointError if source == "checkpoint" else ConfigError
    if not isinstance(node, Mapping):
        raise error(f"{where} must be a mapping with a _target_, got {type(node).__name__}")
    data = dict(node)
    check_plain(data, where, source)
    if "_target_" not in data:
        raise error(f"{where} has no _target_; it does not say which class to build")
    for key in data:
        if key.startswith("_") and key.endswith("_") and key not in _SPECIAL_KEYS:
            raise error(f"{where}.{key}: unknown building key; only {', '.join(sorted(_SPECIAL_KEYS))} are allowed")
    cls = resolve(kind, data.pop("_target_"), where, source)
    if source == "checkpoint":  # settings added since the run was trained: the value that run used
        for key, value in getattr(cls, "legacy_settings", {}).items():
            data.setdefault(key, value)
    partial = bool(data.pop("_partial_", False))
    data.pop("_recursive_", None)
    data.pop("_convert_", None)
    for key, value in data.items():
        nested_kind = _NESTED_KINDS.get(key)
        if nested_kind and isinstance(value, Mapping) and "_target_" in value:
            resolve(nested_kind, value["_target_"], f"{where}.{key}", source)
            for k2, v2 in value.items():
                if k2 != "_target_":
                    check_no_targets(v2, f"{where}.{key}.{k2}", source)
        else:
            check_no_targets(value, f"{where}.{key}", source)
    data.update(extra)
    if partial:
        return functools.partial(cls, **data)
    try:
        return cls(**data)
    except TypeError as e:
        raise error(f"{where}: {cls.__name__} cannot be built from these settings ({e})") from e
