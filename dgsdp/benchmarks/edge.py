"""Speed against EDGE's own code: ``python -m dgsdp.benchmarks.edge --edge-src EDGE_REPO_DIR [--device cpu|cuda]``.

EDGE's ``DanceDecoder``, ``GaussianDiffusion``, ``SMPLSkeleton`` and ``Adan`` are imported from the checkout you give
(dgsdp ships none of its code), built at the paper size with random weights. Everything (both models, the music,
sampling, the training step) runs on ``--device``: ``cuda`` where torch sees a GPU, else ``cpu``.

Sampling: the same weights go into dgsdp's denoiser (the EDGE import's mapping). One song of ``--seconds`` of random
music features is danced by EDGE's ``long_ddim_sample`` (DDIM-50, guidance 2 with its ramp, its half-window
overwrite) and by dgsdp with the project's default sampling, with ``sampling=edge``, and with the default under bf16
autocast at 10 and at 5 steps (``sampling.bf16=true``, ``sampling.steps=5``); and by a guidance-distilled student of
the same size (``train.py distill.teacher=...``: one denoiser pass per step instead of two) with the default, 5 steps
and bf16.

Training: one step at ``--batch`` random 5 s windows, as EDGE's ``train_loop`` runs it (its loss with the velocity,
FK and foot terms, backward, Adan step, EMA update) against dgsdp's ``experiment=edge`` model and loss (the same
architecture, loss terms and weights, Adan, EMA), each in float32 and under bf16 autocast (what Lightning's
``trainer.precision=bf16-mixed`` and accelerate's ``mixed_precision=bf16`` do). On a CPU the bf16 rows, sampling and
training, run only where the CPU has bf16 instructions (AVX512-BF16 or AMX); elsewhere they would take hours. EDGE's FK imports pytorch3d; its
rotation code is pure Python, so a checkout of facebookresearch/pytorch3d on ``PYTHONPATH`` serves (no build). Without
pytorch3d the training figure is n/a.

On a GPU (``--device cuda``) the defaults are a 3-minute song and batch 128 (DGSDP's), float32 matrix products run on
TF32 tensor cores for both codes (``torch.set_float32_matmul_precision("high")``, as dgsdp's training sets it), each
timing is bracketed by ``torch.cuda.synchronize``, one untimed round warms up first, and bf16 is timed on both sides:
EDGE's ``long_ddim_sample`` under bf16 autocast too, and the student at 5 steps in bf16, so each precision is compared
with the same one. The ``mfu`` part (on by default there) prints the model FLOPs utilisation of a training step of the
paper model, as ``python -m dgsdp.benchmarks.training --device cuda --models paper`` measures it.

Repeats are interleaved and the fastest of each is compared. The last line is
``sampling_speedup_vs_edge=<EDGE / dgsdp default> [sampling_speedup_vs_edge_bf16=<both in bf16>]
training_speedup_vs_edge_fp32=<EDGE / dgsdp, float32> [training_speedup_vs_edge_bf16=<EDGE / dgsdp, bf16>]
student_sampling_speedup_vs_edge=<EDGE / the student at 5 steps> [student_sampling_speedup_vs_edge_bf16=<both in
bf16>] (speed only; quality: docs/distillation.md)``: the training headline is float32, what EDGE's own training loop
runs, with bf16 a second figure where it was timed, each precision against the same one; the student's figure is the
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
from dgsdp.training.optim import ema_update
from dgsdp.utils.device import cpu_has_native_bf16

SIZES = {"paper": {"d": 512, "layers": 8, "ff": 1024}, "small": {"d": 64, "layers": 2, "ff": 128}}
WINDOW, STRIDE = 150, 75
EDGE_SWITCHES = {"rotary_placement": "input", "cross_attention_rotary": True, "null_music": "output"}
PRECISIONS = ("fp32", "bf16")
DEVICES = ("cpu", "cuda")
DEFAULT_SECONDS = {"cpu": 30.0, "cuda": 180.0}  # a 3-minute song on a GPU
DEFAULT_BATCH = {"cpu": 32, "cuda": 128}  # DGSDP's batch on a GPU
PARTS = ("sampling", "training", "mfu")
EDGE_SAMPLING = "edge long_ddim_sample"
EDGE_SAMPLING_BF16 = "edge long_ddim_sample, bf16"  # timed on a GPU
STUDENT_HEADLINE = "student 5 steps"  # the student's setting whose quality docs/distillation.md compares
STUDENT_LABEL = "(speed only; quality: docs/distillation.md)"  # the student is timed untrained: its speed only


def default_device() -> str:
    """``cuda`` where torch sees a GPU, else ``cpu``."""
    return "cuda" if torch.cuda.is_available() else "cpu"


def precisions(device: torch.device | str = "cpu") -> tuple[str, ...]:
    """The precisions timed on ``device``: both on a GPU; on a CPU bf16 only where it has bf16 instructions
    (elsewhere torch's bf16 products are a plain loop, hundreds of times slower:
    :func:`dgsdp.utils.device.cpu_has_native_bf16`)."""
    if torch.device(device).type == "cuda" or cpu_has_native_bf16():
        return PRECISIONS
    return tuple(p for p in PRECISIONS if p != "bf16")


def sync(device: torch.device) -> None:
    """Wait for the device's queued work (a GPU runs asynchronously: a timing must include all of its work)."""
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def timed(fn: Callable[[], object], device: torch.device) -> float:
    """Seconds ``fn()`` takes, the device's queued work included."""
    sync(device)
    start = time.perf_counter()
    fn()
    sync(device)
    return time.perf_counter() - start


