"""Evaluate a checkpoint under a paper-table protocol: python evaluate.py checkpoint=<ckpt> protocol=table1 ..."""

from dgsdp.cli.evaluate import main
from dgsdp.cli.runtime import check_command_line

if __name__ == "__main__":
    check_command_line()
    main()
