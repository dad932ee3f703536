"""Config helpers shared by the entry points: where the configs live, composing them, and checking them."""

from __future__ import annotations

import contextlib
from collections.abc import Iterator, Sequence
from pathlib import Path
from typing import Any

from hydra.core.config_store import ConfigStore
from omegaconf import DictConfig, OmegaConf, open_dict, read_write

from dgsdp.cli.schema import register_schemas
from dgsdp.errors import ConfigError
from dgsdp.resources import CONFIG_DIR, CONFIG_MODULE, CONFIG_PATH, register_resolvers  # noqa: F401 (re-exported)

register_resolvers()
register_schemas()

if not OmegaConf.has_resolver("dgsdp_precision"):  # conf/trainer/ddp.yaml: bf16-mixed on GPUs, 32-true on CPUs
    from dgsdp.training.distributed import precision_for

    OmegaConf.register_new_resolver("dgsdp_precision", precision_for)


GENERATE_CONFIG_FILE = CONFIG_DIR / "generate.yaml"
# Name in Hydra's config store of conf/generate.yaml with the groups it uses (paths, hydra) merged in. Generate's
# only search path is that store: the training groups of conf/ (style, audio, model, ...) stay out of it, so that
# ``style=krump`` is a plain value here, not a group choice.
GENERATE_CONFIG_NAME = "dgsdp_generate"


@contextlib.contextmanager
def generate_configs() -> Iterator[None]:
    """While inside: conf/generate.yaml and every option of the groups it uses (paths, hydra, sampling) are in
    Hydra's config store, generate's only search path (so that the training groups, style among them, stay out
    of it and ``style=krump`` is a plain value). Removed afterwards, so that they do not shadow the same files
    when the train or evaluate configs are composed in the same process."""
    store = ConfigStore.instance()
    node = OmegaConf.load(GENERATE_CONFIG_FILE)
    added: list[tuple[str | None, str]] = []
    for entry in node.get("defaults", []):
        if isinstance(entry, str):  # _self_
            continue
        for group in entry:
            for option in (CONFIG_DIR / group).glob("*.yaml"):
                store.store(group=group, name=option.stem, node=OmegaConf.load(option))
                added.append((group, f"{option.stem}.yaml"))
    store.store(name=GENERATE_CONFIG_NAME, node=node)
    added.append((None, f"{GENERATE_CONFIG_NAME}.yaml"))
    try:
        yield
    finally:
        for group, name in added:
            (store.repo.get(group, {}) if group else store.repo).pop(name, None)


_composed: list[Any] = [None]  # the HydraConfig that compose_config set last (not a running app's)


@contextlib.contextmanager
def _hydra_runtime(cfg: DictConfig) -> Iterator[None]:
    """Make ``${hydra:...}`` resolvable against ``cfg.hydra`` for the duration of the block. A running Hydra app's
    own config is put back afterwards; outside an app (a script, a notebook, a test) the composed run's values stay
    readable, as they would be in the app."""
    from hydra.core.hydra_config import HydraConfig

    saved = HydraConfig.instance().cfg
    HydraConfig.instance().set_config(cfg)
    try:
        yield
    finally:
        if saved is not None and saved is not _composed[0]:  # inside a running Hydra app: its own config again
            HydraConfig.instance().cfg = saved
        else:
            _composed[0] = HydraConfig.instance().cfg


@contextlib.contextmanager
def _outside_running_hydra() -> Iterator[None]:
    """Inside a running Hydra job (a sweep's job in a joblib worker, which gets the launcher's global state) Hydra's
    global instance is set, and ``initialize`` refuses to set it again: it is set aside for the block and put back
    afterwards."""
    from hydra.core.global_hydra import GlobalHydra
    from hydra.core.singleton import Singleton

    running = Singleton._instances.get(GlobalHydra)
    if running is None or not running.is_initialized():
        yield
        return
    del Singleton._instances[GlobalHydra]
    try:
        yield
    finally:
        Singleton._instances[GlobalHydra] = running


def compose_config(
    config_name: str = "train", overrides: Sequence[str] = (), output_dir: str | Path | None = None
) -> DictConfig:
    """Compose ``train``, ``generate`` or ``evaluate`` with command-line style overrides, as the entry point
    would, fully resolved. ``output_dir`` stands for the run folder Hydra would create (``paths.output_dir``).

    Safe inside a running Hydra job (evaluation after training, also in a sweep's worker process): Hydra's global
    state is set aside for the composition and put back, and the job's HydraConfig is left as it was."""
    from hydra import compose, initialize, initialize_config_module

    with _outside_running_hydra():
        if config_name == "generate":
            with generate_configs(), initialize(version_base="1.3", config_path=None):
                cfg = compose(GENERATE_CONFIG_NAME, overrides=list(overrides), return_hydra_config=True)
        else:
            with initialize_config_module(CONFIG_MODULE, version_base="1.3"):
                cfg = compose(config_name, overrides=list(overrides), return_hydra_config=True)
    with read_write(cfg), open_dict(cfg):
        cfg.hydra.runtime.output_dir = str(output_dir) if output_dir is not None else cfg.hydra.run.dir
    with _hydra_runtime(cfg):
        with read_write(cfg), open_dict(cfg):
            del cfg["hydra"]  # as in a Hydra app: the task's config has no hydra node
        OmegaConf.resolve(cfg)
    return cfg


def as_list(value: Any) -> list[Any] | None:
    """A config value that may be one item or a list, as a plain list (None stays None)."""
    if value is None:
        return None
    if isinstance(value, str | int | float):
        return [value]
    return list(OmegaConf.to_container(value) if OmegaConf.is_config(value) else value)


def option_names(group: str) -> list[str]:
    """The options of a config group (e.g. ``protocol``: table1, table2, ...)."""
    return sorted(p.stem for p in (CONFIG_DIR / group).glob("*.yaml"))


def check_options(group: str, names: Sequence[Any], key: str) -> None:
    """Raise a ConfigError unless every name is an option of ``group``."""
    options = option_names(group)
    bad = [str(n) for n in names if str(n) not in options]
    if bad:
        raise ConfigError(f"{key}: {', '.join(map(repr, bad))} is not one of {', '.join(options)}")
