"""Evaluate a checkpoint under a paper-table protocol: python evaluate.py checkpoint=<ckpt> protocol=table1 ..."""

from dgsdp.cli.evaluate import main

if __name__ == "__main__":
    main()