def identity_scaler() -> EdgeScaler:
    """A normaliser that maps [-1, 1] to itself (speed does not depend on it)."""
    ones, zeros = torch.ones(151), torch.zeros(151)
    return EdgeScaler(ones, zeros, -ones, ones, 2 * ones, (-1.0, 1.0), True, 1)


def run_sampling(
    edge_src: str, *, size: str, features: int, seconds: float, repeats: int, device: torch.device | str = "cpu"
) -> dict[str, list[float]]:
    """Seconds per song of EDGE's ``long_ddim_sample`` and dgsdp's settings (see the module docstring), interleaved;
    on a GPU after one untimed round."""
    device = torch.device(device)
    gpu = device.type == "cuda"
    n_frames = int(round(seconds * 30))
    layout = WindowLayout(n_frames, WINDOW, STRIDE)
    with edge_code(edge_src) as (edge, stand_ins):
        torch.manual_seed(0)
        s = SIZES[size]
        theirs, diffusion = edge_model(edge, WINDOW, s["d"], s["ff"], s["layers"], 8, features, 2.0)
        state = theirs.state_dict()
        ours = build_model(EdgeCheckpoint(Path("random"), state, state, identity_scaler()))
        student = student_of(ours)
        diffusion.to(device)
        cache = tempfile.mkdtemp(prefix="dgsdp-bench-")
        models = {
            "dgsdp": DanceGenerator(ours, cache_dir=cache, device=device),
            "student": DanceGenerator(student, cache_dir=cache, device=device),
        }
        presets = {
            "dgsdp default": ("dgsdp", SamplingSettings()),
            "dgsdp sampling=edge": ("dgsdp", SamplingSettings.from_config(compose_config("generate", ["sampling=edge"]).sampling)),
            # the bf16 and fewer-step switches measured against the default (docs/sampling.md has their quality)
            "dgsdp default, bf16": ("dgsdp", SamplingSettings(bf16=True)),
            "dgsdp 5 steps, bf16": ("dgsdp", SamplingSettings(steps=5, bf16=True)),
            # a guidance-distilled student (docs/distillation.md has its quality)
            "student default": ("student", SamplingSettings()),
            "student 5 steps": ("student", SamplingSettings(steps=5)),
            "student default, bf16": ("student", SamplingSettings(bf16=True)),
        }  # fmt: skip
        if gpu:
            presets["student 5 steps, bf16"] = ("student", SamplingSettings(steps=5, bf16=True))
        if "bf16" not in precisions(device):
            presets = {name: preset for name, preset in presets.items() if not preset[1].bf16}
        edge_rows = {EDGE_SAMPLING: False, **({EDGE_SAMPLING_BF16: True} if gpu else {})}  # name: bf16
        times: dict[str, list[float]] = {name: [] for name in (*edge_rows, *presets)}
        music = torch.randn(layout.n_windows, WINDOW, features, generator=torch.Generator().manual_seed(1)).to(device)

        def edge_sample(bf16: bool) -> None:
            with torch.no_grad(), torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
                diffusion.long_ddim_sample((layout.n_windows, WINDOW, 151), music)

        def our_sample(model: str, settings: SamplingSettings) -> None:
            models[model].generate(n_frames, music=music, sampling=settings, seed=0)

        for i in range(repeats + gpu):  # on a GPU the first round warms up (kernels, cuBLAS, allocator)
            record = i > 0 or not gpu
            for name, bf16 in edge_rows.items():
                seconds_taken = timed(lambda bf16=bf16: edge_sample(bf16), device)
                if record:
                    times[name].append(seconds_taken)
            for name, (model, settings) in presets.items():
                seconds_taken = timed(lambda model=model, settings=settings: our_sample(model, settings), device)
                if record:
                    times[name].append(seconds_taken)
    return times


