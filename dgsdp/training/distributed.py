"""Data-parallel helpers: which process writes files, and the trainer precision that suits an accelerator."""

from __future__ import annotations

import logging

import torch
from lightning.fabric.utilities.rank_zero import rank_zero_only


def launch_rank() -> int:
    """This process's global rank as known before the process group exists (Lightning's rule: the ``RANK``,
    ``SLURM_PROCID`` or ``LOCAL_RANK`` variable set by the launcher; 0 for a plain ``python train.py``)."""
    return int(getattr(rank_zero_only, "rank", 0) or 0)


def is_writer() -> bool:
    """True on the one process that writes run files (rank 0)."""
    return launch_rank() == 0


def log_files_on_writer_only() -> None:
    """Detach the log-file handlers (Hydra's ``<job>.log``) on every process but rank 0, so a data-parallel run
    writes one log. The handlers open their file lazily (``delay: true`` in ``conf/hydra/default.yaml``), so no
    empty file is left either."""
    if is_writer():
        return
    root = logging.getLogger()
    for handler in list(root.handlers):
        if isinstance(handler, logging.FileHandler):
            root.removeHandler(handler)
            handler.close()


def precision_for(accelerator: str, gpu_precision: str = "bf16-mixed") -> str:
    """``gpu_precision`` on GPUs, ``32-true`` on CPUs; ``auto`` follows whether CUDA is available. On a CPU, bf16
    autocast (``trainer.precision=bf16-mixed``) is a choice, not the default: it is faster only where the CPU has
    native bf16 instructions (AVX512-BF16 or AMX: 1.5-1.8x for a paper-size step on 2 cores of an AMD EPYC Zen 4,
    docs/notes/2026-11-24-against-edge.md), slower elsewhere, and numerically different from float32. Used by ``conf/trainer/ddp.yaml`` as
    ``${dgsdp_precision:${.accelerator}}``."""
    accelerator = str(accelerator).lower()
    on_gpu = accelerator in ("gpu", "cuda") or (accelerator == "auto" and torch.cuda.is_available())
    return gpu_precision if on_gpu else "32-true"
