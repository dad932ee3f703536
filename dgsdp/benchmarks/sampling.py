"""Benchmark of sampling speed: the default few-step sampler against DDIM-50, side by side in one run.

``python -m dgsdp.benchmarks.sampling [--size small|paper] [--seconds 30] [--repeats 3]`` builds one random-init
denoiser (conf/model/<size>.yaml; compute does not depend on the weights), makes one song (a synthetic
drum-machine song, librosa features, for ``small``; random 4800-d features in place of Jukebox's for ``paper``)
and times whole-song long-form sampling with classifier-free guidance (w = 2, 2 denoiser passes per step), the
settings timed in interleaved repeats (A B C A B C ...). It prints one row per setting (best and median seconds,
seconds of compute per second of dance from the best) and, as its last line,
``speedup_vs_ddim50=<ratio> default=<sampler>-<steps>``: DDIM-50's best time over the default's, both with
conditioning computed once per run. Best-of-repeats, as ``timeit`` does: on a shared machine other jobs only ever
add time, so the minimum is the least disturbed measurement. The row ``ddim-50 per-step``
is DDIM-50 through the per-step conditioning path, as sampling ran before the conditioning cache.
``--chunk-sizes 0 4 8 16`` also times the default sampler with the long-form windows in chunks of that many.
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from dataclasses import dataclass

import numpy as np
import torch

from dgsdp.benchmarks.generation import SIZES, build_model
from dgsdp.generation import DanceGenerator
from dgsdp.sampling import GuidanceSettings, SamplingSettings, check_method

FPS = 30
DEFAULT_METHOD, DEFAULT_STEPS = SamplingSettings.method, SamplingSettings.steps  # generate.py's default


class PerStepDenoiser(torch.nn.Module):
    """A denoiser seen through the per-step interface only: conditioning recomputed at every step."""

    def __init__(self, inner: torch.nn.Module) -> None:
        super().__init__()
        self.inner = inner

    def forward(self, x_t, t, music=None, style=None, keep_music=None, keep_style=None):
        return self.inner(x_t, t, music, style, keep_music, keep_style)


@dataclass
class Setting:
    name: str
    method: str
    steps: int
    per_step: bool = False
    chunk_size: int = 0
    eta: float = 1.0


def song_features(size: str, seconds: float, seed: int = 0) -> torch.Tensor:
    """Music features (T, Da) of one song at 30 FPS."""
    n = int(round(seconds * FPS))
    dim = SIZES[size]["audio_dim"]
    if dim == 35:
        from dgsdp.audio.librosa_encoder import LibrosaEncoder
        from dgsdp.data.synthetic_music import synthesize_music

        rate = 15360
        audio, _ = synthesize_music("BR", 120.0, seconds, first_beat_s=0.25, sample_rate_hz=rate,
                                    rng=np.random.default_rng(seed))  # fmt: skip
        return torch.from_numpy(LibrosaEncoder().encode(audio, rate, n_frames=n)).float()
    return torch.randn(n, dim, generator=torch.Generator().manual_seed(seed))


def run_benchmark(
    size: str,
    *,
    seconds: float,
    repeats: int,
    default: tuple[str, int],
    chunk_sizes: list[int],
    device: str,
    bf16: bool,
    per_step_baseline: bool = True,
) -> dict[str, list[float]]:
    model = build_model(size).to(device)
    per_step_model = build_model(size).to(device)  # the same architecture, its denoiser called step by step
    per_step_model.ema.module = PerStepDenoiser(per_step_model.ema.module)
    generators = {
        False: DanceGenerator(model, cache_dir=tempfile.mkdtemp(prefix="dgsdp-bench-"), device=device),
        True: DanceGenerator(per_step_model, cache_dir=tempfile.mkdtemp(prefix="dgsdp-bench-"), device=device),
    }
    music = song_features(size, seconds).to(device)
    style = torch.randn(SIZES[size]["style_dim"], generator=torch.Generator().manual_seed(1)).to(device)
    n = music.shape[0]
    method, steps = default
    settings = [Setting("ddim-50", "ddim", 50), Setting(f"{method}-{steps}", method, steps)]
    if per_step_baseline:
        settings.insert(1, Setting("ddim-50 per-step", "ddim", 50, per_step=True))
    settings += [Setting(f"{method}-{steps} chunk {c}", method, steps, chunk_size=c) for c in chunk_sizes]

    def run(s: Setting, steps: int | None = None) -> float:
        sampling = SamplingSettings(
            method=s.method, steps=steps or s.steps, eta=s.eta, guidance=GuidanceSettings(music=2.0, style=1.0),
            chunk_size=s.chunk_size, bf16=bf16,
        )  # fmt: skip
        if device == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        generators[s.per_step].generate(n, music=music, style=style, sampling=sampling, seed=0)
        if device == "cuda":
            torch.cuda.synchronize()
        return time.perf_counter() - start

    for s in settings:  # warm-up: allocations, kernels, rotary tables
        run(s, steps=2)
    times: dict[str, list[float]] = {s.name: [] for s in settings}
    for _ in range(repeats):
        for s in settings:
            times[s.name].append(run(s))
    return times


def main(argv: list[str] | None = None) -> float:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", choices=sorted(SIZES), default="small")
    parser.add_argument("--seconds", type=float, default=30.0, help="length of the song (seconds)")
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--method", default=DEFAULT_METHOD, help="the default sampler")
    parser.add_argument("--steps", type=int, default=DEFAULT_STEPS, help="its steps")
    parser.add_argument("--chunk-sizes", type=int, nargs="*", default=[], help="also time these chunk sizes")
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--bf16", action="store_true", help="bf16 autocast (CUDA)")
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (torch.set_num_threads)")
    parser.add_argument("--no-per-step", action="store_true", help="skip the per-step DDIM-50 row")
    args = parser.parse_args(argv)
    check_method(args.method)
    if args.threads:
        torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    times = run_benchmark(
        args.size, seconds=args.seconds, repeats=args.repeats, default=(args.method, args.steps),
        chunk_sizes=args.chunk_sizes, device=args.device, bf16=args.bf16, per_step_baseline=not args.no_per_step,
    )  # fmt: skip
    precision = "bf16" if args.bf16 else "fp32"
    print(f"model {args.size}, {args.device} {precision}, {torch.get_num_threads()} threads, {args.seconds:g} s song "
          f"(long-form, 5 s windows 2.5 s apart), guidance w=2, {args.repeats} interleaved repeats")  # fmt: skip
    header = f"{'setting':<28} {'best s':>8} {'median s':>9} {'s per s':>8}"
    print(header)
    print("-" * len(header))
    for name, ts in times.items():
        print(f"{name:<28} {min(ts):>8.3f} {statistics.median(ts):>9.3f} {min(ts) / args.seconds:>8.4f}")
    default = f"{args.method}-{args.steps}"
    ratio = min(times["ddim-50"]) / min(times[default])
    if "ddim-50 per-step" in times:
        per_step = min(times["ddim-50 per-step"]) / min(times[default])
        print(f"speedup over per-step DDIM-50 (sampling before the conditioning cache): {per_step:.2f}")
    print(f"speedup_vs_ddim50={ratio:.2f} default={default}")
    return ratio


if __name__ == "__main__":
    main()