def run_training(
    edge_src: str, *, size: str, features: int, batch: int, repeats: int, device: torch.device | str = "cpu"
) -> dict[str, list[float]]:
    """Seconds per training step of EDGE's code and dgsdp's, in float32 and under bf16 autocast, interleaved."""
    from dgsdp.training.module import DanceDiffusion

    device = torch.device(device)
    s = SIZES[size]
    steps: dict[str, Callable[[bool], None]] = {}
    with edge_code(edge_src) as (edge, _):
        torch.manual_seed(0)
        theirs, diffusion = edge_model(
            edge, WINDOW, s["d"], s["ff"], s["layers"], 8, features, 2.0, smpl=edge["SMPLSkeleton"](str(device))
        )
        diffusion.to(device).train()
        edge_optim = edge["Adan"](theirs.parameters(), lr=4e-4, weight_decay=0.02)  # EDGE.py's
        spec = RunSpec.from_groups(
            model="paper", audio_dim=features, loss="edge", optimizer="adan", d_model=s["d"], n_layers=s["layers"],
            ff_dim=s["ff"], **EDGE_SWITCHES,
        )  # fmt: skip
        ours = DanceDiffusion(spec).to(device).train()
        our_optim = ours.configure_optimizers()
        gen = torch.Generator().manual_seed(1)
        x = (torch.rand(batch, WINDOW, 151, generator=gen) * 2 - 1).to(device)
        music = torch.randn(batch, WINDOW, features, generator=gen).to(device)
        data = {"motion": x, "audio": music, "genre": torch.zeros(batch, dtype=torch.long, device=device)}

        def edge_step(bf16: bool) -> None:  # EDGE.py's train_loop, ema_interval 1
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
                total, _ = diffusion(x, music)
            edge_optim.zero_grad()
            total.backward()
            edge_optim.step()
            diffusion.ema.update_model_average(diffusion.master_model, diffusion.model)

        def our_step(bf16: bool) -> None:  # DanceDiffusion's training_step, optimizer_step and EMA update
            with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
                loss = ours._loss(ours.denoiser, data, train=True)["loss"]
            loss.backward()
            our_optim.step()
            our_optim.zero_grad(set_to_none=True)
            ema_update(ours.ema, ours.denoiser, ours.spec.ema_decay, first=False)  # as optimizer_step runs it

        for precision in precisions(device):
            steps[f"edge {precision}"] = edge_step
            steps[f"dgsdp {precision}"] = our_step
        times: dict[str, list[float]] = {name: [] for name in steps}
        for i in range(repeats + 1):  # the first round warms up
            for name, step in steps.items():
                seconds_taken = timed(lambda step=step, name=name: step(name.endswith("bf16")), device)
                if i:
                    times[name].append(seconds_taken)
    return times


def run_mfu(device: torch.device, batch: int, steps: int = 5) -> dict[str, float]:
    """A training step of the paper model as ``python -m dgsdp.benchmarks.training --models paper`` times it (bf16
    autocast on a GPU): samples/s, TFLOP/s, MFU and the weight update against the per-parameter loops."""
    from dgsdp.benchmarks.training import bench

    return bench("paper", device, batch, steps, bf16=device.type == "cuda")


