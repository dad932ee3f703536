"""Train a dance diffusion model: python train.py [audio=encodec] [style=prompt] [experiment=table4_row0] ..."""

from dgsdp.cli.runtime import check_command_line
from dgsdp.cli.train import main

if __name__ == "__main__":
    check_command_line()
    main()
