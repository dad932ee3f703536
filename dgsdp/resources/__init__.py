"""Files that ship inside the package, and the working folder that everything a run writes goes under.

Shipped with the package (read through :mod:`importlib.resources`, so they are found in a source checkout and in an
installed wheel alike):

- ``dgsdp/conf/``: the Hydra configs (search path ``pkg://dgsdp.conf``);
- ``dgsdp/sweeps/``: one multirun file per paper table;
- ``dgsdp/resources/``: the official AIST++ split lists (``aistpp_splits/``), FineDance's official split lists and
  genres (``finedance/``), the style description prompts (``style_prompts/``), the held-out style descriptions
  (``style_heldout/``) and the papers' published numbers (``paper_tables.yaml``).

Datasets, caches and run outputs never go inside the package: they go under the working folder,
:func:`home` (``$DGSDP_HOME`` when set, else the current folder), as ``data/``, ``data/cache/`` and ``outputs/``.
"""

from __future__ import annotations

import os
from importlib.resources import files
from pathlib import Path

from omegaconf import OmegaConf

from dgsdp.errors import ConfigError

CONFIG_MODULE = "dgsdp.conf"
CONFIG_PATH = f"pkg://{CONFIG_MODULE}"  # Hydra's search path of the shipped configs
HOME_ENV = "DGSDP_HOME"


def shipped(name: str) -> Path:
    """A folder or file shipped inside the dgsdp package (``conf``, ``sweeps``, ``resources``), on disk."""
    path = files("dgsdp").joinpath(name)
    if not isinstance(path, Path):  # a zipped install: Hydra and the readers below need real files
        raise ConfigError(f"dgsdp/{name} is not on disk ({path}); install dgsdp unzipped (pip install)")
    return path


CONFIG_DIR = shipped("conf")
SWEEPS_DIR = shipped("sweeps")
RESOURCES_DIR = shipped("resources")
AISTPP_SPLITS_DIR = RESOURCES_DIR / "aistpp_splits"
STYLE_PROMPTS_FILE = RESOURCES_DIR / "style_prompts" / "aistpp.yaml"
FINEDANCE_DIR = RESOURCES_DIR / "finedance"  # split lists, ignore lists, genres.yaml, genre_aliases.yaml
FINEDANCE_PROMPTS_FILE = RESOURCES_DIR / "style_prompts" / "finedance.yaml"
FINEDANCE_HELDOUT_FILE = RESOURCES_DIR / "style_heldout" / "finedance.yaml"
PAPER_TABLES_FILE = RESOURCES_DIR / "paper_tables.yaml"


def home() -> Path:
    """The working folder: ``$DGSDP_HOME`` if set, else the current folder (absolute)."""
    value = os.environ.get(HOME_ENV, "").strip()
    return Path(value).expanduser().resolve() if value else Path.cwd()


def register_resolvers() -> None:
    """``${dgsdp_home:}`` in configs: the working folder (see :func:`home`), resolved when the config is read."""
    if not OmegaConf.has_resolver("dgsdp_home"):
        OmegaConf.register_new_resolver("dgsdp_home", lambda: str(home()))


def default_log_dir() -> Path:
    """``paths.log_dir`` of the shipped ``paths`` config (``<working folder>/outputs``)."""
    register_resolvers()
    paths = OmegaConf.load(CONFIG_DIR / "paths" / "default.yaml")
    return Path(OmegaConf.create({"paths": paths}).paths.log_dir)


register_resolvers()