def mfu_line(result: dict[str, float], device: torch.device, batch: int) -> str:
    """The ``mfu`` part's line: what ``benchmarks.training`` measured, with the command that gives it."""
    command = f"python -m dgsdp.benchmarks.training --device {device.type} --models paper --batch {batch}"
    mfu = f"{result['mfu_percent']:.1f}% of {result['peak_tflops']:.0f} TFLOP/s" if "mfu_percent" in result else "n/a"
    return (
        f"mfu: the paper model ({command}): {result['samples_per_s']:.1f} samples/s, {result['step_s']:.3f} s per "
        f"step, {result['achieved_tflops']:.1f} TFLOP/s, MFU {mfu}; update {result['update_ms']:.2f} ms against "
        f"{result['reference_update_ms']:.2f} ms in per-parameter loops"
    )


def pytorch3d_importable() -> bool:
    """Whether EDGE's training loss can import pytorch3d (a checkout on PYTHONPATH serves)."""
    return importlib.util.find_spec("pytorch3d") is not None


def device_name(device: torch.device) -> str:
    """The device as the header prints it: the GPU's name, or the CPU and its threads."""
    if device.type == "cuda":
        return f"{torch.cuda.get_device_name(device)} (cuda)"
    return f"CPU ({torch.get_num_threads()} threads)"


def _print_times(times: dict[str, list[float]]) -> dict[str, float]:
    best = {name: min(values) for name, values in times.items()}
    width = max(22, *(len(name) for name in times))
    for name, values in times.items():
        print(f"  {name:<{width}} {best[name]:8.2f}   (all: {', '.join(f'{v:.2f}' for v in values)})")
    return best


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m dgsdp.benchmarks.edge", description=__doc__.splitlines()[0])
    parser.add_argument("--edge-src", required=True, help="a checkout of EDGE's repository (Stanford-TML/EDGE)")
    parser.add_argument(
        "--device", choices=DEVICES, default=None, help="default: cuda where torch sees a GPU, else cpu"
    )
    parser.add_argument("--size", choices=sorted(SIZES), default="paper")
    parser.add_argument("--features", type=int, choices=(35, 4800), default=4800, help="music feature width")
    parser.add_argument("--seconds", type=float, default=None, help="length of the song (s; default 30, 180 on a GPU)")
    parser.add_argument("--batch", type=int, default=None, help="training batch (windows; default 32, 128 on a GPU)")
    parser.add_argument("--repeats", type=int, default=2)
    parser.add_argument("--parts", nargs="+", choices=PARTS, default=None,
                        help="default: sampling and training, and mfu on a GPU")  # fmt: skip
    parser.add_argument("--threads", type=int, default=None, help="CPU threads (torch.set_num_threads)")
    return parser


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = _parser()
    args = parser.parse_args(argv)
    name = args.device or default_device()
    if name == "cuda" and not torch.cuda.is_available():
        parser.error("--device cuda: torch sees no CUDA device here (torch.cuda.is_available() is false); "
                     "use --device cpu")  # fmt: skip
    device = torch.device(name)
    seconds = DEFAULT_SECONDS[device.type] if args.seconds is None else args.seconds
    batch = DEFAULT_BATCH[device.type] if args.batch is None else args.batch
    parts = args.parts or [p for p in PARTS if p != "mfu" or device.type == "cuda"]
    if not seconds > 0:
        parser.error(f"--seconds must be positive, got {seconds:g}")
    if batch < 1 or args.repeats < 1:
        parser.error(f"--batch and --repeats must be at least 1, got {batch} and {args.repeats}")
    if args.threads:
        torch.set_num_threads(args.threads)
    gpu = device.type == "cuda"
    if gpu:
        torch.set_float32_matmul_precision("high")  # TF32, as dgsdp's training on CUDA sets it; both codes
    best: dict[str, float] = {}
    print(
        f"device: {device_name(device)}" + ("; float32 matmuls on TF32 (precision high) for both codes" if gpu else "")
    )
    if gpu:
        setting = f"{torch.cuda.get_device_name(device)}, size {args.size}, {args.features}-d features"
    else:
        setting = f"size {args.size}, {args.features}-d features, {torch.get_num_threads()} threads"
    if "bf16" not in precisions(device):
        print("this CPU has no bf16 instructions (AVX512-BF16 or AMX): the bf16 rows are left out (float32 only)")
    if "sampling" in parts:
        times = run_sampling(
            args.edge_src, size=args.size, features=args.features, seconds=seconds, repeats=args.repeats, device=device
        )
        warm = ", after a warm-up round" if gpu else ""
        print(
            f"sampling: {setting}, {seconds:g} s song, {args.repeats} interleaved repeats{warm}; fastest of each (s):"
        )
        best.update(_print_times(times))
        for row in times:
            if row.startswith("edge"):
                continue
            if row.endswith("bf16") and EDGE_SAMPLING_BF16 in best:
                print(f"  {row} vs EDGE's code in bf16: {best[EDGE_SAMPLING_BF16] / best[row]:.2f}x")
            else:
                print(f"  {row} vs EDGE's code: {best[EDGE_SAMPLING] / best[row]:.2f}x")
        if gpu:
            torch.cuda.empty_cache()
    if "training" in parts:
        if not pytorch3d_importable():
            print("training: n/a: EDGE's training loss imports pytorch3d, which is not importable; its rotation code is "
                  "pure Python, so a checkout of facebookresearch/pytorch3d on PYTHONPATH serves")  # fmt: skip
        else:
            times = run_training(
                args.edge_src, size=args.size, features=args.features, batch=batch, repeats=args.repeats, device=device
            )
            print(f"training: {setting}, batch {batch}, {args.repeats} interleaved repeats after a warm-up; "
                  "seconds per step, fastest of each:")  # fmt: skip
            best.update(_print_times(times))
            if gpu:
                torch.cuda.empty_cache()
    if "mfu" in parts:
        if gpu:
            try:
                print(mfu_line(run_mfu(device, batch), device, batch))
            except (ImportError, torch.cuda.OutOfMemoryError) as e:  # the figures above stand without it
                print(f"mfu: n/a ({type(e).__name__}: {e})")
        else:
            print(
                "mfu: n/a on a CPU (no reliable peak figure); python -m dgsdp.benchmarks.training gives its throughput"
            )
    print(headline(best))
    return best


