"""Sampling speed against EDGE's own code: ``python -m dgsdp.benchmarks.edge --edge-src EDGE_REPO_DIR``.

EDGE's ``DanceDecoder`` and ``GaussianDiffusion`` are imported from the checkout you give (dgsdp ships none of its
code), built at the paper size with random weights, and the same weights go into dgsdp's denoiser (the EDGE
import's mapping). One song of ``--seconds`` of random music features is danced by EDGE's ``long_ddim_sample``
(DDIM-50, guidance 2 with its ramp, its half-window overwrite) and by dgsdp with the project's default sampling and
with ``sampling=edge``; repeats are interleaved and the fastest of each is compared. The last line is
``sampling_speedup_vs_edge=<EDGE / dgsdp default> training_speedup_vs_edge=<x or n/a>``.

EDGE's training step computes its FK loss with pytorch3d; where pytorch3d is not installed it cannot run, and the
training figure is printed as n/a with the reason.
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
import time
from pathlib import Path

import torch

from dgsdp.cli.config import compose_config
from dgsdp.generation import DanceGenerator, WindowLayout
from dgsdp.interop.edge.checkpoint import EdgeCheckpoint, EdgeScaler
from dgsdp.interop.edge.convert import build_model
from dgsdp.interop.edge.verify import edge_code, edge_model
from dgsdp.sampling import SamplingSettings

SIZES = {"paper": {"d": 512, "layers": 8, "ff": 1024}, "small": {"d": 64, "layers": 2, "ff": 128}}
WINDOW, STRIDE = 150, 75


def identity_scaler() -> EdgeScaler:
    """A normaliser that maps [-1, 1] to itself (speed does not depend on it)."""
    ones, zeros = torch.ones(151), torch.zeros(151)
    return EdgeScaler(ones, zeros, -ones, ones, 2 * ones, (-1.0, 1.0), True, 1)


def run(edge_src: str, *, size: str, features: int, seconds: float, repeats: int) -> dict[str, list[float]]:
    n_frames = int(round(seconds * 30))
    layout = WindowLayout(n_frames, WINDOW, STRIDE)
    times: dict[str, list[float]] = {"edge long_ddim_sample": [], "dgsdp default": [], "dgsdp sampling=edge": []}
    with edge_code(edge_src) as (edge, stand_ins):
        torch.manual_seed(0)
        s = SIZES[size]
        theirs, diffusion = edge_model(edge, WINDOW, s["d"], s["ff"], s["layers"], 8, features, 2.0)
        state = theirs.state_dict()
        ours = build_model(EdgeCheckpoint(Path("random"), state, state, identity_scaler()))
        generator = DanceGenerator(ours, cache_dir=tempfile.mkdtemp(prefix="dgsdp-bench-"))
        presets = {
            "dgsdp default": SamplingSettings(),
            "dgsdp sampling=edge": SamplingSettings.from_config(compose_config("generate", ["sampling=edge"]).sampling),
        }
        music = torch.randn(layout.n_windows, WINDOW, features, generator=torch.Generator().manual_seed(1))

        def time_edge() -> float:
            start = time.perf_counter()
            with torch.no_grad():
                diffusion.long_ddim_sample((layout.n_windows, WINDOW, 151), music)
            return time.perf_counter() - start

        def time_ours(settings: SamplingSettings) -> float:
            start = time.perf_counter()
            generator.generate(n_frames, music=music, sampling=settings, seed=0)
            return time.perf_counter() - start

        for _ in range(repeats):
            times["edge long_ddim_sample"].append(time_edge())
            for name, settings in presets.items():
                times[name].append(time_ours(settings))
    return times


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(prog="python -m dgsdp.benchmarks.edge", description=__doc__.splitlines()[0])
    parser.add_argument("--edge-src", required=True, help="a checkout of EDGE's repository (Stanford-TML/EDGE)")
    parser.add_argument("--size", choices=sorted(SIZES), default="paper")
    parser.add_argument("--features", type=int, choices=(35, 4800), default=4800, help="music feature width")
    parser.add_argument("--seconds", type=float, default=30.0, help="length of the song (seconds)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (torch.set_num_threads)")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    times = run(args.edge_src, size=args.size, features=args.features, seconds=args.seconds, repeats=args.repeats)
    best = {name: min(values) for name, values in times.items()}
    print(f"size {args.size}, {args.features}-d features, {args.seconds:g} s song, {torch.get_num_threads()} threads, "
          f"{args.repeats} interleaved repeats; fastest of each (s):")  # fmt: skip
    for name, values in times.items():
        print(f"  {name:<22} {best[name]:8.2f}   (all: {', '.join(f'{v:.2f}' for v in values)})")
    edge = best["edge long_ddim_sample"]
    print(f"  dgsdp sampling=edge vs EDGE's code: {edge / best['dgsdp sampling=edge']:.2f}x")
    training = "n/a"
    if importlib.util.find_spec("pytorch3d") is None:
        training += " (EDGE's training loss needs pytorch3d, which is not installed)"
    print(f"sampling_speedup_vs_edge={edge / best['dgsdp default']:.2f} training_speedup_vs_edge={training}")
    return best


if __name__ == "__main__":
    main()
