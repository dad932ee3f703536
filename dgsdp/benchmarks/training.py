"""Training throughput: samples/s, achieved TFLOP/s, model FLOPs utilisation (MFU) and peak memory.

    python -m dgsdp.benchmarks.training [--device cpu|cuda] [--models small paper] [--batch 32] [--steps 5]
                                        [--compile] [--gradient-checkpointing] [--data data/synthetic]

Runs full training steps (diffusion loss with FK and foot terms, backward, Adan step, EMA update) of the real
LightningModule on random 5 s windows, without data loading. The update alone (Adan step and EMA update, as the
training module runs them: :mod:`dgsdp.training.optim`) is timed beside the per-parameter loops the project ran
before (adan-pytorch's Adan and AveragedModel's update) on the same weights and gradients: "update ms" and the
ratio. FLOPs of one step are counted with ``torch.utils.flop_counter.FlopCounterMode`` (matrix products and attention, forward and backward; recomputation
by activation checkpointing not counted, so MFU stays a model-FLOPs figure). MFU = achieved FLOP/s / the
device's dense peak for the precision used: bf16 with ``--bf16`` (default on CUDA), TF32 for float32 matmuls at
precision "high" (set on CUDA, as in training), from the vendors' spec sheets (:data:`PEAK_TFLOPS`). On a CPU
there is no reliable peak figure, so MFU is printed as n/a.

``--data ROOT`` (an AIST++-layout dataset, e.g. the synthetic one the quick start writes to data/synthetic) times
the batches of a training epoch instead: the host loader's (each batch collated on the host and copied to the
device) against windows kept on the device (``data.on_device``, :mod:`dgsdp.data.device`), after checking that the
two give equal batches.
"""

from __future__ import annotations

import argparse
import resource
import time

import torch

from dgsdp.trained.spec import RunSpec
from dgsdp.training.module import DanceDiffusion
from dgsdp.training.optim import ema_update

# Dense (no sparsity) peak tensor TFLOP/s from NVIDIA's spec sheets: (bf16, tf32, fp32 without tensor cores).
# Matched against torch.cuda.get_device_name() in this order (more specific names first).
PEAK_TFLOPS: dict[str, tuple[float, float, float]] = {
    "H100 PCIe": (756.0, 378.0, 51.2),
    "H100 NVL": (835.0, 418.0, 60.0),
    "H100": (989.4, 494.7, 66.9),  # SXM5 ("NVIDIA H100 80GB HBM3")
    "H200": (989.4, 494.7, 66.9),  # SXM
    "A100": (312.0, 156.0, 19.5),  # SXM4 and PCIe
    "A6000": (154.8, 77.4, 38.7),  # RTX A6000
    "L40S": (362.1, 183.0, 91.6),
    "L4": (121.0, 60.0, 30.3),
}
AUDIO_DIM = {"small": 35, "paper": 4800}  # the default librosa features; the papers' Jukebox features


def build(model_name: str, style_dim: int) -> DanceDiffusion:
    spec = RunSpec.from_groups(
        model=model_name, audio_dim=AUDIO_DIM[model_name], style_dim=style_dim, style_kind="prompt",
        style_bank_size=40, n_genres=10,
    )  # fmt: skip
    model = DanceDiffusion(spec)
    model.style_vectors.normal_()
    model.style_genre_index.copy_(torch.arange(40) % 10)
    return model


def peak_tflops(device: torch.device, bf16: bool) -> float | None:
    """The device's dense peak for the precision of the run, or None (CPU, or a GPU not in the table)."""
    if device.type != "cuda":
        return None
    name = torch.cuda.get_device_name(device)
    peaks = next((v for k, v in PEAK_TFLOPS.items() if k in name), None)
    if peaks is None:
        return None
    if bf16:
        return peaks[0]
    return peaks[1] if torch.get_float32_matmul_precision() != "highest" else peaks[2]


