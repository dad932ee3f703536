"""Speed against EDGE's own code: ``python -m dgsdp.benchmarks.edge --edge-src EDGE_REPO_DIR``.

EDGE's ``DanceDecoder``, ``GaussianDiffusion``, ``SMPLSkeleton`` and ``Adan`` are imported from the checkout you give
(dgsdp ships none of its code), built at the paper size with random weights.

Sampling: the same weights go into dgsdp's denoiser (the EDGE import's mapping). One song of ``--seconds`` of random
music features is danced by EDGE's ``long_ddim_sample`` (DDIM-50, guidance 2 with its ramp, its half-window
overwrite) and by dgsdp with the project's default sampling, with ``sampling=edge``, and with the default under bf16
autocast at 10 and at 5 steps (``sampling.bf16=true``, ``sampling.steps=5``); and by a guidance-distilled student of
the same size (``train.py distill.teacher=...``: one denoiser pass per step instead of two) with the default, 5 steps
and bf16.

Training: one step at ``--batch`` random 5 s windows, as EDGE's ``train_loop`` runs it (its loss with the velocity,
FK and foot terms, backward, Adan step, EMA update) against dgsdp's ``experiment=edge`` model and loss (the same
architecture, loss terms and weights, Adan, EMA), each in float32 and under bf16 autocast (what Lightning's
``trainer.precision=bf16-mixed`` and accelerate's ``mixed_precision=bf16`` do). The bf16 rows, sampling and
training, run only where the CPU has bf16 instructions (AVX512-BF16 or AMX); elsewhere they would take hours. EDGE's FK imports pytorch3d; its
rotation code is pure Python, so a checkout of facebookresearch/pytorch3d on ``PYTHONPATH`` serves (no build). Without
pytorch3d the training figure is n/a.

Repeats are interleaved and the fastest of each is compared. The last line is
``sampling_speedup_vs_edge=<EDGE / dgsdp default> training_speedup_vs_edge_fp32=<EDGE / dgsdp, float32>
[training_speedup_vs_edge_bf16=<EDGE / dgsdp, bf16>] student_sampling_speedup_vs_edge=<EDGE / the student at 5 steps>
(speed only; quality: docs/distillation.md)``: the training headline is float32, what EDGE's own training loop runs,
with bf16 a second figure where the CPU has it, each precision against the same one; the student's figure is the
speed of an untrained student at its 5-step setting, the one docs/distillation.md measured against the default's
quality.
"""

from __future__ import annotations

import argparse
import importlib.util
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import torch

from dgsdp.benchmarks.generation import student_of
from dgsdp.cli.config import compose_config
from dgsdp.generation import DanceGenerator, WindowLayout
from dgsdp.interop.edge.checkpoint import EdgeCheckpoint, EdgeScaler
from dgsdp.interop.edge.convert import build_model
from dgsdp.interop.edge.verify import edge_code, edge_model
from dgsdp.sampling import SamplingSettings
from dgsdp.trained.spec import RunSpec
from dgsdp.utils.device import cpu_has_native_bf16

SIZES = {"paper": {"d": 512, "layers": 8, "ff": 1024}, "small": {"d": 64, "layers": 2, "ff": 128}}
WINDOW, STRIDE = 150, 75
EDGE_SWITCHES = {"rotary_placement": "input", "cross_attention_rotary": True, "null_music": "output"}
PRECISIONS = ("fp32", "bf16")
STUDENT_HEADLINE = "student 5 steps"  # the student's setting whose quality docs/distillation.md compares
STUDENT_LABEL = "(speed only; quality: docs/distillation.md)"  # the student is timed untrained: its speed only


def precisions() -> tuple[str, ...]:
    """The precisions timed here: bf16 only where the CPU has bf16 instructions (elsewhere torch's bf16 products
    are a plain loop, hundreds of times slower: :func:`dgsdp.utils.device.cpu_has_native_bf16`)."""
    return PRECISIONS if cpu_has_native_bf16() else tuple(p for p in PRECISIONS if p != "bf16")


def identity_scaler() -> EdgeScaler:
    """A normaliser that maps [-1, 1] to itself (speed does not depend on it)."""
    ones, zeros = torch.ones(151), torch.zeros(151)
    return EdgeScaler(ones, zeros, -ones, ones, 2 * ones, (-1.0, 1.0), True, 1)


