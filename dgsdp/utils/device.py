"""Device selection shared by every entry point."""

from __future__ import annotations


def resolve_device(device: str) -> str:
    """``"auto"`` -> ``"cuda"`` when a GPU is visible, else ``"cpu"``; other values pass through."""
    if device == "auto":
        import torch

        return "cuda" if torch.cuda.is_available() else "cpu"
    return str(device)


def cpu_has_native_bf16() -> bool:
    """Whether this CPU multiplies bf16 matrices in hardware (AVX512-BF16 or AMX, as oneDNN reports it). Without
    them torch falls back to a plain loop: on an AVX2-only AMD EPYC a 2048 x 2048 bf16 product took 57 s against
    0.16 s in float32, so bf16 autocast on such a CPU is hundreds of times slower, not faster."""
    import torch

    try:
        return bool(torch.ops.mkldnn._is_mkldnn_bf16_supported())
    except (AttributeError, RuntimeError):  # a torch built without oneDNN: no fast bf16 path either
        return False


def check_cpu_bf16(setting: str) -> None:
    """ConfigError naming ``setting`` (the key that asked for bf16 autocast on a CPU) where this CPU has no native
    bf16 instructions (:func:`cpu_has_native_bf16`)."""
    if cpu_has_native_bf16():
        return
    from dgsdp.errors import ConfigError

    raise ConfigError(
        f"{setting} asks for bf16 autocast on a CPU without bf16 instructions (AVX512-BF16 or AMX): there torch "
        "multiplies bf16 matrices in a plain loop, hundreds of times slower than float32. Use float32 (leave the "
        "setting off), or run on a CPU or GPU with bf16 support"
    )
