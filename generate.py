"""Generate dances: python generate.py checkpoint=<ckpt> music=<file|folder|list> style=<genre|text|schedule> ..."""

from dgsdp.cli.generate import main

if __name__ == "__main__":
    main()
