"""Generate dances: python generate.py checkpoint=<ckpt> music=<file|folder|list> style=<genre|text|schedule> ..."""

from dgsdp.cli.generate import main
from dgsdp.cli.runtime import check_command_line

if __name__ == "__main__":
    check_command_line()
    main()