def bench(
    model_name: str,
    device: torch.device,
    batch: int,
    steps: int,
    bf16: bool,
    compile: bool = False,
    gradient_checkpointing: bool = False,
) -> dict[str, float]:
    torch.manual_seed(0)
    model = build(model_name, style_dim=384).to(device).train()
    model.denoiser.gradient_checkpointing = gradient_checkpointing
    optimizer = model.configure_optimizers()
    audio_dim = model.denoiser.audio_dim
    data = {
        "motion": torch.rand(batch, 150, 151, device=device) * 2 - 1,
        "audio": torch.randn(batch, 150, audio_dim, device=device),
        "genre": torch.randint(0, 10, (batch,), device=device),
    }

    def step() -> None:
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=bf16):
            loss = model._loss(model.denoiser, data, train=True)["loss"]
        loss.backward()
        optimizer.step()
        optimizer.zero_grad(set_to_none=True)
        ema_update(model.ema, model.denoiser, model.spec.ema_decay, first=False)

    from torch.utils.flop_counter import FlopCounterMode

    model.denoiser.gradient_checkpointing = False  # count the model's FLOPs, not the recomputation
    counter = FlopCounterMode(display=False)
    with counter:
        step()
    flops_per_step = counter.get_total_flops()
    model.denoiser.gradient_checkpointing = gradient_checkpointing
    if compile:
        model.denoiser.compile()
        step()  # compiles
    step()  # warm-up
    if device.type == "cuda":
        torch.cuda.synchronize(device)
        torch.cuda.reset_peak_memory_stats(device)
    start = time.perf_counter()
    for _ in range(steps):
        step()
    if device.type == "cuda":
        torch.cuda.synchronize(device)
    seconds = (time.perf_counter() - start) / steps
    if device.type == "cuda":
        peak_gib = torch.cuda.max_memory_allocated(device) / 2**30
    else:
        peak_gib = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 2**20  # process peak RSS (KiB -> GiB)
    update_s, reference_s = time_updates(model, optimizer, data, steps)
    result = {
        "update_ms": 1000 * update_s,
        "reference_update_ms": 1000 * reference_s,
        "params_M": sum(p.numel() for p in model.denoiser.parameters()) / 1e6,
        "samples_per_s": batch / seconds,
        "step_s": seconds,
        "tflops_per_step": flops_per_step / 1e12,
        "achieved_tflops": flops_per_step / seconds / 1e12,
        "peak_memory_gib": peak_gib,
    }
    peak = peak_tflops(device, bf16)
    if peak:
        result["peak_tflops"] = peak
        result["mfu_percent"] = 100 * result["achieved_tflops"] / peak
    return result


def time_updates(
    model: DanceDiffusion, optimizer: torch.optim.Optimizer, data: dict[str, torch.Tensor], steps: int
) -> tuple[float, float]:
    """Seconds of one weight update (Adan step and EMA update) as training runs it, and as adan-pytorch's Adan and
    AveragedModel's update ran it, on the model's weights with the gradients of one more step."""
    from adan_pytorch import Adan as LoopAdan

    loss = model._loss(model.denoiser, data, train=True)["loss"]
    loss.backward()
    group = optimizer.param_groups[0]
    loop = LoopAdan(model.denoiser.parameters(), lr=group["lr"], betas=group["betas"], eps=group["eps"],
                    weight_decay=group["weight_decay"])  # fmt: skip

    def ours() -> None:
        optimizer.step()
        ema_update(model.ema, model.denoiser, model.spec.ema_decay, first=False)

    def theirs() -> None:
        loop.step()
        model.ema.update_parameters(model.denoiser)

    out = []
    for update in (ours, theirs, ours, theirs):  # each twice, interleaved: a warm-up and the timed runs
        update()
        sync(model.device)
        start = time.perf_counter()
        for _ in range(steps):
            update()
        sync(model.device)
        out.append((time.perf_counter() - start) / steps)
    optimizer.zero_grad(set_to_none=True)
    return min(out[0], out[2]), min(out[1], out[3])


def sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