def run_sampling(edge_src: str, *, size: str, features: int, seconds: float, repeats: int) -> dict[str, list[float]]:
    n_frames = int(round(seconds * 30))
    layout = WindowLayout(n_frames, WINDOW, STRIDE)
    with edge_code(edge_src) as (edge, stand_ins):
        torch.manual_seed(0)
        s = SIZES[size]
        theirs, diffusion = edge_model(edge, WINDOW, s["d"], s["ff"], s["layers"], 8, features, 2.0)
        state = theirs.state_dict()
        ours = build_model(EdgeCheckpoint(Path("random"), state, state, identity_scaler()))
        cache = tempfile.mkdtemp(prefix="dgsdp-bench-")
        models = {
            "dgsdp": DanceGenerator(ours, cache_dir=cache),
            "student": DanceGenerator(student_of(ours), cache_dir=cache),
        }
        presets = {
            "dgsdp default": ("dgsdp", SamplingSettings()),
            "dgsdp sampling=edge": ("dgsdp", SamplingSettings.from_config(compose_config("generate", ["sampling=edge"]).sampling)),
            # the CPU switches measured against the default (docs/sampling.md has their quality)
            "dgsdp default, bf16": ("dgsdp", SamplingSettings(bf16=True)),
            "dgsdp 5 steps, bf16": ("dgsdp", SamplingSettings(steps=5, bf16=True)),
            # a guidance-distilled student (docs/distillation.md has its quality)
            "student default": ("student", SamplingSettings()),
            "student 5 steps": ("student", SamplingSettings(steps=5)),
            "student default, bf16": ("student", SamplingSettings(bf16=True)),
        }  # fmt: skip
        if not cpu_has_native_bf16():
            presets = {name: preset for name, preset in presets.items() if not preset[1].bf16}
        times: dict[str, list[float]] = {"edge long_ddim_sample": [], **{name: [] for name in presets}}
        music = torch.randn(layout.n_windows, WINDOW, features, generator=torch.Generator().manual_seed(1))

        def time_edge() -> float:
            start = time.perf_counter()
            with torch.no_grad():
                diffusion.long_ddim_sample((layout.n_windows, WINDOW, 151), music)
            return time.perf_counter() - start

        def time_ours(model: str, settings: SamplingSettings) -> float:
            start = time.perf_counter()
            models[model].generate(n_frames, music=music, sampling=settings, seed=0)
            return time.perf_counter() - start

        for _ in range(repeats):
            times["edge long_ddim_sample"].append(time_edge())
            for name, (model, settings) in presets.items():
                times[name].append(time_ours(model, settings))
    return times


def run_training(edge_src: str, *, size: str, features: int, batch: int, repeats: int) -> dict[str, list[float]]:
    """Seconds per training step of EDGE's code and dgsdp's, in float32 and under bf16 autocast, interleaved."""
    from dgsdp.training.module import DanceDiffusion

    s = SIZES[size]
    steps: dict[str, Callable[[bool], None]] = {}
    with edge_code(edge_src) as (edge, _):
        torch.manual_seed(0)
        theirs, diffusion = edge_model(
            edge, WINDOW, s["d"], s["ff"], s["layers"], 8, features, 2.0, smpl=edge["SMPLSkeleton"]("cpu")
        )
        diffusion.train()
        edge_optim = edge["Adan"](theirs.parameters(), lr=4e-4, weight_decay=0.02)  # EDGE.py's
        spec = RunSpec.from_groups(
            model="paper", audio_dim=features, loss="edge", optimizer="adan", d_model=s["d"], n_layers=s["layers"],
            ff_dim=s["ff"], **EDGE_SWITCHES,
        )  # fmt: skip
        ours = DanceDiffusion(spec).train()
        our_optim = ours.configure_optimizers()
        gen = torch.Generator().manual_seed(1)
        x = torch.rand(batch, WINDOW, 151, generator=gen) * 2 - 1
        music = torch.randn(batch, WINDOW, features, generator=gen)
        data = {"motion": x, "audio": music, "genre": torch.zeros(batch, dtype=torch.long)}

        def edge_step(bf16: bool) -> None:  # EDGE.py's train_loop, ema_interval 1
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                total, _ = diffusion(x, music)
            edge_optim.zero_grad()
            total.backward()
            edge_optim.step()
            diffusion.ema.update_model_average(diffusion.master_model, diffusion.model)

        def our_step(bf16: bool) -> None:  # DanceDiffusion's training_step, optimizer_step and EMA update
            with torch.autocast("cpu", dtype=torch.bfloat16, enabled=bf16):
                loss = ours._loss(ours.denoiser, data, train=True)["loss"]
            loss.backward()
            our_optim.step()
            our_optim.zero_grad(set_to_none=True)
            ours.ema.update_parameters(ours.denoiser)

        for precision in precisions():
            steps[f"edge {precision}"] = edge_step
            steps[f"dgsdp {precision}"] = our_step
        times: dict[str, list[float]] = {name: [] for name in steps}
        for i in range(repeats + 1):  # the first round warms up
            for name, step in steps.items():
                start = time.perf_counter()
                step(name.endswith("bf16"))
                if i:
                    times[name].append(time.perf_counter() - start)
    return times


