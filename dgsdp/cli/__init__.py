"""Entry points (train, generate, evaluate) behind the thin root scripts."""
