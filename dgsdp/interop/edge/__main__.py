"""``python -m dgsdp.interop.edge`` (console script ``dgsdp-import-edge``): import EDGE's released checkpoint, or
verify an import against EDGE's own code.

    python -m dgsdp.interop.edge import checkpoint.pt edge.ckpt        # EMA weights; --weights model for the raw ones
    python -m dgsdp.interop.edge verify --edge-src EDGE checkpoint.pt   # exits 1 above the tolerance
"""

from __future__ import annotations

import argparse
import logging
import sys

from dgsdp.errors import DgsdpError
from dgsdp.interop.edge.verify import TOLERANCE


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m dgsdp.interop.edge",
        description="Import EDGE's released checkpoint as a dgsdp checkpoint, or verify an import against EDGE's code.",
    )
    sub = p.add_subparsers(dest="command", required=True)
    imp = sub.add_parser("import", help="write EDGE's checkpoint as a dgsdp checkpoint")
    imp.add_argument("edge_ckpt", help="EDGE's checkpoint.pt")
    imp.add_argument("out", help="the dgsdp checkpoint to write (e.g. edge.ckpt)")
    imp.add_argument("--weights", choices=("ema", "model"), default="ema", help="EDGE's EMA weights (default) or raw")
    imp.add_argument(
        "--floor-height", type=float, default=None,
        help="the floor of EDGE's data, z-up metres (default: measured on the model's own unconditional dances)",
    )  # fmt: skip
    ver = sub.add_parser("verify", help="compare the import with EDGE's own code on the same inputs and noise")
    ver.add_argument("edge_ckpt", help="EDGE's checkpoint.pt")
    ver.add_argument("--edge-src", required=True, help="a checkout of EDGE's repository (Stanford-TML/EDGE)")
    ver.add_argument("--weights", choices=("ema", "model"), default="ema")
    ver.add_argument("--windows", type=int, default=4, help="windows of the long-form sample (default 4)")
    ver.add_argument("--seed", type=int, default=0)
    ver.add_argument("--tolerance", type=float, default=TOLERANCE)
    return p


def main(argv: list[str] | None = None) -> int:
    args = parser().parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(message)s")
    try:
        if args.command == "import":
            from dgsdp.interop.edge.convert import import_edge

            out = import_edge(args.edge_ckpt, args.out, weights=args.weights, floor_height=args.floor_height)
            print(f"wrote {out}")
            print(
                f"next: python generate.py checkpoint={out} music=<song or folder>   (EDGE's own sampling: add sampling=edge)"
            )
            return 0
        from dgsdp.interop.edge.verify import verify

        result = verify(args.edge_src, args.edge_ckpt, n_windows=args.windows, seed=args.seed, weights=args.weights)
        print(f"max_abs_diff={result.max_abs_diff:.3g} denoiser_max_abs_diff={result.denoiser_max_abs_diff:.3g}")
        return 0 if result.passed(args.tolerance) else 1
    except DgsdpError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    sys.exit(main())