def _print_times(times: dict[str, list[float]]) -> dict[str, float]:
    best = {name: min(values) for name, values in times.items()}
    for name, values in times.items():
        print(f"  {name:<22} {best[name]:8.2f}   (all: {', '.join(f'{v:.2f}' for v in values)})")
    return best


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(prog="python -m dgsdp.benchmarks.edge", description=__doc__.splitlines()[0])
    parser.add_argument("--edge-src", required=True, help="a checkout of EDGE's repository (Stanford-TML/EDGE)")
    parser.add_argument("--size", choices=sorted(SIZES), default="paper")
    parser.add_argument("--features", type=int, choices=(35, 4800), default=4800, help="music feature width")
    parser.add_argument("--seconds", type=float, default=30.0, help="length of the song (seconds)")
    parser.add_argument("--batch", type=int, default=32, help="training batch (windows)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--parts", nargs="+", choices=("sampling", "training"), default=["sampling", "training"])
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (torch.set_num_threads)")
    args = parser.parse_args(argv)
    if args.threads:
        torch.set_num_threads(args.threads)
    best: dict[str, float] = {}
    setting = f"size {args.size}, {args.features}-d features, {torch.get_num_threads()} threads"
    if not cpu_has_native_bf16():
        print("this CPU has no bf16 instructions (AVX512-BF16 or AMX): the bf16 rows are left out (float32 only)")
    if "sampling" in args.parts:
        times = run_sampling(
            args.edge_src, size=args.size, features=args.features, seconds=args.seconds, repeats=args.repeats
        )
        print(f"sampling: {setting}, {args.seconds:g} s song, {args.repeats} interleaved repeats; fastest of each (s):")
        best.update(_print_times(times))
        edge = best["edge long_ddim_sample"]
        for name in times:
            if not name.startswith("edge"):
                print(f"  {name} vs EDGE's code: {edge / best[name]:.2f}x")
    if "training" in args.parts:
        if importlib.util.find_spec("pytorch3d") is None:
            print("training: n/a: EDGE's training loss imports pytorch3d, which is not importable; its rotation code is "
                  "pure Python, so a checkout of facebookresearch/pytorch3d on PYTHONPATH serves")  # fmt: skip
        else:
            times = run_training(
                args.edge_src, size=args.size, features=args.features, batch=args.batch, repeats=args.repeats
            )
            print(f"training: {setting}, batch {args.batch}, {args.repeats} interleaved repeats after a warm-up; "
                  "seconds per step, fastest of each:")  # fmt: skip
            best.update(_print_times(times))
    print(headline(best))
    return best


def headline(best: dict[str, float]) -> str:
    """The last line from the fastest time of each setting (``best``; a part not run leaves its figures n/a):
    ``sampling_speedup_vs_edge`` (EDGE / dgsdp's default), ``training_speedup_vs_edge_fp32`` (EDGE / dgsdp, both in
    float32, what EDGE's own training loop runs: the headline), ``training_speedup_vs_edge_bf16`` where bf16 was
    timed, and last ``student_sampling_speedup_vs_edge`` (EDGE / the student at 5 steps) with its label: an untrained
    student's speed, whose quality docs/distillation.md measures. Each precision is compared with the same precision,
    never one side's fastest with the other's."""

    def ratio(edge: str, ours: str) -> str:
        return f"{best[edge] / best[ours]:.2f}" if edge in best and ours in best else "n/a"

    parts = [
        f"sampling_speedup_vs_edge={ratio('edge long_ddim_sample', 'dgsdp default')}",
        f"training_speedup_vs_edge_fp32={ratio('edge fp32', 'dgsdp fp32')}",
    ]
    if "edge bf16" in best and "dgsdp bf16" in best:
        parts.append(f"training_speedup_vs_edge_bf16={ratio('edge bf16', 'dgsdp bf16')}")
    parts.append(f"student_sampling_speedup_vs_edge={ratio('edge long_ddim_sample', STUDENT_HEADLINE)} {STUDENT_LABEL}")
    return " ".join(parts)


if __name__ == "__main__":
    main()
