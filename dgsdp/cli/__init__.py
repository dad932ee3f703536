"""Entry points (train, generate, evaluate) behind the thin root scripts."""

from dgsdp.cli import runtime as _runtime  # noqa: F401 - registers the resolvers conf/hydra uses