def headline(best: dict[str, float]) -> str:
    """The last line from the fastest time of each setting (``best``; a part not run leaves its figures n/a):
    ``sampling_speedup_vs_edge`` (EDGE / dgsdp's default), ``sampling_speedup_vs_edge_bf16`` where EDGE's sampling
    was timed in bf16 too (a GPU), ``training_speedup_vs_edge_fp32`` (EDGE / dgsdp, both in float32, what EDGE's own
    training loop runs: the headline), ``training_speedup_vs_edge_bf16`` where bf16 was timed, and last
    ``student_sampling_speedup_vs_edge`` (EDGE / the student at 5 steps; ``_bf16`` beside it where both were timed in
    bf16) with its label: an untrained student's speed, whose quality docs/distillation.md measures. Each precision
    is compared with the same precision, never one side's fastest with the other's."""

    def ratio(edge: str, ours: str) -> str:
        return f"{best[edge] / best[ours]:.2f}" if edge in best and ours in best else "n/a"

    def both(edge: str, ours: str) -> bool:
        return edge in best and ours in best

    parts = [f"sampling_speedup_vs_edge={ratio(EDGE_SAMPLING, 'dgsdp default')}"]
    if both(EDGE_SAMPLING_BF16, "dgsdp default, bf16"):
        parts.append(f"sampling_speedup_vs_edge_bf16={ratio(EDGE_SAMPLING_BF16, 'dgsdp default, bf16')}")
    parts.append(f"training_speedup_vs_edge_fp32={ratio('edge fp32', 'dgsdp fp32')}")
    if both("edge bf16", "dgsdp bf16"):
        parts.append(f"training_speedup_vs_edge_bf16={ratio('edge bf16', 'dgsdp bf16')}")
    parts.append(f"student_sampling_speedup_vs_edge={ratio(EDGE_SAMPLING, STUDENT_HEADLINE)}")
    if both(EDGE_SAMPLING_BF16, f"{STUDENT_HEADLINE}, bf16"):
        parts.append(f"student_sampling_speedup_vs_edge_bf16={ratio(EDGE_SAMPLING_BF16, f'{STUDENT_HEADLINE}, bf16')}")
    return " ".join(parts) + f" {STUDENT_LABEL}"


if __name__ == "__main__":
    main()
