"""``python -m dgsdp.sweep <table>``: train and evaluate one paper table (see :mod:`dgsdp.cli.sweep`)."""

from dgsdp.cli.sweep import launch, main

__all__ = ["launch", "main"]

if __name__ == "__main__":
    main()
