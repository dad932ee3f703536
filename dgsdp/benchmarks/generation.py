"""Benchmark of generation speed: seconds of compute per second of dance.

``python -m dgsdp.benchmarks.generation`` builds random-init denoisers of the small (conf/model/small.yaml) and
paper (conf/model/paper.yaml, Jukebox 4800-d music, 512-d style) sizes and times long-form DDIM sampling with
classifier-free guidance (2 denoiser passes per step) on CPU, and on CUDA when available (optionally under bf16
autocast). It prints one table row per model, device and precision.
"""

from __future__ import annotations

import argparse
import dataclasses
import tempfile
import time
from dataclasses import dataclass

import torch

from dgsdp.generation import DanceGenerator
from dgsdp.sampling import GuidanceSettings, SamplingSettings
from dgsdp.trained import TrainedModel
from dgsdp.trained.spec import RunSpec

# Music and style sizes of each benchmarked model: small runs on the 35-d librosa features with one-hot
# genres; paper is EDGE/DGSDP's size with Jukebox features and CLIP-sized style vectors.
SIZES = {"small": {"audio_dim": 35, "style_dim": 10}, "paper": {"audio_dim": 4800, "style_dim": 512}}
FPS = 30


@dataclass
class Timing:
    model: str
    device: str
    precision: str
    n_params_m: float
    dance_seconds: float
    compute_seconds: float

    @property
    def seconds_per_second(self) -> float:
        return self.compute_seconds / self.dance_seconds


def build_model(size: str) -> TrainedModel:
    """A random-init model of conf/model/<size>.yaml with the music/style sizes of :data:`SIZES`."""
    dims = SIZES[size]
    spec = RunSpec.from_groups(model=size, audio_dim=dims["audio_dim"], style_dim=dims["style_dim"])
    return TrainedModel(spec).eval()


def student_of(model: TrainedModel) -> TrainedModel:
    """A guidance-distilled student of ``model``'s architecture (its weights, the guidance projection at zero:
    the speed of a trained one)."""
    spec = dataclasses.replace(model.spec, model={**model.spec.model, "guidance_inputs": 1})
    student = TrainedModel(spec, source="checkpoint")
    missing, unexpected = student.load_state_dict(model.state_dict(), strict=False)
    if unexpected or any("guidance_proj" not in k for k in missing):
        raise RuntimeError(f"the student does not fit the model: missing {missing}, extra {unexpected}")
    return student.eval()


def time_generation(size: str, device: str, *, seconds: float, steps: int, bf16: bool, repeats: int = 1) -> Timing:
    """Time long-form DDIM sampling of ``seconds`` of dance (best of ``repeats``, after one warm-up step)."""
    model = build_model(size).to(device)
    dims = SIZES[size]
    n = int(round(seconds * FPS))
    music = torch.randn(n, dims["audio_dim"], device=device)
    style = torch.randn(dims["style_dim"], device=device)
    generator = DanceGenerator(model, cache_dir=tempfile.mkdtemp(prefix="dgsdp-bench-"), device=device)

    def run(n_steps: int) -> float:
        sampling = SamplingSettings(
            method="ddim", steps=n_steps, guidance=GuidanceSettings(music=2.0, style=1.0, longform_ramp_fraction=0.0),
            bf16=bf16,
        )  # fmt: skip
        if device == "cuda":
            torch.cuda.synchronize()
        start = time.perf_counter()
        generator.generate(n, music=music, style=style, sampling=sampling, seed=0)
        if device == "cuda":
            torch.cuda.synchronize()
        return time.perf_counter() - start

    run(1)  # warm-up (allocations, kernels)
    best = min(run(steps) for _ in range(repeats))
    n_params = sum(p.numel() for p in model.denoiser.parameters()) / 1e6
    return Timing(size, device, "bf16" if bf16 else "fp32", n_params, seconds, best)


def print_table(rows: list[Timing], steps: int) -> None:
    print(f"DDIM {steps} steps, guidance w=2 (2 denoiser passes per step), long-form windows of 5 s, stride 2.5 s")
    header = f"{'model':<7} {'params':>8} {'device':<6} {'prec':<5} {'dance s':>8} {'compute s':>10} {'s per s':>8}"
    print(header)
    print("-" * len(header))
    for r in rows:
        print(
            f"{r.model:<7} {r.n_params_m:>7.1f}M {r.device:<6} {r.precision:<5} {r.dance_seconds:>8.1f} "
            f"{r.compute_seconds:>10.2f} {r.seconds_per_second:>8.3f}"
        )


def main(argv: list[str] | None = None) -> list[Timing]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", nargs="+", default=["small", "paper"], choices=sorted(SIZES))
    parser.add_argument("--seconds", type=float, default=10.0, help="length of the dance (seconds)")
    parser.add_argument("--steps", type=int, default=50, help="DDIM sampling steps")
    parser.add_argument("--devices", nargs="+", default=None, help="default: cpu, and cuda when available")
    parser.add_argument("--bf16", action="store_true", help="also time bf16 autocast on CUDA")
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (torch.set_num_threads)")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    devices = args.devices or (["cpu", "cuda"] if torch.cuda.is_available() else ["cpu"])
    torch.manual_seed(0)
    rows = []
    for size in args.models:
        for device in devices:
            precisions = [False, True] if (device == "cuda" and args.bf16) else [False]
            for bf16 in precisions:
                rows.append(
                    time_generation(
                        size, device, seconds=args.seconds, steps=args.steps, bf16=bf16, repeats=args.repeats
                    )
                )
    print_table(rows, args.steps)
    return rows


if __name__ == "__main__":
    main()
