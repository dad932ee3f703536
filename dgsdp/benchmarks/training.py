"""Training throughput: samples/s, peak memory and (on GPU) model FLOPs utilisation.

    python -m dgsdp.benchmarks.training [--device cpu|cuda] [--models small paper] [--batch 32] [--steps 5]

Runs full training steps (diffusion loss with FK and foot terms, backward, Adan step, EMA update) of the real
LightningModule on random 5 s windows, without data loading. FLOPs of one step are counted with
``torch.utils.flop_counter.FlopCounterMode``; MFU = achieved FLOP/s / the device's peak (bf16 dense).
"""

from __future__ import annotations

import argparse
import resource
import time

import torch
from omegaconf import OmegaConf

from dgsdp.resources import CONFIG_DIR
from dgsdp.training.module import DanceDiffusion

PEAK_BF16_TFLOPS = {"H100": 989.0, "H200": 989.0, "A100": 312.0, "A6000": 155.0, "L40": 181.0}
AUDIO_DIM = {"small": 35, "paper": 4800}  # the default librosa features; the papers' Jukebox features


def build(model_name: str, style_dim: int) -> DanceDiffusion:
    model_cfg = OmegaConf.to_container(OmegaConf.load(CONFIG_DIR / "model" / f"{model_name}.yaml"))
    ema_decay = model_cfg.pop("ema_decay")
    diffusion = OmegaConf.to_container(OmegaConf.load(CONFIG_DIR / "diffusion" / "default.yaml"))
    drop = {k: diffusion.pop(k) for k in ("music_drop_prob", "style_drop_prob")}
    hparams = {
        "model": {**model_cfg, "style_injection": "modulation", "also_concat": True},
        "conditioning": {
            "audio_dim": AUDIO_DIM[model_name],
            "style_dim": style_dim,
            "style_bank_size": 40,
            "n_genres": 10,
            **drop,
        },  # fmt: skip
        "diffusion": diffusion,
        "loss": OmegaConf.to_container(OmegaConf.load(CONFIG_DIR / "loss" / "edge.yaml")),
        "optimizer": OmegaConf.to_container(OmegaConf.load(CONFIG_DIR / "optimizer" / "adan.yaml")),
        "ema": {"decay": ema_decay},
    }
    model = DanceDiffusion(hparams)
    model.style_vectors.normal_()
    model.style_genre_index.copy_(torch.arange(40) % 10)
    return model


def peak_tflops(device: torch.device) -> float | None:
    if device.type != "cuda":
        return None
    name = torch.cuda.get_device_name(device)
    return next((v for k, v in PEAK_BF16_TFLOPS.items() if k in name), None)


def bench(model_name: str, device: torch.device, batch: int, steps: int, bf16: bool) -> dict[str, float]:
    torch.manual_seed(0)
    model = build(model_name, style_dim=384).to(device).train()
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
        model.ema.update_parameters(model.denoiser)

    from torch.utils.flop_counter import FlopCounterMode

    counter = FlopCounterMode(display=False)
    with counter:
        step()
    flops_per_step = counter.get_total_flops()
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
    result = {
        "params_M": sum(p.numel() for p in model.denoiser.parameters()) / 1e6,
        "samples_per_s": batch / seconds,
        "step_s": seconds,
        "tflops_per_step": flops_per_step / 1e12,
        "achieved_tflops": flops_per_step / seconds / 1e12,
        "peak_memory_gib": peak_gib,
    }
    peak = peak_tflops(device)
    if peak:
        result["mfu_percent"] = 100 * result["achieved_tflops"] / peak
    return result


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--device", default="cuda" if torch.cuda.is_available() else "cpu")
    parser.add_argument("--models", nargs="+", default=["small", "paper"], choices=["small", "paper"])
    parser.add_argument("--batch", type=int, default=None, help="default: 32 on CPU, 128 on GPU (DGSDP's batch)")
    parser.add_argument("--steps", type=int, default=5)
    parser.add_argument("--bf16", action=argparse.BooleanOptionalAction, default=None, help="default: on for CUDA")
    args = parser.parse_args(argv)
    device = torch.device(args.device)
    bf16 = device.type == "cuda" if args.bf16 is None else args.bf16
    batch = args.batch or (128 if device.type == "cuda" else 32)
    name = torch.cuda.get_device_name(device) if device.type == "cuda" else f"CPU ({torch.get_num_threads()} threads)"
    print(f"device: {name}; batch {batch}; bf16 autocast: {bf16}; {args.steps} timed steps")
    print(
        f"{'model':<7}{'params':>9}{'samples/s':>11}{'step s':>9}{'TFLOP/step':>12}{'TFLOP/s':>9}{'peak GiB':>10}{'MFU %':>7}"
    )
    for model_name in args.models:
        r = bench(model_name, device, batch, args.steps, bf16)
        mfu = f"{r['mfu_percent']:.1f}" if "mfu_percent" in r else "-"
        print(
            f"{model_name:<7}{r['params_M']:>8.2f}M{r['samples_per_s']:>11.1f}{r['step_s']:>9.3f}"
            f"{r['tflops_per_step']:>12.3f}{r['achieved_tflops']:>9.2f}{r['peak_memory_gib']:>10.2f}{mfu:>7}"
        )


if __name__ == "__main__":
    main()
