"""Benchmark of the synthetic AIST++ generator.

``python -m dgsdp.benchmarks.synthetic`` writes the default synthetic dataset (10 genres x 8 dances of 16 s and one
ignored take, as ``python train.py`` does on first use) into a temporary folder and prints the wall-clock time,
the dances and the seconds of dance and music made per wall-clock second, then the time of a second call that
finds the complete dataset and reuses it, as a ratio against the first. Target: the default dataset in under a
minute on 2 CPU cores.
"""

from __future__ import annotations

import argparse
import tempfile
import time
from pathlib import Path

from dgsdp.data.synthetic import generate_synthetic_aistpp, read_manifest

TARGET_SECONDS = 60.0


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sequences-per-genre", type=int, default=8)
    parser.add_argument("--seconds", type=float, default=16.0, help="length of each dance and its music")
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    settings = dict(seed=args.seed, sequences_per_genre=args.sequences_per_genre, seconds=args.seconds)

    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp) / "synthetic"
        start = time.perf_counter()
        generate_synthetic_aistpp(root, **settings)
        first = time.perf_counter() - start
        manifest = read_manifest(root)
        n_dances, n_songs = len(manifest["sequences"]), len(manifest["music"])
        size_mb = sum(p.stat().st_size for p in root.rglob("*") if p.is_file()) / 1e6
        print(
            f"generation: {n_dances} dances and {n_songs} songs of {args.seconds:.0f} s ({size_mb:.0f} MB) in "
            f"{first:.1f} s: {n_dances / first:.1f} dances/s, {n_dances * args.seconds / first:.0f} dance s/s, "
            f"{n_songs * args.seconds / first:.0f} music s/s (target: under {TARGET_SECONDS:.0f} s for the default; "
            f"{'met' if first < TARGET_SECONDS else 'missed'})"
        )
        start = time.perf_counter()
        generate_synthetic_aistpp(root, **settings)
        again = time.perf_counter() - start
        print(f"reuse of the complete dataset: {again * 1e3:.1f} ms ({first / max(again, 1e-9):.0f}x faster)")


if __name__ == "__main__":
    main()
