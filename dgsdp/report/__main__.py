"""``python -m dgsdp.report <sweep dir | run dirs | results.json ...> [--out DIR] [--no-plots] [--wandb auto|on|off]``."""

from __future__ import annotations

import argparse
from pathlib import Path

from dgsdp.errors import DgsdpError
from dgsdp.report import table_markdown, write_report


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(prog="python -m dgsdp.report", description=__doc__)
    parser.add_argument("paths", nargs="+", help="sweep folders, run folders or results.json files")
    parser.add_argument("--out", help="output folder (default: <first path>/report)")
    parser.add_argument("--no-plots", action="store_true", help="skip the bar charts")
    parser.add_argument("--wandb", choices=("auto", "on", "off"), default="auto",
                        help="push the tables to wandb (auto: when the runs were logged there)")  # fmt: skip
    args = parser.parse_args(argv)
    first = Path(args.paths[0]).expanduser()
    out = Path(args.out) if args.out else (first if first.is_dir() else first.parent) / "report"
    try:
        written = write_report(args.paths, out, plots=not args.no_plots, wandb=args.wandb)
    except DgsdpError as e:
        raise SystemExit(f"error: {e}") from None
    for table in written["tables"]:
        print(table_markdown(table))
    print(f"report written: {written['markdown']} {written['csv']}")


if __name__ == "__main__":
    main()