def bench_data(root: str, device: torch.device, batch: int, epochs: int = 2) -> dict[str, float]:
    """Milliseconds per training batch on ``device`` from the host loader and from windows kept on the device."""
    from pathlib import Path

    from dgsdp.audio import LibrosaEncoder
    from dgsdp.data.datamodule import DanceDataModule, EpochShuffleSampler, ResumableLoader
    from dgsdp.data.device import DeviceLoader, DeviceWindows
    from dgsdp.errors import DataError

    if not (Path(root) / "motions").is_dir():
        raise DataError(f"--data {root}: no dataset there; run the quick start (or 'python -m dgsdp.data.synthetic')")
    dm = DanceDataModule(root, str(Path(root).parent / "cache"), audio_encoder=LibrosaEncoder(rhythm_only=True),
                         batch_size=batch, progress=False, movement_channels=("speed",))  # fmt: skip
    dm.setup("fit")
    dataset = dm.datasets["train"]
    host = ResumableLoader(dataset, batch_size=batch, seed=0)
    windows = DeviceWindows(dataset, device)
    on_device = DeviceLoader(windows, batch_size=batch, sampler=EpochShuffleSampler(len(windows), 0))

    def moved(b: dict) -> dict:
        return {k: v.to(device, non_blocking=True) if torch.is_tensor(v) else v for k, v in b.items()}

    first_host, first_device = moved(next(iter(host))), next(iter(on_device))
    for key, value in first_host.items():
        same = torch.equal(value, first_device[key]) if torch.is_tensor(value) else value == first_device[key]
        if not same:
            raise RuntimeError(
                f"the host loader and the device store give different batches ({key!r}): a bug; please report it"
            )
    times = {}
    for name, loader, prepare in (("host", host, moved), ("device", on_device, lambda b: b)):
        count = 0
        sync(device)
        start = time.perf_counter()
        for epoch in range(epochs):
            loader.sampler.set_epoch(epoch)
            for b in loader:
                prepare(b)
                count += 1
        sync(device)
        times[name] = (time.perf_counter() - start) / count * 1e3
    return {"windows": len(dataset), "batches": count, "store_mb": windows.nbytes / 1e6, **times}


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--models", nargs="+", default=["small", "paper"], choices=["small", "paper"])
    parser.add_argument("--batch", type=int, default=None, help="default: 32 on CPU, 128 on GPU (DGSDP's batch)")
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--bf16", action=argparse.BooleanOptionalAction, default=None, help="default: on for CUDA")
    parser.add_argument("--compile", action="store_true", help="torch.compile the denoiser (as compile=true)")
    parser.add_argument("--gradient-checkpointing", action="store_true", help="recompute layer activations")
    parser.add_argument("--data", metavar="ROOT", help="time the training batches of this dataset instead")
    args = parser.parse_args(argv)
    device = torch.device(args.device)
    if device.type == "cuda":
        torch.set_float32_matmul_precision("high")  # TF32, as training on CUDA
    bf16 = device.type == "cuda" if args.bf16 is None else args.bf16
    batch = args.batch or (128 if device.type == "cuda" else 32)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU ({torch.get_num_threads()} threads)"
    if args.data:
        r = bench_data(args.data, device, batch)
        print(f"device: {name}; {r['windows']} training windows of {args.data}, batch {batch}, {r['batches']} batches "
              f"(2 epochs); the windows take {r['store_mb']:.1f} MB on the device")  # fmt: skip
        print(f"ms per batch: host loader (collate + copy) {r['host']:.2f}, on the device {r['device']:.2f}, "
              f"ratio {r['host'] / r['device']:.1f}x (equal batches checked)")  # fmt: skip
        return
    print(
        f"device: {name}; batch {batch}; bf16 autocast: {bf16}; compile: {args.compile}; "
        f"gradient checkpointing: {args.gradient_checkpointing}; {args.steps} timed steps"
    )
    if device.type == "cpu":
        print("MFU: n/a on CPU (no reliable peak figure); peak memory = the process's peak resident set size")
    print(
        f"{'model':<7}{'params':>9}{'samples/s':>11}{'step s':>9}{'TFLOP/step':>12}{'TFLOP/s':>9}{'peak GiB':>10}"
        f"{'device peak TFLOP/s':>21}{'MFU %':>7}{'update ms':>11}{'loop ms':>9}{'ratio':>7}"
    )
    for model_name in args.models:
        r = bench(model_name, device, batch, args.steps, bf16, args.compile, args.gradient_checkpointing)
        mfu = f"{r['mfu_percent']:.1f}" if "mfu_percent" in r else "n/a"
        peak = f"{r['peak_tflops']:.1f}" if "peak_tflops" in r else "n/a"
        print(
            f"{model_name:<7}{r['params_M']:>8.2f}M{r['samples_per_s']:>11.1f}{r['step_s']:>9.3f}"
            f"{r['tflops_per_step']:>12.3f}{r['achieved_tflops']:>9.2f}{r['peak_memory_gib']:>10.2f}{peak:>21}{mfu:>7}"
            f"{r['update_ms']:>11.2f}{r['reference_update_ms']:>9.2f}{r['reference_update_ms'] / r['update_ms']:>6.1f}x"
        )
    print("update ms: Adan step + EMA update as training runs them; loop ms: adan-pytorch's Adan + AveragedModel")


if __name__ == "__main__":
    main()
