"""Peak memory of dancing one long song: ``python -m dgsdp.benchmarks.memory [--seconds 300] [--size paper]``.

Builds a random-init model of conf/model/<size>.yaml (random 4800-d features in place of Jukebox's for ``paper``;
memory does not depend on the weights), dances one song of ``--seconds`` with the default sampling (or
``--steps``, ``--chunk-size``), and prints the process's peak resident set size from ``resource.getrusage`` (Linux
reports it in KiB), before sampling and in all. ``--student`` dances with a guidance-distilled student of the same
size (docs/distillation.md: one pass per step). Run one setting per process: the peak of a process never goes down.
The last line is ``peak_rss_gib=<x> peak_rss_gb=<y>``.
"""

from __future__ import annotations

import argparse
import resource
import tempfile
import time

import torch

from dgsdp.benchmarks.generation import SIZES, build_model, student_of
from dgsdp.generation import DanceGenerator
from dgsdp.sampling import SamplingSettings

FPS = 30


def peak_rss_bytes() -> int:
    """The peak resident set size of this process so far (Linux: ru_maxrss is in KiB)."""
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(prog="python -m dgsdp.benchmarks.memory", description=__doc__.splitlines()[0])
    parser.add_argument("--seconds", type=float, default=300.0, help="length of the song (seconds)")
    parser.add_argument("--size", choices=sorted(SIZES), default="paper")
    parser.add_argument("--steps", type=int, default=SamplingSettings.steps)
    parser.add_argument("--chunk-size", type=int, default=0, help="sampling.chunk_size (0: all windows at once)")
    parser.add_argument("--student", action="store_true", help="a guidance-distilled student of the same size")
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (torch.set_num_threads)")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    model = build_model(args.size)
    if args.student:
        model = student_of(model)
    dims = SIZES[args.size]
    n = int(round(args.seconds * FPS))
    music = torch.randn(n, dims["audio_dim"], generator=torch.Generator().manual_seed(0))
    style = torch.randn(dims["style_dim"]) if dims["style_dim"] else None
    before = peak_rss_bytes()
    generator = DanceGenerator(model, cache_dir=tempfile.mkdtemp(prefix="dgsdp-bench-"))
    sampling = SamplingSettings(steps=args.steps, chunk_size=args.chunk_size)
    start = time.perf_counter()
    motion = generator.generate(n, music=music, style=style, sampling=sampling, seed=0)
    seconds = time.perf_counter() - start
    peak = peak_rss_bytes()
    who = "student" if args.student else "model"
    print(f"{args.size} {who}, {args.seconds:g} s song ({tuple(motion.shape[1:])}), {args.steps} steps, chunk size "
          f"{args.chunk_size}, {torch.get_num_threads()} threads: sampled in {seconds:.1f} s; peak RSS before "
          f"sampling {before / 2**30:.2f} GiB, in all {peak / 2**30:.2f} GiB ({peak / 1e9:.2f} GB)")  # fmt: skip
    print(f"peak_rss_gib={peak / 2**30:.2f} peak_rss_gb={peak / 1e9:.2f}")
    return {"peak_bytes": float(peak), "before_bytes": float(before), "seconds": seconds}


if __name__ == "__main__":
    main()
